"""Every estimator on every bundled battery file, fed a seeded stream of plausible and bad
samples: bad values are rejected with their own verdict and change nothing, nothing raises and
no estimator fails, every estimate is a SoC in [0, 1] with a finite positive variance
(tracking/tracker.py, tracking/gate.py; the brief's "the node keeps running and loses no
state")."""

from __future__ import annotations

import math
import random
from collections import Counter
from pathlib import Path

import pytest
from conftest import REPO_ROOT

from soc_estimator_ros.estimators import ESTIMATORS
from soc_estimator_ros.params import BatteryParams, load_battery_params
from soc_estimator_ros.tracking import GateConfig, Sample, Tracker, TrackerConfig, Verdict
from soc_estimator_ros.units import NS_PER_S

BATTERY_FILES = sorted(
    p for p in (REPO_ROOT / "config").glob("*.yaml") if p.name != "soc_estimator_node.yaml"
)
N_SAMPLES = 800
T0_NS = 1_778_000_000 * NS_PER_S

#: A bad value and the verdict the gate must give it, whatever the stream did before.
VALUE_FAULTS = {
    "current_nan": Verdict.NON_FINITE,
    "voltage_inf": Verdict.NON_FINITE,
    "voltage_negative": Verdict.VOLTAGE_RANGE,
    "current_absurd": Verdict.CURRENT_RANGE,
    "absent": Verdict.NOT_PRESENT,
}


class Clock:
    """The receiver's steady clock, advanced by the stream."""

    def __init__(self) -> None:
        self.t_s = 100.0

    def __call__(self) -> float:
        return self.t_s


def _cells(rng: random.Random, voltage_v: float, n: int) -> tuple[float, ...]:
    """The cells' voltages about the pack's share, one of them sometimes NaN, absurd or
    missing (a cell's bad reading rejects that cell alone: cells/bank.py)."""
    cells = [voltage_v / n + rng.gauss(0.0, 0.01) for _ in range(n)]
    q = rng.random()
    if q < 0.05:
        cells[rng.randrange(n)] = math.nan
    elif q < 0.08:
        cells[rng.randrange(n)] = 99.0
    elif q < 0.1:
        cells.pop()
    return tuple(cells)


def _run(battery: BatteryParams, estimator: str, seed: int) -> Counter:
    """Feed the stream; assert per sample; return the faults injected, by kind."""
    rng = random.Random(seed)
    lim = battery.limits
    clock = Clock()
    config = TrackerConfig(
        estimator=estimator,
        initial_soc=rng.choice(["ocv", 0.5, 0.95]),
        health=rng.random() < 0.5,
        filter_period_s=rng.choice([0.0, 1.0]),
    )
    gate = GateConfig.from_limits(lim, stale_timeout_s=2.0, time_jump_s=10.0)
    tracker = Tracker(battery, gate, config, steady_clock=clock)
    stamp_ns = T0_NS
    current_a, voltage_v = 0.0, 0.5 * (lim.voltage_min_v + lim.voltage_max_v)
    injected: Counter = Counter()
    for _ in range(N_SAMPLES):
        # Periods from 1 ms to 5 s, now and then an hour or a day of silence.
        dt_s = rng.choice([0.001, 0.1, 0.1, 0.2, 1.0, 5.0])
        if rng.random() < 0.005:
            dt_s = rng.choice([3600.0, 86400.0])
        stamp_ns += int(dt_s * NS_PER_S)
        clock.t_s += dt_s
        current_a += rng.gauss(0.0, 0.5 * battery.capacity_ah)
        current_a = min(
            max(current_a, -0.9 * lim.current_max_charge_a), 0.9 * lim.current_max_discharge_a
        )
        voltage_v += rng.gauss(0.0, 0.02 * battery.cells_in_series)
        voltage_v = min(max(voltage_v, lim.voltage_min_v), lim.voltage_max_v)
        temperature_c = rng.choice([25.0, 10.0, -15.0, 45.0, math.nan, math.inf, 1e3])
        sample = Sample(stamp_ns, current_a, voltage_v, temperature_c)
        if battery.cells_in_series > 1 and rng.random() < 0.7:
            sample = Sample(
                stamp_ns,
                current_a,
                voltage_v,
                temperature_c,
                True,
                _cells(rng, voltage_v, battery.cells_in_series),
            )
        fault = (
            rng.choice([*VALUE_FAULTS, "stamp_back", "stamp_ahead"]) if rng.random() < 0.1 else None
        )
        if fault == "current_nan":
            sample = Sample(stamp_ns, math.nan, voltage_v, temperature_c)
        elif fault == "voltage_inf":
            sample = Sample(stamp_ns, current_a, math.inf, temperature_c)
        elif fault == "voltage_negative":
            sample = Sample(stamp_ns, current_a, -1.0, temperature_c)
        elif fault == "current_absurd":
            sample = Sample(stamp_ns, 1e6, voltage_v, temperature_c)
        elif fault == "absent":
            sample = Sample(stamp_ns, current_a, voltage_v, temperature_c, present=False)
        elif fault == "stamp_back":
            sample = Sample(
                stamp_ns - int(rng.choice([0.5, 5.0, 1e4]) * NS_PER_S), current_a, voltage_v
            )
        elif fault == "stamp_ahead":
            sample = Sample(
                stamp_ns + int(rng.choice([30.0, 1e5]) * NS_PER_S), current_a, voltage_v
            )
        if fault is not None:
            injected[fault] += 1
        before = (tracker.soc, tracker.soc_var, tracker.estimator)
        result = tracker.process(sample, clock_ns=int(clock.t_s * NS_PER_S))
        where = f"{battery.name}, {estimator}, seed {seed}, sample at {stamp_ns}"
        assert result.verdict not in (Verdict.ESTIMATOR_ERROR, Verdict.ESTIMATOR_DT), where
        assert not any(e.key == "estimator_error" for e in result.events), where
        if fault in VALUE_FAULTS:
            assert result.verdict is VALUE_FAULTS[fault], where
            assert (tracker.soc, tracker.soc_var, tracker.estimator) == before, where
        if result.estimate is not None:
            est = result.estimate
            assert 0.0 <= est.soc <= 1.0 and 0.0 < est.soc_var < math.inf, where
        if result.cells is not None:
            assert 0.0 <= result.cells.usable_soc <= 1.0, where
        assert math.isfinite(tracker.soc) and 0.0 < tracker.soc_var < math.inf, where
    return injected


@pytest.mark.parametrize("estimator", sorted(ESTIMATORS))
@pytest.mark.parametrize("path", BATTERY_FILES, ids=lambda p: Path(p).stem)
def test_bad_samples_are_rejected_and_change_nothing(path: Path, estimator: str) -> None:
    battery = load_battery_params(path)
    injected = _run(battery, estimator, seed=sum(map(ord, path.stem + estimator)))
    # The draw put every kind of fault in the stream (about 8 of each in 800 samples).
    assert set(injected) == {*VALUE_FAULTS, "stamp_back", "stamp_ahead"}
