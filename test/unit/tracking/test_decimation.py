"""A filter rate below the input rate (tracking/decimation.py, TrackerConfig.filter_period_s):
the charge counted exactly, every sample still estimated, a period at the sample period the
same as none, input faults still caught on every sample."""

from __future__ import annotations

import math

import numpy as np
import pytest
from conftest import REPO_ROOT, bag_path

from soc_estimator_ros.params import load_battery_params
from soc_estimator_ros.recordings import read_recording
from soc_estimator_ros.tracking import GateConfig, Sample, Tracker, TrackerConfig, Verdict
from soc_estimator_ros.tracking.decimation import Decimator
from soc_estimator_ros.units import NS_PER_S, SECONDS_PER_HOUR

SLA = load_battery_params(REPO_ROOT / "config" / "sla_12v5ah.yaml")
PERIOD_NS = NS_PER_S // 100  # a 100 Hz bridge


def load_steps(n: int) -> list[tuple[float, float]]:
    """(current A, voltage V) of 2-s load steps at 100 Hz, as node_latency.py sends."""
    out = []
    for k in range(n):
        current = 3.0 if (k // 200) % 2 else 12.0
        out.append((current, 12.6 - 0.02 * current))
    return out


def run(
    config: TrackerConfig, samples: list[tuple[float, float]], battery=SLA
) -> tuple[Tracker, list]:
    tracker = Tracker(battery, GateConfig.from_limits(battery.limits), config)
    results = [
        tracker.process(Sample(k * PERIOD_NS, i, v, 25.0)) for k, (i, v) in enumerate(samples)
    ]
    return tracker, results


def test_coulomb_counting_at_a_tenth_of_the_input_rate_counts_the_same_charge() -> None:
    samples = load_steps(3001)  # 30 s, 15 load steps
    every, _ = run(TrackerConfig(estimator="coulomb", initial_soc=0.9), samples)
    tenth, results = run(
        TrackerConfig(estimator="coulomb", initial_soc=0.9, filter_period_s=0.1), samples
    )
    # The same sums in another order: 3000 terms of ~1e-6 each, rounding ~1e-16 apiece.
    assert tenth.soc == pytest.approx(every.soc, abs=1e-12)
    steps = [r for r in results if r.filtered]
    assert len(steps) == 301  # the first sample, then one per 10 samples
    assert all(r.accepted for r in results)  # every sample estimated, step or not
    assert tenth.samples_used == every.samples_used == 3001


def test_between_steps_the_soc_moves_by_the_charge_counted_since() -> None:
    samples = [(12.0, 12.36)] * 15
    tracker, results = run(
        TrackerConfig(estimator="hybrid", initial_soc=0.9, filter_period_s=0.1), samples
    )
    step = results[10]
    assert step.filtered and not results[11].filtered
    for k in range(11, 15):  # k - 10 samples of 12 A for 0.01 s each since the step
        dq = 12.0 * 0.01 * (k - 10) / (SECONDS_PER_HOUR * SLA.capacity_ah)
        est = results[k].estimate
        # Sums of k - 10 products: rounding ~1e-17 against a SoC step of ~7e-6.
        assert est.soc == pytest.approx(step.estimate.soc - dq, abs=1e-14)
        assert est.soc_var == step.estimate.soc_var
        assert math.isnan(est.innovation_v) and not est.updated


def test_a_charge_between_steps_counts_at_the_charge_efficiency() -> None:
    samples = [(-3.0, 13.8)] * 15
    _, results = run(
        TrackerConfig(estimator="coulomb", initial_soc=0.5, filter_period_s=0.1), samples
    )
    eta = SLA.coulomb_efficiency_charge
    assert eta < 1.0  # the SLA file's charge efficiency, else this test shows nothing
    step = results[10].estimate
    dq = -3.0 * 0.01 * 3 / (SECONDS_PER_HOUR * SLA.capacity_ah)
    # Three samples of charge since the step, at the efficiency; the next step lands there.
    assert results[13].estimate.soc == pytest.approx(step.soc - eta * dq, abs=1e-14)
    ten = -3.0 * 0.1 * eta / (SECONDS_PER_HOUR * SLA.capacity_ah)
    assert step.soc == pytest.approx(0.5 - ten, abs=1e-12)


def test_a_period_of_one_sample_is_the_filter_on_every_sample() -> None:
    series = read_recording(bag_path("sla_field_run_1_full_rest"))  # 10 Hz
    n = 3000
    samples = list(zip(series.current_a[:n].tolist(), series.voltage_v[:n].tolist(), strict=True))
    socs = {}
    for period in (0.0, 0.1):
        tracker = Tracker(
            SLA,
            GateConfig.from_limits(SLA.limits),
            TrackerConfig(estimator="hybrid", initial_soc=0.95, filter_period_s=period),
        )
        out = []
        for k, (i, v) in enumerate(samples):
            r = tracker.process(Sample(int(series.t_s[k] * NS_PER_S), i, v, 25.0))
            out.append(r.estimate.soc)
        socs[period] = np.array(out)
    # One sample per interval: its held current is (i * dt) / dt, equal to i but for the
    # last bit; 3000 UKF steps keep that at rounding level.
    assert np.max(np.abs(socs[0.1] - socs[0.0])) < 1e-9


def test_a_bad_sample_between_steps_is_rejected_and_not_counted() -> None:
    samples = load_steps(25)
    samples[14] = (math.nan, 12.4)
    tracker, results = run(
        TrackerConfig(estimator="coulomb", initial_soc=0.9, filter_period_s=0.1), samples
    )
    assert results[14].verdict is not Verdict.ACCEPTED and results[14].estimate is None
    assert tracker.samples_used == 24
    assert all(r.estimate is not None and math.isfinite(r.estimate.soc) for r in results[15:])


def test_the_interval_summary() -> None:
    d = Decimator(0.1)
    assert d.add(0.0, 2.0, 12.0, (3.0, 3.0)) is not None  # the first sample is a step
    assert d.add(0.05, 4.0, 11.0, (2.9, 3.1)) is None
    interval = d.add(0.1, 6.0, 10.0, (2.8, 3.2))
    assert interval is not None
    # Held current: (2 A x 0.05 s + 4 A x 0.05 s) / 0.1 s; means over the two new samples.
    assert interval.held_current_a == pytest.approx(3.0, abs=1e-12)
    assert interval.mean_current_a == pytest.approx(5.0)
    assert interval.mean_voltage_v == pytest.approx(10.5)
    assert interval.mean_cell_voltage_v == pytest.approx((2.85, 3.15))
    assert d.add(0.15, 1.0, 12.0, ()) is None  # an interval without cell voltages
    assert d.add(0.2, 1.0, 12.0, (3.0, 3.0)).mean_cell_voltage_v == ()
    with pytest.raises(ValueError, match="filter period"):
        Decimator(0.0)
    with pytest.raises(ValueError, match="filter_period_s"):
        TrackerConfig(filter_period_s=-1.0)
