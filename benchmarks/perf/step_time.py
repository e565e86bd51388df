"""Per-step time of each estimator (microseconds, median and p99) and peak RSS.

Prints numbers; asserts nothing (speed is checked by reading these, never by timed tests).
Input: a bundled field-run bag when present, else a synthetic 10 Hz stream. The hybrid runs
twice, the second time without its wide start's grid (item 12, ``grid_soc_std_min: 0``), and
prints on how many steps the grid ran and the ratio of the two means, measured in one run.

    python benchmarks/perf/step_time.py [--steps N] [--bag bags/sla_field_run_1_full_rest] \
        [--battery config/sla_12v5ah.yaml] [--start-std 0.05]
"""

from __future__ import annotations

import argparse
import resource
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]  # the checkout (its bags/ and config/)

from soc_estimator_ros.estimators import ESTIMATORS, make_estimator  # noqa: E402
from soc_estimator_ros.params import load_battery_params  # noqa: E402


def load_input(bag: Path | None, steps: int):
    if bag is not None and bag.exists():
        from soc_estimator_ros.recordings import read_battery_bag

        s = read_battery_bag(bag)
        n = min(steps, len(s.t_s))
        return s.t_s[:n], s.current_a[:n], s.voltage_v[:n], f"bag {bag.name}"
    rng = np.random.default_rng(0)
    t = np.arange(steps) * 0.1
    current = np.repeat(rng.choice([0.0, 3.0, 12.0, 30.0], steps // 50 + 1), 50)[:steps]
    voltage = 12.7 - 0.03 * current - 0.5 * t / t[-1] + rng.normal(0, 0.004, steps)
    return t, current, voltage, "synthetic 10 Hz stream"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=20000)
    ap.add_argument("--bag", type=Path, default=ROOT / "bags" / "sla_field_run_1_full_rest")
    ap.add_argument("--battery", type=Path, default=ROOT / "config" / "sla_12v5ah.yaml")
    ap.add_argument("--start-std", type=float, default=0.05, help="the start's SoC std")
    args = ap.parse_args()
    battery = load_battery_params(args.battery)
    t, current, voltage, what = load_input(args.bag, args.steps)
    print(f"input: {what}, {len(t)} samples; battery: {battery.name}")
    print(f"{'estimator':<10} {'median_us':>10} {'p99_us':>10} {'x_realtime_10Hz':>16}")
    runs = [(name, None) for name in sorted(ESTIMATORS)]
    runs.append(("hybrid", {**battery.filters.get("hybrid", {}), "grid_soc_std_min": 0.0}))
    means: dict[str, float] = {}
    for name, tuning in runs:
        est = make_estimator(name, battery, 0.9, args.start_std, tuning=tuning)
        times = np.empty(len(t))
        gridded = 0
        clock = time.perf_counter_ns
        for k in range(len(t)):
            t0 = clock()
            est.step(float(t[k]), float(current[k]), float(voltage[k]))
            times[k] = clock() - t0
            gridded += getattr(est, "grid", None) is not None
        us = times / 1000.0
        mean_s = float(np.mean(times)) * 1e-9
        label = name if tuning is None else f"{name}, no grid"
        means[label] = mean_s
        print(
            f"{label:<10} {np.median(us):>10.1f} {np.percentile(us, 99):>10.1f} "
            f"{0.1 / mean_s:>16.0f}" + (f"  (grid on {gridded} steps)" if gridded else "")
        )
    ratio = means["hybrid"] / means["hybrid, no grid"]
    print(f"hybrid / hybrid without the grid, mean step: {ratio:.2f}")
    rss_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    print(f"peak RSS: {rss_mb:.1f} MiB")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
