"""Every estimator on every bundled field run: the README's "Accuracy" table, printed.

Usage::

    python benchmarks/studies/accuracy_table.py [--jobs 2] [--bags bags]

Per estimator and chemistry, for each field run (in name order: run 1, run 2, cold run): MAE,
RMSE and max error (% SoC, after the 10-minute window, from the true start) and the time to
reach |error| < 2 % from starts 20 % above and 30 % below the truth (s; ``n/a`` where that
start is outside [0, 1], ``never`` where it is not reached). Initial SoC std 0.1 for every
start, as in ``test/test_accuracy.py``. About 7 minutes on 2 cores.
"""

from __future__ import annotations

import argparse
import math
import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]  # the checkout (its bags/ and config/)

from soc_estimator_ros.estimators import make_estimator  # noqa: E402
from soc_estimator_ros.evaluation import accuracy, run_estimator  # noqa: E402
from soc_estimator_ros.params import load_battery_params  # noqa: E402
from soc_estimator_ros.recordings import read_battery_bag  # noqa: E402

FILES = {"sla": ROOT / "config" / "sla_12v5ah.yaml", "lfp": ROOT / "config" / "lfp_12v6ah.yaml"}
ESTIMATORS = ("hybrid", "t2rc_ukf", "ekf", "dcc_ekf", "rc_kf", "coulomb")
OFFSETS = (0.0, 0.2, -0.3)
INITIAL_SOC_STD = 0.1


def job(args: tuple[str, str, float]) -> tuple[str, str, float, tuple[float, ...] | None]:
    bag, estimator, offset = args
    series = read_battery_bag(bag)
    battery = load_battery_params(FILES[Path(bag).name[:3]])
    soc0 = float(series.soc_ref[0]) + offset
    if not 0.0 <= soc0 <= 1.0:
        return bag, estimator, offset, None
    est = make_estimator(estimator, battery, soc0, INITIAL_SOC_STD)
    out = run_estimator(est, series)
    acc = accuracy(out.t_s, out.soc, series.soc_ref)
    return bag, estimator, offset, (acc.mae, acc.rmse, acc.max_abs, acc.t_converge_s)


def seconds(value: tuple[float, ...] | None) -> str:
    if value is None:
        return "n/a"
    return "never" if math.isinf(value[3]) else f"{value[3]:.0f}"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--bags", type=Path, default=ROOT / "bags")
    args = ap.parse_args()
    bags = sorted(str(p) for p in args.bags.glob("*field_run*"))
    if not bags:
        print(f"no field-run bags under {args.bags}")
        return 1
    jobs = [(b, e, o) for e in ESTIMATORS for b in bags for o in OFFSETS]
    res = {}
    with ProcessPoolExecutor(args.jobs) as ex:
        for bag, est, off, r in ex.map(job, jobs):
            res[(Path(bag).name, est, off)] = r
    print(
        "| Estimator | Chemistry | MAE (%) | RMSE (%) | max (%) "
        "| t < 2 % from +20 % (s) | from -30 % (s) |"
    )
    print("|---|---|---|---|---|---|---|")
    for est in ESTIMATORS:
        for chem in ("sla", "lfp"):
            runs = [Path(b).name for b in bags if Path(b).name.startswith(chem)]
            true = [res[(r, est, 0.0)] for r in runs]
            cols = [" / ".join(f"{100 * t[k]:.2f}" for t in true) for k in range(3)]
            up = " / ".join(seconds(res[(r, est, 0.2)]) for r in runs)
            down = " / ".join(seconds(res[(r, est, -0.3)]) for r in runs)
            print(f"| {est} | {chem.upper()} | {cols[0]} | {cols[1]} | {cols[2]} | {up} | {down} |")
    print("runs in each cell: " + ", ".join(Path(b).name for b in bags))
    return 0


if __name__ == "__main__":
    sys.exit(main())
