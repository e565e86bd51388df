"""The tracker's OCV hysteresis (models/hysteresis.py): the state advanced on every accepted
sample, every consumer handed the voltage on the discharge branch, the start, the FULL and the
saved state."""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import pytest
from conftest import REPO_ROOT

from soc_estimator_ros.models.hysteresis import Hysteresis, HysteresisState
from soc_estimator_ros.params import load_battery_params
from soc_estimator_ros.tracking import GateConfig, Sample, SavedState, Tracker, TrackerConfig
from soc_estimator_ros.tracking.persistence import load_state, resume_decision, save_state
from soc_estimator_ros.units import NS_PER_S

LFP = load_battery_params(REPO_ROOT / "config" / "lfp_12v6ah.yaml")
HYST = Hysteresis(gap_v=0.08, rate_per_soc=50.0)
T0_NS = 1_778_000_000 * NS_PER_S
PERIOD_S = 0.1


def tracker(battery=LFP, **config) -> Tracker:
    cfg = TrackerConfig(**{"estimator": "hybrid", "initial_soc": 0.5, **config})
    return Tracker(battery, GateConfig.from_limits(battery.limits), cfg)


def profile() -> list[tuple[float, float]]:
    """(current A, voltage V): a charge at 3 A, a rest, a discharge at 6 A, a rest; the
    voltage moving with the current as a pack's would (the numbers need not be a model's)."""
    out = []
    for k in range(3000):
        i = -3.0 if k < 900 else 0.0 if k < 1500 else 6.0 if k < 2600 else 0.0
        out.append((i, 13.25 - 0.03 * i + 1e-5 * (k % 97)))
    return out


def run(t: Tracker, samples, k0: int = 0) -> list:
    """The samples at 10 Hz, the first one ``k0`` periods after T0."""
    return [
        t.process(Sample(T0_NS + round(k * PERIOD_S * NS_PER_S), i, v, 25.0))
        for k, (i, v) in enumerate(samples, start=k0)
    ]


def test_a_zero_gap_changes_nothing_to_the_bit() -> None:
    plain, zero = tracker(), tracker(replace(LFP, hysteresis=Hysteresis(0.0, 50.0)))
    for a, b in zip(run(plain, profile()), run(zero, profile()), strict=True):
        assert a.estimate.soc == b.estimate.soc and a.estimate.soc_var == b.estimate.soc_var
    assert plain.hysteresis is None and zero.hysteresis is not None


def test_the_estimator_reads_the_voltage_on_the_discharge_branch() -> None:
    t = tracker(replace(LFP, hysteresis=HYST), initial_branch=0.0)
    seen: list[float] = []
    step = t.estimator.step

    def spy(t_s, current_a, voltage_v, *args, **kw):
        seen.append(voltage_v)
        return step(t_s, current_a, voltage_v, *args, **kw)

    t.estimator.step = spy  # type: ignore[method-assign]
    samples = profile()[:900]  # the charge alone
    run(t, samples)
    # The state by the model's own step along the same held currents: 899 steps of 3 A
    # charging for 0.1 s (the first sample starts it).
    state = HysteresisState(0.0, 0.0)
    for i, _ in samples[:-1]:
        state = HYST.step(state, i, PERIOD_S, LFP.capacity_ah, LFP.coulomb_efficiency_charge)
    assert t.hysteresis is not None
    assert t.hysteresis.branch == pytest.approx(state.branch, abs=1e-12)  # float sums: 1e-12
    assert 0.4 < state.branch < 0.9  # 0.075 Ah into 6 Ah at rate 50: b = 1 - exp(-0.62 eta)
    assert seen[-1] == pytest.approx(samples[-1][1] - HYST.gap_v * state.branch, abs=1e-12)
    assert seen[0] == samples[0][1]  # on the discharge branch at the start: no offset


def test_the_ocv_start_reads_the_discharge_branch_with_the_state_uncertainty() -> None:
    t = tracker(replace(LFP, hysteresis=HYST))  # start unknown: midway, std 1/2
    model = LFP.thevenin_model()
    soc, std = t.soc_from_ocv(13.30)
    std_v = math.hypot(t.config.ocv_voltage_std_v, HYST.gap_v / 2.0)
    want, want_std = model.soc_at_terminal_voltage(13.30 - 0.04, 0.0, std_v, None)
    assert soc == pytest.approx(min(max(want, 0.0), 1.0), abs=1e-12)
    assert std == pytest.approx(want_std, abs=1e-12)


def test_the_state_is_saved_and_resumed(tmp_path: Path) -> None:
    battery = replace(LFP, hysteresis=HYST)
    t = tracker(battery, initial_branch=0.0)
    run(t, profile()[:900])
    saved = t.saved_state()
    assert saved is not None and saved.hysteresis == t.hysteresis
    path = tmp_path / "state.yaml"
    save_state(path, saved)
    assert load_state(path).hysteresis == saved.hysteresis

    def resume(now_s: float):
        return resume_decision(path, now_s, 3600.0, battery.name)

    again = Tracker(
        battery,
        GateConfig.from_limits(battery.limits),
        TrackerConfig(estimator="hybrid", initial_soc="resume"),
        resume=resume,
    )
    assert again.hysteresis == HysteresisState.unknown()  # before the first sample
    again.process(Sample(T0_NS + 1000 * NS_PER_S, 0.0, 13.3, 25.0))
    assert again.hysteresis == saved.hysteresis


def test_a_state_file_without_hysteresis_still_loads(tmp_path: Path) -> None:
    path = tmp_path / "state.yaml"
    save_state(path, SavedState(0.5, 1e-4, 1.0, "hybrid", LFP.name))
    assert load_state(path).hysteresis is None
    text = path.read_text() + "hysteresis: {branch: 1.5, var: 0.0}\n"
    path.write_text(text)
    with pytest.raises(Exception, match="branch in \\[0, 1\\]"):
        load_state(path)


def test_an_unknown_start_widens_the_filter_reading_until_the_current_settles_it() -> None:
    t = tracker(replace(LFP, hysteresis=HYST))
    samples = profile()
    run(t, samples[:1])
    assert t.estimator.voltage_offset_var_v2 == pytest.approx(HYST.gap_v**2 / 4.0, rel=1e-12)
    run(t, samples[1:900], k0=1)
    # 899 steps of 3 A held for 0.1 s: var(b) = exp(-2 gamma dz) / 4, dz the charge stored.
    dz = 899 * 0.1 * 3.0 * LFP.coulomb_efficiency_charge / (3600.0 * LFP.capacity_ah)
    want = HYST.gap_v**2 * math.exp(-2.0 * HYST.rate_per_soc * dz) / 4.0
    assert t.estimator.voltage_offset_var_v2 == pytest.approx(want, rel=1e-9)  # float sums


def test_a_full_charge_puts_the_pack_on_the_charge_branch() -> None:
    t = tracker(replace(LFP, hysteresis=HYST), initial_branch=0.0)
    run(t, profile()[:10])
    t._recalibrate(1.0, 0.01)  # what the runtime monitor's FULL calls
    assert t.hysteresis == HysteresisState(1.0, 0.0)


def test_across_a_gap_the_state_moves_by_the_charge_the_soc_counts() -> None:
    t = tracker(replace(LFP, hysteresis=HYST), initial_branch=1.0)
    run(t, [(0.2, 13.1)])
    # Ten minutes of silence between an idle 0.2 A and 0.0 A: the estimators count the mean,
    # 0.1 A, over the gap (estimators/base.py), and so does the hysteresis.
    t.process(Sample(T0_NS + 600 * NS_PER_S, 0.0, 13.1, 25.0))
    want = HYST.step(HysteresisState(1.0, 0.0), 0.1, 600.0, LFP.capacity_ah)
    assert t.hysteresis is not None
    assert t.hysteresis.branch == pytest.approx(want.branch, abs=1e-15)
