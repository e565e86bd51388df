"""From a wrong start: does the hybrid converge where the OCV can tell, and does its sigma
hold the error where it cannot?

Issue 24's target: from +-30 % initial error, within 2 % within 10 minutes wherever the OCV
can tell (SLA always; LFP once it rests 20 minutes or crosses a knee); where it cannot, sigma
stays >= |error| / 2. Each corpus mission (``tools/make_bags.py --corpus``; its ``bag.yaml``
says the split) is run from its reference start +0.3 and -0.3 (skipped where that leaves
[0, 1], as test_accuracy.py skips), declared with std 0.1 (a user's guess: the same as the
correct starts of ``do_no_harm.py``), through the bundled file of its chemistry.

Where the OCV can tell is read on the truth and the file, not on the estimate: the first
sample whose true SoC lies where the file's OCV resolves it to ``RESOLVED_SOC`` (1 point)
under the model's own persistent error, ``bias_std_v / |dOCV/dsoc| <= RESOLVED_SOC`` (the
hybrid's ``bias_std_v``, the same ratio as its item 9). On the SLA curve that holds everywhere
(the SoC of its first sample); on LFP's it holds below about 0.35 and in the step near 0.75,
not on the flat stretches, where a rest does not tell either (item 9). Per start, printed:

* ``tell_s``: seconds from the start to that sample (``-``: never in the mission);
* ``after``: the largest |error| from ``tell_s`` + 600 s on (points; the target: < 2);
* ``held``: % of the samples before then (the OCV cannot tell yet, or the 10 minutes run) with
  sigma >= |error| / 2 (the target: all of them);
* ``final``: |error| at the end (points) and ``std`` sigma there;
* ``ref``: the largest |error| over the same samples as ``after`` of the same hybrid started
  from the truth as sure as a resumed state (std ``REF_START_STD``): what no start corrects,
  the charge count's own drift where the OCV is flat (the current sensor's offset over the
  mission's time, its gain and the capacity over the charge moved) and the model's error; a
  miss within ``SAME_AS_REF`` of it is not the start's;
* ``out``: degrees the mission's median temperature lies outside the file's (0 inside):
  beyond ``FAR_OUTSIDE_C`` the guard keeps to the charge count (do no harm), which does not
  correct a wrong start.

    python benchmarks/studies/wrong_start.py --corpus /work/corpus --split validation \
        [--chemistry lfp] [--jobs 2] [--tracker]
"""

from __future__ import annotations

import argparse
import math
import os
import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from do_no_harm import (  # noqa: E402
    WINDOW_S,
    Case,
    add_tuning_option,
    corpus_cases,
    estimates,
    selected,
    tuning_of,
)

from soc_estimator_ros.estimators.hybrid import Hybrid  # noqa: E402

OFFSETS = (0.3, -0.3)
START_STD = 0.1
#: The std of the true start ``ref`` is run from: as sure as a resumed state.
REF_START_STD = 0.015
#: A miss within this many points of ``ref`` is counted as the true start's (the summary).
SAME_AS_REF = 0.5
#: Beyond this many degC outside the file's temperatures the guard's prior that the model
#: holds is below 0.61 of its value inside (``exp(-(d / 2)^2 / 2)``, hybrid item 7): it keeps
#: to the charge count, which does not correct a wrong start (the summary).
FAR_OUTSIDE_C = 2.0
#: SoC the OCV resolves under the model's persistent error where it "can tell" (fraction).
RESOLVED_SOC = 0.01
#: ``held``'s rounding allowance (SoC): a start 0.3 off with std 0.15 sits on the bound, and
#: ``|0.898 - 0.598|`` is 0.30000000000000004 in floating point, so the first sample of an
#: ungated start "missed" it by 4e-17. A billionth of SoC is far below anything measured.
HELD_ROUNDING = 1e-9


def tell_index(case: Case) -> int | None:
    """The first sample whose true SoC the file's OCV resolves to ``RESOLVED_SOC`` (module
    docstring); None when no sample does."""
    tuning = Hybrid.merged_tuning(case.battery.filters.get("hybrid"))
    bias_v = float(tuning["bias_std_v"])
    slope = case.battery.thevenin_model().ocv.slope
    for k, soc in enumerate(case.soc_ref):
        if math.isfinite(soc) and bias_v <= RESOLVED_SOC * abs(slope(float(soc))):
            return k
    return None


def judged_samples(case: Case) -> tuple[float, np.ndarray]:
    """When the OCV can tell (s from the start; inf: never) and the samples ``after`` reads,
    from 10 minutes after it: the mission's, whatever the start."""
    t = case.series.t_s - case.series.t_s[0]
    k = tell_index(case)
    tell_s = math.inf if k is None else float(t[k])
    return tell_s, t >= tell_s + WINDOW_S


def true_start_after(case: Case, tuning: dict | None = None, tracker: bool = False) -> float:
    """``ref``: the largest |error| (points) over the judged samples of the hybrid from the
    true start with std ``REF_START_STD``; nan when the OCV never tells."""
    _, judged = judged_samples(case)
    if not judged.any():
        return math.nan
    ref = estimates(case, "hybrid", float(case.soc_ref[0]), REF_START_STD, tuning, tracker)
    return 100 * float(np.nanmax(np.abs(ref.soc - case.soc_ref)[judged]))


def score(
    case: Case,
    offset: float,
    start_std: float = START_STD,
    tuning: dict | None = None,
    tracker: bool = False,
    ref: float | None = None,
) -> dict[str, float | str] | None:
    """One start (module docstring), the file's hybrid tuning updated with ``tuning``, bare or
    as the node runs it (``tracker``: ``do_no_harm.estimates``); None when it leaves [0, 1].
    ``ref``: the mission's :func:`true_start_after` if already run (it is the same for every
    start of a mission), else run here."""
    soc0 = float(case.soc_ref[0]) + offset
    if not 0.0 <= soc0 <= 1.0:
        return None
    out = estimates(case, "hybrid", soc0, start_std, tuning, tracker)
    err = np.abs(out.soc - case.soc_ref)
    tell_s, judged = judged_samples(case)
    before = ~judged & np.isfinite(err)
    if ref is None:
        ref = true_start_after(case, tuning, tracker)
    return {
        "case": case.name,
        "split": case.split,
        "offset": 100 * offset,
        "tell_s": tell_s,
        "after": 100 * float(np.nanmax(err[judged])) if judged.any() else math.nan,
        "held": 100 * float(np.mean(err[before] <= 2.0 * out.soc_std[before] + HELD_ROUNDING))
        if before.any()
        else math.nan,
        "final": 100 * float(err[-1]),
        "std": 100 * float(out.soc_std[-1]),
        "ref": ref,
        "out": outside_c(case),
    }


def outside_c(case: Case) -> float:
    """Degrees the mission's median measured temperature lies outside the file's (0 inside;
    nan without a temperature)."""
    temps = case.series.temperature_c
    if temps is None or not np.isfinite(temps).any():
        return math.nan
    return abs(case.battery.thevenin_model().extrapolation_c(float(np.nanmedian(temps))))


def _job(args: tuple[Case, float, dict | None, bool]) -> list[dict[str, float | str]]:
    """Every start of one mission, its true start's run (``ref``) made once for them."""
    case, start_std, tuning, tracker = args
    ref = true_start_after(case, tuning, tracker)
    rows = (score(case, o, start_std, tuning, tracker, ref) for o in OFFSETS)
    return [r for r in rows if r]


def summary(rows: list[dict[str, float | str]]) -> list[str]:
    """Per split: starts where the OCV could tell and how many were within 2 points from 10
    minutes after; how many held sigma >= |error| / 2 on every sample before, and on 95 %."""
    out = []
    for split in sorted({str(r["split"]) for r in rows}):
        g = [r for r in rows if r["split"] == split]
        told = [r for r in g if math.isfinite(float(r["after"]))]
        conv = sum(float(r["after"]) < 2.0 for r in told)
        missed = [r for r in told if float(r["after"]) >= 2.0]
        as_ref, rest = [], []
        for r in missed:
            same = float(r["after"]) <= float(r["ref"]) + SAME_AS_REF
            (as_ref if same else rest).append(r)
        cold_hot = sum(float(r["out"]) > FAR_OUTSIDE_C for r in rest)
        held = [float(r["held"]) for r in g if math.isfinite(float(r["held"]))]
        out.append(
            f"{split} ({len(g)} starts): the OCV could tell on {len(told)}, within 2 points from "
            f"10 minutes after on {conv}; sigma >= |error| / 2 until then on every sample on "
            f"{sum(h >= 100.0 for h in held)} of {len(held)}, on 95 % of them on "
            f"{sum(h >= 95.0 for h in held)}"
        )
        out.append(
            f"  of the {len(missed)} beyond 2 points, {len(as_ref)} within {SAME_AS_REF:g} point "
            f"of the true start's run over the same samples (ref: not the start's); of the "
            f"other {len(rest)}, {cold_hot} more than {FAR_OUTSIDE_C:g} degC outside the "
            "file's temperatures"
        )
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--corpus", type=Path, required=True, help="a directory of corpus missions")
    ap.add_argument("--split", default="", help="only missions of this split")
    ap.add_argument("--chemistry", default="", help="only missions of this chemistry")
    ap.add_argument("--jobs", type=int, default=os.cpu_count() or 1)
    ap.add_argument("--start-std", type=float, default=START_STD, help="the start's std")
    add_tuning_option(ap, "a hybrid tuning entry over its file's")
    ap.add_argument(
        "--tracker",
        action="store_true",
        help="the hybrid as the node runs it (the gate, FULL at a CC-CV end), not bare",
    )
    args = ap.parse_args()
    tuning = tuning_of(args.tuning)
    if not args.corpus.is_dir():
        print(f"wrong_start: no corpus at {args.corpus}")
        return 1
    cases = selected(corpus_cases(args.corpus), args.split, args.chemistry)
    with ProcessPoolExecutor(max(1, args.jobs)) as pool:
        jobs = [(c, args.start_std, tuning, args.tracker) for c in cases]
        rows = [r for mission in pool.map(_job, jobs) for r in mission]
    keys = ("offset", "tell_s", "after", "held", "final", "std", "ref", "out")
    print(f"{'case':<28} {'split':<10} " + " ".join(f"{k:>8}" for k in keys))
    for r in rows:
        print(
            f"{r['case']:<28} {r['split']:<10} "
            + " ".join(f"{float(r[k]):8.1f}" if k != "tell_s" else _tell(r[k]) for k in keys)
        )
    print(
        f"(points of SoC; start std {args.start_std:g}"
        f"{'; through the tracker' if args.tracker else ''}; tell_s: when the OCV could tell, s; "
        f"after: max |error| from {WINDOW_S:.0f} s later, < 2 the target; held: % of the "
        "samples before with sigma >= |error| / 2, 100 the target; ref: max |error| over the "
        f"same samples from the true start, std {REF_START_STD:g}; out: degC outside the "
        "file's temperatures)"
    )
    for line in summary(rows):
        print(line)
    return 0


def _tell(value: float | str) -> str:
    return f"{'-':>8}" if not math.isfinite(float(value)) else f"{float(value):8.0f}"


if __name__ == "__main__":
    raise SystemExit(main())
