"""Offline replay throughput of each estimator on the bundled 10 Hz field runs, and peak RSS.

Samples per second and times real time of ``replay.run.replay_estimator`` (what ``soc_replay``
runs: the samples through the node's tracker and input gate), per estimator and bag, the best
of ``--repeat`` runs (the fastest run is the least disturbed one, as ``timeit`` takes it); the
process's peak RSS at the end. Target (issue "Replay and evaluation"): ``t2rc_ukf`` >= 1000x
real time at 10 Hz. Prints numbers, asserts nothing.

    python benchmarks/perf/replay_throughput.py [--bags sla_field_run_1_full_rest,...] [--repeat 3]
"""

from __future__ import annotations

import argparse
import math
import resource
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]  # the checkout (its bags/ and config/)

from soc_estimator_ros.estimators import ESTIMATORS  # noqa: E402
from soc_estimator_ros.params import load_battery_params  # noqa: E402
from soc_estimator_ros.recordings import read_battery_bag  # noqa: E402
from soc_estimator_ros.replay.run import battery_file_for, replay_estimator  # noqa: E402


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "--bags", default="sla_field_run_1_full_rest,lfp_field_run_1_full_rest", help="names"
    )
    ap.add_argument("--repeat", type=int, default=3, help="runs per estimator; the best counts")
    ap.add_argument("--estimators", default=",".join(sorted(ESTIMATORS)), help="names")
    args = ap.parse_args()
    print(f"{'bag':<28} {'estimator':<10} {'samples':>8} {'samples/s':>10} {'x_realtime':>10}")
    for name in args.bags.split(","):
        series = read_battery_bag(ROOT / "bags" / name)
        battery = load_battery_params(battery_file_for(series))
        span_s = float(series.t_s[-1] - series.t_s[0])
        for est_name in args.estimators.split(","):
            wall = math.inf
            for _ in range(args.repeat):
                t0 = time.perf_counter()
                replay_estimator(series, battery, est_name, "ref", name)
                wall = min(wall, time.perf_counter() - t0)
            rate = len(series) / wall
            print(
                f"{name:<28} {est_name:<10} {len(series):>8} {rate:>10.0f} {span_s / wall:>10.0f}"
            )
    rss_mib = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    print(f"peak RSS of this process: {rss_mib:.1f} MiB (numpy, scipy, filterpy, rosbags loaded)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
