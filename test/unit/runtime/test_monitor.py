"""runtime/monitor.py through the tracker: reports on a schedule of sample time, the state the
predictions read, FULL recalibrating the SoC, level events, and the SoC carried over silence."""

from __future__ import annotations

import math

import numpy as np
import pytest
from conftest import REPO_ROOT

from soc_estimator_ros.messages import RUNTIME_FIELDS, runtime_vector
from soc_estimator_ros.params import LevelSettings, load_battery_params
from soc_estimator_ros.runtime import BatteryLevel, ChargePhase, RuntimeConfig
from soc_estimator_ros.runtime.charging import FULL_SOC_STD
from soc_estimator_ros.tracking import GateConfig, Level, Sample, Tracker, TrackerConfig

SLA = load_battery_params(REPO_ROOT / "config" / "sla_12v5ah.yaml")
LFP = load_battery_params(REPO_ROOT / "config" / "lfp_12v6ah.yaml")
S = 1_000_000_000


def tracker(battery=SLA, estimator="hybrid", soc=0.8, **runtime) -> Tracker:
    config = TrackerConfig(estimator=estimator, initial_soc=soc, runtime=RuntimeConfig(**runtime))
    return Tracker(battery, GateConfig.from_limits(battery.limits), config)


def feed(tr: Tracker, samples, t0_ns=0):
    """(current A, voltage V) per 0.1 s; the results."""
    return [
        tr.process(Sample(t0_ns + k * S // 10, float(i), float(v), 25.0))
        for k, (i, v) in enumerate(samples)
    ]


def test_a_report_every_second_of_sample_time_with_every_field():
    tr = tracker()
    results = feed(tr, [(5.0, 12.2)] * 101)  # 10 s at 10 Hz
    reports = [r.runtime for r in results if r.runtime is not None]
    assert len(reports) == 11  # at 0 s and then every second
    last = reports[-1]
    assert set(last.fields()) == set(RUNTIME_FIELDS)
    assert len(runtime_vector(last.fields())) == len(RUNTIME_FIELDS)
    assert math.isfinite(last.time_to_empty_s) and last.time_to_empty_s > 0.0
    assert last.load_power_w == pytest.approx(5.0 * 12.2)
    assert math.isnan(last.time_to_full_s)  # not charging
    assert 0.0 < last.max_discharge_current_60s_a <= last.max_discharge_current_10s_a
    none = tracker(predict_period_s=0.0)
    assert all(r.runtime is None for r in feed(none, [(5.0, 12.2)] * 30))


def test_predictions_read_the_estimators_branch_voltages_else_the_models_own():
    """The hybrid's state holds v1_v, v2_v, bias_v and r_delta_ohm: the prediction reads them.
    Coulomb counting has none: the monitor runs the model's branches on the current itself, and they
    match the t2rc_ukf's prediction (the same model) to within its corrections."""
    samples = [(10.0, 12.0)] * 300
    hybrid = tracker(estimator="hybrid")
    feed(hybrid, samples)
    est = hybrid.last_estimate
    state = hybrid.runtime.pack_state(est, hybrid.estimator, 25.0)
    names = est.state_names
    assert state.branch_v == (est.x[names.index("v1_v")], est.x[names.index("v2_v")])
    assert state.bias_v == est.x[names.index("bias_v")]
    assert state.r_delta_ohm == est.x[names.index("r_delta_ohm")]
    coulomb = tracker(estimator="coulomb")
    feed(coulomb, samples)
    own = coulomb.runtime.pack_state(coulomb.last_estimate, coulomb.estimator, 25.0)
    model = SLA.thevenin_model()
    x = model.rested_state(0.8)
    for _ in range(299):  # the estimators' zero-order hold, from rest
        x = model.step(x, 10.0, 0.1, 25.0)
    np.testing.assert_allclose(own.branch_v, x[1:], rtol=1e-3)


def cc_cv(charge_a=3.0, seconds_cc=120.0, hold_s=70.0):
    """A synthetic CC-CV end on the LFP pack: CC at 13.8 V, CV at 14.4 V tapering, then the
    taper current at 14.4 V."""
    samples = [(-charge_a, 13.8)] * round(10 * seconds_cc)
    samples += [(-float(i), 14.4) for i in np.geomspace(charge_a, 0.25, 600)]
    samples += [(-0.2, 14.4)] * round(10 * hold_s)
    return samples


def test_full_recalibrates_the_soc_and_says_so():
    tr = tracker(LFP, soc=0.7)
    results, guarded_at_full = [], None
    for k, sample in enumerate(cc_cv()):
        results += feed(tr, [sample], t0_ns=k * S // 10)
        if guarded_at_full is None and any(
            "charge complete" in e.message for e in results[-1].events
        ):
            guarded_at_full = tr.estimator.guarded()
    done = [
        (k, e) for k, r in enumerate(results) for e in r.events if "charge complete" in e.message
    ]
    assert len(done) == 1
    full_at, event = done[0]
    assert event.level is Level.INFO and "recalibrated" in event.message
    est = results[full_at].estimate
    assert est.soc == 1.0
    # The hybrid publishes the guard's mixture (estimators/guard.py): its UKF and its count both
    # recalibrated to 1.0 with FULL_SOC_STD, the UKF's variance floored at the file's
    # model_soc_std (the model's persistent error), so d = 0, the two fused at the worst
    # correlation have the std (1 - a) FULL_SOC_STD + a floor, a the UKF's share, and the
    # variance is w fused^2 + (1 - w) FULL_SOC_STD^2 with the guard's weight w (rounding only).
    floor = max(FULL_SOC_STD, LFP.filters["hybrid"].get("model_soc_std", 0.0))
    w = guarded_at_full.model_weight
    a = FULL_SOC_STD**2 / (FULL_SOC_STD**2 + floor**2)
    fused = (1.0 - a) * FULL_SOC_STD + a * floor
    assert est.soc_var == guarded_at_full.soc_var
    assert est.soc_var == pytest.approx(w * fused**2 + (1.0 - w) * FULL_SOC_STD**2, rel=1e-12)
    assert tr.runtime.full and tr.runtime.charge.phase is ChargePhase.FULL
    assert tr.soc == pytest.approx(1.0, abs=1e-3)  # the estimator itself, on the next samples
    # During the charge the time to full was predicted, and it is 0 once full.
    during = [r.runtime.time_to_full_s for r in results[:full_at] if r.runtime is not None]
    assert any(math.isfinite(v) and v > 0 for v in during)
    after = [r.runtime for r in results[full_at:] if r.runtime is not None]
    assert after and after[-1].time_to_full_s == 0.0


def test_a_deferred_prediction_is_the_one_made_on_its_sample():
    """The node's monitor (``deferred``) takes a due prediction's inputs on its sample and
    computes it at ``flush`` (after the SoC is published): every report equals the synchronous
    one field for field, exactly (no tolerance: the same inputs through the same arithmetic),
    through a discharge, a CC-CV charge (time to full) and FULL."""
    now, later = tracker(LFP, soc=0.7), tracker(LFP, soc=0.7, deferred=True)
    samples = [(5.0, 13.0)] * 200 + list(cc_cv())
    made, flushed = [], []
    for k, sample in enumerate(samples):
        r_now = feed(now, [sample], t0_ns=k * S // 10)[0]
        r_later = feed(later, [sample], t0_ns=k * S // 10)[0]
        assert r_later.runtime is None
        report = later.runtime.flush()
        assert later.runtime.flush() is None  # computed once
        assert (report is None) == (r_now.runtime is None)
        if report is not None:
            made.append(r_now.runtime)
            flushed.append(report)
            assert later.runtime.report is report
    assert len(made) > 60
    assert any(math.isfinite(r.time_to_full_s) and r.time_to_full_s > 0 for r in made)
    assert made[-1].time_to_full_s == 0.0  # FULL reached
    # NaN fields (the time to full while discharging) compare equal as NaN in both.
    assert [repr(r) for r in flushed] == [repr(r) for r in made]


def test_level_changes_are_events_and_level_overrides_apply_at_once():
    tr = tracker(SLA, estimator="coulomb", soc=0.505, levels=LevelSettings(debounce_s=5.0))
    results = feed(tr, [(20.0, 11.8)] * 400)  # 40 s at 20 A: 0.505 -> 0.46
    messages = [e.message for r in results for e in r.events]
    assert any("battery level ok -> warn" in msg for msg in messages)
    assert tr.runtime.level is BatteryLevel.WARN
    tr.runtime.set_levels(LevelSettings(warn_soc=0.3, critical_soc=0.2))
    feed(tr, [(0.0, 12.1)], t0_ns=41 * S)
    assert tr.runtime.level is BatteryLevel.OK
    with pytest.raises(ValueError):
        tr.runtime.set_levels(LevelSettings(warn_soc=0.1, critical_soc=0.2))


def test_mission_power_replaces_the_window():
    tr = tracker(SLA)
    feed(tr, [(2.0, 12.4)] * 20)
    tr.runtime.set_mission_power(120.0)
    report = next(r.runtime for r in feed(tr, [(2.0, 12.4)] * 20, t0_ns=2 * S) if r.runtime)
    assert report.load_power_w == 120.0 and report.load_source == "mission"


def test_soc_carried_forward_grows_its_std_and_is_never_nan():
    clock = [100.0]
    config = TrackerConfig(estimator="coulomb", initial_soc=0.6, initial_soc_std=0.01)
    tr = Tracker(SLA, GateConfig.from_limits(SLA.limits), config, steady_clock=lambda: clock[0])
    assert tr.carried_forward(100.0)[2] == 0.0
    tr.process(Sample(0, 1.0, 12.3, 25.0))
    stds = []
    for silent in (0.0, 10.0, 100.0, 1e4, 1e7):
        soc, std, seconds = tr.carried_forward(100.0 + silent)
        assert soc == tr.soc and seconds == silent and math.isfinite(std)
        stds.append(std)
    assert stds == sorted(stds) and stds[0] == pytest.approx(0.01) and stds[-1] == 1.0
    gap = tr.estimator.time_policy.gap_current_std_a
    expected = math.sqrt(0.01**2 + (gap * 100.0 / 3600 / SLA.capacity_ah) ** 2)
    assert stds[2] == pytest.approx(expected)
