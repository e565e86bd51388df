"""Filter-steps per second of the batch engine (``batch/``) and of the per-sample path.

t2rc_ukf both ways, in one run: the batch engine with K lanes (the bundled recordings of one
chemistry, each under a grid of tunings: recordings x tunings) stepped in lock-step over
their first ``--steps`` samples; the per-sample path (``T2rcUkf`` through ``Estimator.step``,
filterpy's UKF, as ``soc_replay`` runs it without the tracker) over ``--samples`` samples of
the first recording. Each the best of ``--repeat`` runs (the least disturbed, as ``timeit``
takes it). Prints filter-steps/s of both by the wall clock and by the process's CPU time (on
a machine shared with other work the CPU time is what this process got; the wall clock is
what it waited), their ratios, and the largest SoC difference of a batch lane replaying the
per-sample run (a check that the two computed the same). NumPy's BLAS is not called in the
engine's step (its threads are irrelevant here).
Targets (issue 28): >= 10^6 filter-steps/s, >= 50x the per-sample path. Asserts nothing.

    python benchmarks/perf/batch_throughput.py [--lanes 4096] [--steps 300] [--chemistry lfp]
"""

from __future__ import annotations

import argparse
import math
import os
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]  # the checkout (its bags/ and config/)

from soc_estimator_ros.batch import BatchT2rcUkf, LaneInputs, UkfTuning, run_lanes  # noqa: E402
from soc_estimator_ros.estimators import make_estimator  # noqa: E402
from soc_estimator_ros.params import load_battery_params  # noqa: E402
from soc_estimator_ros.recordings import read_battery_bag  # noqa: E402

FILES = {"lfp": "lfp_12v6ah.yaml", "sla": "sla_12v5ah.yaml"}
DEFAULT_BAGS = {
    "lfp": "lfp_field_run_1_full_rest,lfp_aged75_m1,lfp_validation_1001,lfp_slow_discharge",
    "sla": "sla_field_run_1_full_rest,sla_validation_1003,sla_slow_discharge,sla_pulse_test",
}


def tuning_grid(base: UkfTuning, n: int) -> list[UkfTuning]:
    """``n`` tunings around ``base``: the measurement variance and the SoC process noise on
    log grids (lane 0 is ``base`` itself)."""
    out = []
    for i in range(n):
        f_r = 2.0 ** ((i % 16) / 4.0 - 2.0) if i else 1.0
        f_q = 10.0 ** ((i // 16 % 8) / 4.0 - 1.0) if i else 1.0
        q = (base.q_diag[0] * f_q, *base.q_diag[1:])
        out.append(UkfTuning(q, base.r_v2 * f_r, base.p0_v2, base.alpha, base.beta, base.kappa))
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--chemistry", choices=sorted(FILES), default="lfp")
    ap.add_argument("--bags", help="comma-separated bag names (default: four of the chemistry)")
    ap.add_argument("--lanes", type=int, default=4096, help="K, the batch engine's filters")
    ap.add_argument("--steps", type=int, default=300, help="lock-step steps of the batch run")
    ap.add_argument("--samples", type=int, default=3000, help="per-sample path's samples")
    ap.add_argument("--repeat", type=int, default=3, help="runs of each; the best counts")
    args = ap.parse_args()
    battery = load_battery_params(ROOT / "config" / FILES[args.chemistry])
    names = (args.bags or DEFAULT_BAGS[args.chemistry]).split(",")
    series = [read_battery_bag(ROOT / "bags" / name) for name in names]
    first = series[0]
    start = float(first.soc_ref[0]) if first.soc_ref is not None else 0.5

    # the per-sample path: one filter, one step per sample
    n = min(args.samples, len(first))
    ref_soc = np.empty(n)
    wall, cpu = math.inf, math.inf
    for _ in range(args.repeat):
        est = make_estimator("t2rc_ukf", battery, start, 0.05)
        t0, c0 = time.perf_counter(), time.process_time()
        for k in range(n):
            e = est.step(
                float(first.t_s[k]),
                float(first.current_a[k]),
                float(first.voltage_v[k]),
                float(first.temperature_c[k]),
            )
            ref_soc[k] = e.soc
        wall = min(wall, time.perf_counter() - t0)
        cpu = min(cpu, time.process_time() - c0)
    per_sample, per_sample_cpu = n / wall, n / cpu

    # the batch engine: K lanes = recordings x tunings, in lock-step
    k = args.lanes
    lane_rec = np.arange(k) % len(series)
    per_rec = -(-k // len(series))
    grid = tuning_grid(UkfTuning.of(battery.filters.get("t2rc_ukf")), per_rec)
    tunings = [grid[lane // len(series)] for lane in range(k)]
    steps = min(args.steps, min(len(s) for s in series))
    inputs = LaneInputs.from_series(series, lane_rec, max_samples=steps)
    soc0 = np.array([start if lane_rec[i] == 0 else 0.5 for i in range(k)])
    wall, cpu = math.inf, math.inf
    for _ in range(args.repeat):
        engine = BatchT2rcUkf(battery, soc0, 0.05, tunings)
        t0, c0 = time.perf_counter(), time.process_time()
        run_lanes(engine, inputs, keep=False)
        wall = min(wall, time.perf_counter() - t0)
        cpu = min(cpu, time.process_time() - c0)
    batch, batch_cpu = k * steps / wall, k * steps / cpu

    # check: lane 0 replays the per-sample run (recording 0, the file's tuning)
    check = BatchT2rcUkf(battery, np.array([start]))
    m = min(n, steps)
    run = run_lanes(check, LaneInputs.from_series([first], max_samples=m))
    assert run is not None
    diff = float(np.max(np.abs(run.soc[:, 0] - ref_soc[:m])))

    load = ", ".join(f"{v:.2f}" for v in os.getloadavg())
    print(f"battery {battery.name}; recordings {', '.join(names)}")
    print(f"cores {os.cpu_count()}, load average {load}")
    print(f"{'path':<12} {'filters':>8} {'steps':>7} {'steps/s (wall)':>15} {'steps/s (cpu)':>15}")
    print(f"{'per-sample':<12} {1:>8} {n:>7} {per_sample:>15.0f} {per_sample_cpu:>15.0f}")
    print(f"{'batch':<12} {k:>8} {steps:>7} {batch:>15.0f} {batch_cpu:>15.0f}")
    print(
        f"ratio batch / per-sample: {batch / per_sample:.1f}x wall, "
        f"{batch_cpu / per_sample_cpu:.1f}x cpu (targets: >= 1e6 steps/s, >= 50x)"
    )
    print(f"largest SoC difference, batch lane vs per-sample over {m} samples: {diff:.2e}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
