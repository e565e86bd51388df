"""A right start declared wide on LFP's plateau: what the exact posterior does with it.

The do-no-harm rule (issue 24) compares the hybrid, started at the true SoC with std 0.1, with
coulomb counting from the same start, which keeps it. On LFP's plateau a voltage reading cannot
tell one SoC from another within the model's own error, so Bayes' rule turns the reading into
"somewhere on the plateau": the prior truncated to the SoCs whose OCV matches the reading. Its
mean lies toward the plateau's middle, away from a start near its edge, even though the start
was exactly right and the reading exact.

For each start this prints that posterior, computed exactly on a grid (no filter, no
linearization): prior ``N(truth, start_std)`` on [0, 1], one reading ``V = OCV(truth)`` (the
voltage a perfect model would predict at the truth) with error std ``sigma_v``, and

    p(s | V) ~ N(s; truth, start_std) N(V - OCV(s); 0, sigma_v)

its mean less the truth (points of SoC: how far the best estimate in the mean-square sense
moves off a right start) and its std. ``sigma_v`` is what the voltage can tell at best: a
mission's many samples do not shrink it below the model's persistent error (the battery file's
``filters.hybrid.bias_std_v``, 20 mV for the LFP file: the default), since that error does not
average out. The shift stays until a knee or a long rest brings information; on the plateau a
shift above 1 point is a do-no-harm miss for any estimator that reads the voltage consistently.

    python benchmarks/studies/plateau_posterior.py [--battery config/lfp_12v6ah.yaml]
    python benchmarks/studies/plateau_posterior.py --corpus /work/corpus --chemistry lfp
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml

from soc_estimator_ros.estimators.hybrid import Hybrid
from soc_estimator_ros.models.ocv import OcvCurve
from soc_estimator_ros.params import BatteryParams, load_battery_params
from soc_estimator_ros.recordings import read_recording
from soc_estimator_ros.replay.run import battery_file_for
from soc_estimator_ros.resources import bundled_file

GRID = np.linspace(0.0, 1.0, 20_001)  # 0.005 point of SoC: finer than any table step here


@dataclass(frozen=True)
class Posterior:
    """The posterior's mean less the truth and its std (fractions of SoC)."""

    shift: float
    std: float


def posterior(ocv: OcvCurve, truth: float, start_std: float, sigma_v: float) -> Posterior:
    """The exact posterior of the module docstring on :data:`GRID`."""
    v = ocv.ocv_array(GRID)
    log_w = -0.5 * ((GRID - truth) / start_std) ** 2 - 0.5 * ((ocv.ocv(truth) - v) / sigma_v) ** 2
    w = np.exp(log_w - log_w.max())
    mean = float(np.sum(w * GRID) / np.sum(w))
    std = float(np.sqrt(np.sum(w * (GRID - mean) ** 2) / np.sum(w)))
    return Posterior(mean - truth, std)


def model_error_v(battery: BatteryParams) -> float:
    """The hybrid's persistent model error for ``battery`` (``bias_std_v``, file or default)."""
    tuning = Hybrid.merged_tuning(battery.filters.get("hybrid"))
    return float(tuning["bias_std_v"])


def starts(args: argparse.Namespace) -> list[tuple[str, str, float, BatteryParams]]:
    """(name, split, true start, battery file): the corpus' missions or the ``--truths``."""
    if args.corpus is None:
        battery = load_battery_params(args.battery)
        return [(f"start {t:.3f}", "-", t, battery) for t in args.truths]
    out = []
    for meta in sorted(args.corpus.glob("*/bag.yaml")):
        info = yaml.safe_load(meta.read_text()) or {}
        s = read_recording(meta.parent, max_samples=1)
        battery = load_battery_params(battery_file_for(s))
        if s.soc_ref is None or (args.chemistry and battery.chemistry != args.chemistry):
            continue
        out.append((meta.parent.name, str(info.get("split", "?")), float(s.soc_ref[0]), battery))
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--battery", type=Path, default=bundled_file("lfp"))
    ap.add_argument(
        "--truths",
        type=float,
        nargs="+",
        default=[0.3, 0.45, 0.55, 0.6, 0.646, 0.7, 0.75, 0.8, 0.9],
        help="true starts (SoC) without --corpus",
    )
    ap.add_argument("--corpus", type=Path, help="a directory of corpus missions: their starts")
    ap.add_argument("--chemistry", default="", help="only missions of this chemistry")
    ap.add_argument("--start-std", type=float, nargs="+", default=[0.1, 0.015])
    ap.add_argument(
        "--sigma-mv",
        type=float,
        nargs="+",
        help="the reading's std, mV (default: 5 and the file's hybrid bias_std_v)",
    )
    args = ap.parse_args()
    rows = starts(args)
    if not rows:
        print("plateau_posterior: no starts")
        return 1
    header = ["case", "split", "truth"]
    cols = []
    for std0 in args.start_std:
        for sig in args.sigma_mv or [5.0, None]:
            cols.append((std0, sig))
            label = "file" if sig is None else f"{sig:g}mV"
            header.append(f"std{std0:g}/{label}")
    print(
        f"{header[0]:<24} {header[1]:<10} {header[2]:>6} "
        + " ".join(f"{h:>16}" for h in header[3:])
    )
    for name, split, truth, battery in rows:
        ocv = battery.thevenin_model().ocv
        cells = []
        for std0, sig in cols:
            sigma_v = 1e-3 * sig if sig is not None else model_error_v(battery)
            p = posterior(ocv, truth, std0, sigma_v)
            cells.append(f"{100 * p.shift:+6.2f} ({100 * p.std:4.1f})")
        print(f"{name:<24} {split:<10} {truth:6.3f} " + " ".join(f"{c:>16}" for c in cells))
    print(
        "(posterior mean - truth, points of SoC, and its std in parentheses; 'file' = the "
        "battery file's filters.hybrid.bias_std_v as the reading's std)"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
