"""State of power against the physics model: is the predicted 10-s (60-s) current real?

Issue 27's target: the largest discharge current the node predicts for the next 10 s
(``max_discharge_current_10s_a``) is not exceeded by more than 5 % by the current that really
takes the pack to ``limits.voltage_min_v`` in that time. The truth comes from the simulator
that made the bags (PyBaMM, ``tools/make_bags.PackSim``; dev-only, run this with the sim venv
of bags/README.md), never from the estimator's own equivalent circuit:

* a pack of the bundled kind (``PACKS``) at an ambient temperature is driven by a seeder-like
  duty cycle (:data:`DUTY`: bursts, cruising, a stop) from full, its samples measured through
  the bundled bags' sensors (``SensorModel.draw``, a fixed seed per case), and fed, sample by
  sample, to the tracker as the node runs it (the hybrid from the true start with std 0.1,
  the runtime monitor predicting every second);
* at every checkpoint (the end of a cruise once the true SoC has fallen past each of
  :data:`CHECK_SOCS`) the monitor's last prediction is read, and the simulation is copied
  (``copy.deepcopy``: the solver state at that instant) to find, by bisection, the largest
  constant current whose terminal voltage stays at or above ``voltage_min_v`` over the
  horizon (sampled every 0.1 s), capped at ``limits.current_max_discharge_a`` as the
  prediction is;
* printed: predicted vs true current, their ratio (the target: at most 1.05), and the lowest
  voltage the pack really reaches when the predicted current is drawn.

Nothing here is tuned: the battery files and the node's defaults as bundled; the cases were
fixed before the first run. Ambient 25 and 5 degC lie inside the files' identified
temperatures, 0 degC just outside (SLA, LFP identified at 5 and 25 degC).

    /tmp/sim/bin/python benchmarks/studies/state_of_power.py [--cases lfp:25 sla:5 ...]

About 2-5 minutes per case on one core (SLA's full model is the slower).
"""

from __future__ import annotations

import argparse
import copy
import math
import sys
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "tools"))

import make_bags as mb  # noqa: E402

from soc_estimator_ros.params import BatteryParams, load_battery_params  # noqa: E402
from soc_estimator_ros.replay.run import INITIAL_SOC_STD  # noqa: E402
from soc_estimator_ros.resources import bundled_file  # noqa: E402
from soc_estimator_ros.tracking import GateConfig, Sample, Tracker, TrackerConfig  # noqa: E402

#: The duty cycle, in C of the pack's nominal capacity, repeated from full: (duration s, C).
#: The checkpoint is the end of the cruise (a planner asks before the next climb).
DUTY = ((30.0, 2.0), (20.0, 4.0), (120.0, 0.6), (60.0, 0.01))
CRUISE_END = 2  # index in DUTY after which a checkpoint may be taken
CHECK_SOCS = (0.9, 0.7, 0.5, 0.35, 0.25)
RATE_HZ = 10.0
HORIZONS_S = (10.0, 60.0)
#: Bisection steps: a bracket of 60 A halved 12 times is 15 mA wide.
BISECT_STEPS = 12
SEED = 4100  # the sensors' draw; a case's index is added
TARGET_RATIO = 1.05
CASES = ("lfp:25", "lfp:5", "lfp:0", "sla:25", "sla:5", "sla:0")


@dataclass(frozen=True)
class Check:
    """One checkpoint: what the node predicted, what the physics allows."""

    soc_true: float
    soc_est: float
    temperature_c: float
    horizon_s: float
    predicted_a: float
    true_a: float
    v_min_at_predicted_v: float

    @property
    def ratio(self) -> float:
        return self.predicted_a / self.true_a if self.true_a > 0.0 else math.inf


def lowest_voltage_v(sim: mb.PackSim, current_a: float, horizon_s: float) -> float:
    """The lowest terminal voltage of a copy of ``sim`` holding ``current_a`` for
    ``horizon_s`` (-inf when the solver stops: the cell fell through its 1.5 V event)."""
    trial = copy.deepcopy(sim)
    times = trial.t_s + np.arange(1, int(round(horizon_s * 10.0)) + 1) / 10.0
    times = np.minimum(times, trial.t_s + horizon_s - 1e-6)
    try:
        v, _, _ = trial.segment(horizon_s, current_a, times)
    except Exception:  # noqa: BLE001 (a solver failure under the load is a voltage collapse)
        return -math.inf
    return float(np.min(v))


def true_max_current_a(sim: mb.PackSim, battery: BatteryParams, horizon_s: float) -> float:
    """The largest constant current over ``horizon_s`` within ``voltage_min_v`` (bisection,
    capped at ``current_max_discharge_a``)."""
    limit_v = battery.limits.voltage_min_v
    hi = battery.limits.current_max_discharge_a
    if lowest_voltage_v(sim, hi, horizon_s) >= limit_v:
        return hi
    lo = 0.0
    for _ in range(BISECT_STEPS):
        mid = 0.5 * (lo + hi)
        if lowest_voltage_v(sim, mid, horizon_s) >= limit_v:
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi)


def run_case(case: str) -> list[Check]:
    """One pack and ambient: the duty cycle from full, a check at each SoC of CHECK_SOCS."""
    chem, temp_text = case.split(":")
    ambient_c = float(temp_text)
    pack = mb.PACKS[chem]
    battery = load_battery_params(bundled_file(chem))
    q_ah = pack.pack_capacity_ah
    rng = np.random.default_rng(SEED + CASES.index(case) if case in CASES else SEED)
    sensors = mb.SensorModel.draw(rng)
    sim = mb.PackSim(pack, ambient_c)
    capacity_ah = battery.capacity_ah  # the SoC of a checkpoint: charge out of the file's
    config = TrackerConfig(estimator="hybrid", initial_soc=1.0, initial_soc_std=INITIAL_SOC_STD)
    tracker = Tracker(battery, GateConfig.from_limits(battery.limits), config)
    checks: list[Check] = []
    pending = [s for s in CHECK_SOCS if s > battery.limits.soc_min - 0.05]
    report = None
    stamp0_ns = 1_700_000_000 * 10**9
    while pending:
        for k, (duration_s, c_rate) in enumerate(DUTY):
            current_a = c_rate * q_ah
            times = np.round(sim.t_s + np.arange(int(round(duration_s * RATE_HZ))) / RATE_HZ, 6)
            v, q, temp = sim.segment(duration_s, current_a, times)
            i_m, v_m, t_m = sensors.measure(rng, np.full(times.size, current_a), v, temp)
            for j in range(times.size):
                r = tracker.process(
                    Sample(stamp0_ns + int(round(times[j] * 1e9)), i_m[j], v_m[j], t_m[j])
                )
                if r.runtime is not None:
                    report = r.runtime
            soc_true = 1.0 - float(q[-1]) / capacity_ah
            limits = battery.limits
            if soc_true < limits.soc_min - 0.02 or sim.last_v < limits.voltage_min_v:
                return checks
            if k != CRUISE_END or not pending or soc_true > pending[0] or report is None:
                continue
            pending.pop(0)
            predicted = {
                10.0: report.max_discharge_current_10s_a,
                60.0: report.max_discharge_current_60s_a,
            }
            for h in HORIZONS_S:
                true_a = true_max_current_a(sim, battery, h)
                checks.append(
                    Check(
                        soc_true,
                        report.soc,
                        float(temp[-1]),
                        h,
                        predicted[h],
                        true_a,
                        lowest_voltage_v(sim, predicted[h], h),
                    )
                )
    return checks


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", nargs="+", default=list(CASES), help="chemistry:ambient_c")
    ap.add_argument("--jobs", type=int, default=1)
    args = ap.parse_args()
    with ProcessPoolExecutor(max(1, args.jobs)) as pool:
        results = list(pool.map(run_case, args.cases))
    print(
        f"{'case':<8} {'SoC true':>8} {'est':>6} {'temp C':>6} {'h s':>4} {'pred A':>7} "
        f"{'true A':>7} {'ratio':>6} {'V at pred':>9}"
    )
    worst = 0.0
    for case, checks in zip(args.cases, results, strict=True):
        for c in checks:
            worst = max(worst, c.ratio)
            print(
                f"{case:<8} {c.soc_true:8.3f} {c.soc_est:6.3f} {c.temperature_c:6.1f} "
                f"{c.horizon_s:4.0f} {c.predicted_a:7.2f} {c.true_a:7.2f} {c.ratio:6.3f} "
                f"{c.v_min_at_predicted_v:9.3f}"
            )
    print(
        f"(ratio = predicted / true largest current within voltage_min_v; target <= "
        f"{TARGET_RATIO}; worst {worst:.3f})"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
