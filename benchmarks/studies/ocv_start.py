"""A start from the OCV, as the node boots without a saved state: each mission's first sample
read as an OCV, against its true SoC, and the hybrid from that start.

Two readings of the same first sample (its voltage, current and temperature):

* ``curve``: the voltage on the file's OCV curve, as if the pack rested;
* ``model``: what the tracker does (``Tracker.soc_from_ocv``: ``TheveninModel.
  soc_at_terminal_voltage``, the model's drop at the sample's current and its temperature
  offset taken out, the relaxation no one knows at a start in the std).

Per mission: the first sample's current and temperature, the true SoC, each reading's error
(points) and its error over its std (``z``); with ``--run`` also the hybrid replayed from the
tracker's start (``soc_replay --initial-soc ocv``): MAE and max after the 10-minute window.
Per chemistry: the mean and largest |error|, how many starts lie within 2 std, and the
hybrid's mean MAE. The split each mission belongs to is printed beside it (``bag.yaml``).

    python benchmarks/studies/ocv_start.py --corpus /work/corpus --split validation [--run]
"""

from __future__ import annotations

import argparse
import math
import os
import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from do_no_harm import Case, corpus_cases  # noqa: E402

from soc_estimator_ros.replay.run import replay_estimator  # noqa: E402
from soc_estimator_ros.tracking import GateConfig, Tracker  # noqa: E402


def start_row(case: Case, run: bool) -> dict[str, float | str]:
    """The two readings of ``case``'s first sample and, with ``run``, the hybrid from it."""
    s = case.series
    tracker = Tracker(case.battery, GateConfig.from_limits(case.battery.limits))
    temp_c = math.nan if s.temperature_c is None else float(s.temperature_c[0])
    v, i = float(s.voltage_v[0]), float(s.current_a[0])
    curve_soc, curve_std = case.battery.ocv_curve().soc_at_with_std(
        v, tracker.config.ocv_voltage_std_v
    )
    soc, std = tracker.soc_from_ocv(v, i, temp_c)
    row: dict[str, float | str] = {
        "name": case.name,
        "split": case.split,
        "chemistry": case.battery.chemistry,
        "current_a": i,
        "temp_c": temp_c,
        "ref": float(case.soc_ref[0]),
        "curve": min(max(curve_soc, 0.0), 1.0),
        "curve_std": curve_std,
        "model": soc,
        "model_std": std,
        "mae": math.nan,
        "max": math.nan,
    }
    if run:
        acc = replay_estimator(s, case.battery, "hybrid", "ocv", case.name).accuracy
        if acc is not None:
            row["mae"], row["max"] = 100 * acc.mae, 100 * acc.max_abs
    return row


def _job(args: tuple[Case, bool]) -> dict[str, float | str]:
    return start_row(*args)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--corpus", type=Path, action="append", required=True, help="repeatable")
    ap.add_argument("--split", default="", help="only missions of this split")
    ap.add_argument("--chemistry", default="", help="only missions of this chemistry")
    ap.add_argument("--run", action="store_true", help="also replay the hybrid from the start")
    ap.add_argument("--jobs", type=int, default=os.cpu_count() or 1)
    args = ap.parse_args()
    cases = [c for root in args.corpus for c in corpus_cases(root)]
    cases = [c for c in cases if not args.split or c.split == args.split]
    cases = [c for c in cases if not args.chemistry or c.battery.chemistry == args.chemistry]
    with ProcessPoolExecutor(max(1, args.jobs)) as pool:
        rows = list(pool.map(_job, [(c, args.run) for c in cases]))
    print(
        f"{'mission':<24} {'split':<10} {'I A':>6} {'T C':>5} {'true':>6} "
        f"{'curve err':>9} {'z':>6} {'model err':>9} {'z':>6} {'std':>5} {'MAE':>6} {'max':>6}"
    )
    for r in rows:
        ref = float(r["ref"])
        ce, me = float(r["curve"]) - ref, float(r["model"]) - ref
        print(
            f"{r['name']:<24} {r['split']:<10} {float(r['current_a']):6.2f} "
            f"{float(r['temp_c']):5.1f} {100 * ref:6.1f} {100 * ce:9.1f} "
            f"{ce / float(r['curve_std']):6.2f} {100 * me:9.1f} {me / float(r['model_std']):6.2f} "
            f"{100 * float(r['model_std']):5.1f} {float(r['mae']):6.2f} {float(r['max']):6.2f}"
        )
    print(
        "(points of SoC; z = error / std; std, MAE and max: the model's reading and the "
        "hybrid from it)"
    )
    for line in summary(rows):
        print(line)
    return 0


def summary(rows: list[dict[str, float | str]]) -> list[str]:
    """Per chemistry and split: each reading's mean and largest |error|, the starts within 2 std,
    and the hybrid's mean MAE and max from the model's reading."""
    out = []
    for chem, split in sorted({(str(r["chemistry"]), str(r["split"])) for r in rows}):
        g = [r for r in rows if r["chemistry"] == chem and r["split"] == split]
        ref = np.array([float(r["ref"]) for r in g])
        parts = []
        for key in ("curve", "model"):
            err = np.abs(np.array([float(r[key]) for r in g]) - ref)
            std = np.array([float(r[f"{key}_std"]) for r in g])
            parts.append(
                f"{key}: |error| mean {100 * err.mean():.2f} max {100 * err.max():.2f}, "
                f"within 2 std on {int(np.sum(err <= 2 * std))}"
            )
        line = f"{chem} {split} ({len(g)}): " + "; ".join(parts)
        mae = [float(r["mae"]) for r in g if not math.isnan(float(r["mae"]))]
        if mae:
            mx = [float(r["max"]) for r in g if not math.isnan(float(r["max"]))]
            good = sum(1 for r in g if float(r["mae"]) <= 1.0 and float(r["max"]) <= 3.0)
            line += (
                f"; hybrid from the model's start: mean MAE {np.mean(mae):.3f}, mean max "
                f"{np.mean(mx):.3f}, MAE <= 1 and max <= 3 on {good}"
            )
        out.append(line)
    return out


if __name__ == "__main__":
    sys.exit(main())
