"""runtime/prediction.py: state of power, time to empty and to full, the load window, each
checked against the package's own Thevenin model run in the time domain (ROS-free)."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from conftest import REPO_ROOT

from soc_estimator_ros.models.thevenin import TemperatureExtrapolation
from soc_estimator_ros.params import load_battery_params
from soc_estimator_ros.runtime.prediction import (
    EARLY_POWER_REL_STD,
    MISSION_POWER_REL_STD,
    SOP_CONFIDENCE_K,
    LoadForecast,
    PackState,
    PowerWindow,
    cv_onset_soc,
    max_current_a,
    prediction_std_v,
    state_of_power,
    steady_voltage_v,
    terminal_path_v,
    time_to_empty,
    time_to_full,
)

SLA = load_battery_params(REPO_ROOT / "config" / "sla_12v5ah.yaml")
LFP = load_battery_params(REPO_ROOT / "config" / "lfp_12v6ah.yaml")


def drive(model, x, z, current_a, seconds, dt=0.1, temperature_c=25.0):
    """The model itself, stepped at ``dt`` (parameters re-read every step): the state, the
    surface lag and the terminal voltage after ``seconds`` of ``current_a``."""
    for _ in range(round(seconds / dt)):
        soc = float(x[0])
        x = model.step(x, current_a, dt, temperature_c)
        z = model.surface_step(z, current_a, dt, soc)
    return x, z, model.terminal_voltage(x, current_a, temperature_c, sum(z))


def loaded_state(model, soc, current_a, seconds, temperature_c=25.0, soc_std=0.0):
    """A pack after ``seconds`` of ``current_a`` from rest at ``soc``: (x, z, PackState); the
    state known exactly (no margin in the state of power) unless ``soc_std`` is given."""
    x, z, _ = drive(model, model.rested_state(soc), model.surface_rest(), current_a, seconds)
    state = PackState(
        soc=float(x[0]),
        soc_std=soc_std,
        branch_v=tuple(float(v) for v in x[1:]),
        surface_z=tuple(z),
        temperature_c=temperature_c,
    )
    return x, z, state


@pytest.mark.parametrize(
    ("battery", "soc", "pre_a", "pre_s"),
    [(SLA, 0.6, 0.0, 0.0), (SLA, 0.5, 8.0, 120.0), (LFP, 0.3, 0.0, 0.0), (LFP, 0.4, 15.0, 60.0)],
)
@pytest.mark.parametrize("horizon_s", [10.0, 60.0])
def test_max_discharge_current_ends_at_the_voltage_limit_through_the_model(
    battery, soc, pre_a, pre_s, horizon_s
):
    """Draw the state of power's current through the model for the horizon: the terminal
    voltage ends at limits.voltage_min_v within 1 % (the issue's check; it is far closer), and
    5 % more current ends below it."""
    model = battery.thevenin_model()
    lim = battery.limits
    x, z, state = loaded_state(model, soc, pre_a, pre_s)
    i_max = max_current_a(model, state, horizon_s, lim.voltage_min_v, 1000.0)
    assert 0.0 < i_max < 1000.0  # the voltage limit binds, not the cap
    _, _, v_end = drive(model, x, z, i_max, horizon_s)
    assert abs(v_end - lim.voltage_min_v) <= 0.01 * lim.voltage_min_v
    # Closer still: what is left is the state of power's coarser steps (3 per half horizon).
    assert abs(v_end - lim.voltage_min_v) <= 0.005 * lim.voltage_min_v
    _, _, v_more = drive(model, x, z, 1.05 * i_max, horizon_s)
    assert v_more < lim.voltage_min_v


@pytest.mark.parametrize("horizon_s", [10.0, 60.0])
def test_an_uncertain_state_keeps_its_margin_to_the_limit(horizon_s):
    """With the estimate's stds the current drawn through the model ends SOP_CONFIDENCE_K
    std of the predicted voltage above the limit, and a state with no uncertainty gets more
    current."""
    model = SLA.thevenin_model()
    lim = SLA.limits
    x, z, exact = loaded_state(model, 0.5, 8.0, 120.0)
    # The SLA hybrid's stds at 47 % SoC in the state-of-power study (docs/accuracy.md).
    state = replace(
        exact, soc_std=0.03, branch_std_v=(0.0016, 0.004), bias_std_v=0.01, r_delta_std_ohm=0.001
    )
    i_max = max_current_a(model, state, horizon_s, lim.voltage_min_v, 1000.0)
    assert 0.0 < i_max < max_current_a(model, exact, horizon_s, lim.voltage_min_v, 1000.0)
    margin_v = SOP_CONFIDENCE_K * float(prediction_std_v(model, state, np.array([i_max]))[0])
    by_hand = math.sqrt(
        (model.ocv.slope(state.soc) * 0.03) ** 2
        + 0.0016**2
        + 0.004**2
        + 0.01**2
        + (i_max * 0.001) ** 2
    )
    assert margin_v == pytest.approx(SOP_CONFIDENCE_K * by_hand, rel=1e-12)
    assert margin_v > 0.05  # else the margin would be lost in the tolerance below
    _, _, v_end = drive(model, x, z, i_max, horizon_s)
    # 2 mV: the search's interpolation and its 3 steps per half horizon against the 0.1-s
    # drive (0.1 mV here as measured), against a margin of 88-90 mV.
    assert abs(v_end - (lim.voltage_min_v + margin_v)) <= 0.002


@pytest.mark.parametrize(("battery", "soc"), [(SLA, 0.8), (LFP, 0.9)])
def test_max_charge_current_ends_at_the_voltage_limit_through_the_model(battery, soc):
    model = battery.thevenin_model()
    lim = battery.limits
    x, z, state = loaded_state(model, soc, 0.0, 0.0)
    i_max = max_current_a(model, state, 10.0, lim.voltage_max_v, 1000.0, charge=True)
    assert 0.0 < i_max < 1000.0
    _, _, v_end = drive(model, x, z, -i_max, 10.0)
    assert abs(v_end - lim.voltage_max_v) <= 0.01 * lim.voltage_max_v


def test_state_of_power_is_capped_by_the_current_limits_and_shrinks_with_the_horizon():
    model = SLA.thevenin_model()
    _, _, state = loaded_state(model, 0.95, 0.0, 0.0)
    sop = state_of_power(model, SLA.limits, state)
    # SLA: 5 A of charge never lifts the model to 14.7 V: the file's charge limit binds.
    assert sop.max_charge_current_10s_a == SLA.limits.current_max_charge_a
    assert sop.max_discharge_current_60s_a <= sop.max_discharge_current_10s_a
    _, _, low = loaded_state(model, 0.45, 0.0, 0.0)
    sop_low = state_of_power(model, SLA.limits, low)
    assert sop_low.max_discharge_current_10s_a < sop.max_discharge_current_10s_a


@pytest.mark.parametrize("battery", [SLA, LFP])
def test_state_of_power_does_not_go_beyond_the_fitted_currents(battery):
    """A full pack the model says could give the file's 60 A for 10 s: the prediction stops at
    the highest current the model was fitted at (the file's envelope), exactly; a file that
    records no envelope keeps the old cap, the file's limit."""
    model = battery.thevenin_model()
    envelope_a = model.fitted_current_max_a
    assert battery.thevenin.fitted_c_rate_max is not None  # soc_identify writes it
    assert envelope_a == battery.thevenin.fitted_c_rate_max * battery.capacity_ah
    assert envelope_a < battery.limits.current_max_discharge_a  # else nothing is tested
    _, _, state = loaded_state(model, 0.95, 0.0, 0.0)
    unrecorded = replace(battery.thevenin, fitted_c_rate_max=None)
    free = state_of_power(battery.thevenin_model(unrecorded), battery.limits, state)
    assert free.max_discharge_current_10s_a == battery.limits.current_max_discharge_a
    sop = state_of_power(model, battery.limits, state)
    assert sop.max_discharge_current_10s_a == envelope_a
    assert sop.max_discharge_current_60s_a <= envelope_a
    assert sop.max_charge_current_10s_a <= min(envelope_a, battery.limits.current_max_charge_a)


def test_a_pack_already_below_the_limit_can_deliver_nothing():
    model = SLA.thevenin_model()
    state = PackState(soc=0.05, soc_std=0.01, branch_v=(0.5, 0.5))
    assert max_current_a(model, state, 10.0, SLA.limits.voltage_min_v, 60.0) == 0.0


def with_arrhenius(battery):
    """``battery`` with an activation energy: its resistances grow by the Arrhenius law below
    the identified temperatures (models/thevenin.py)."""
    ea = TemperatureExtrapolation(activation_energy_j_per_mol=30_000.0)
    return replace(battery, thevenin=replace(battery.thevenin, extrapolation=ea))


#: (battery, temperature degC): inside the identified range (2-28 degC), and 32 degC below it
#: with Ea (every resistance 5.6x at 30 kJ/mol: arithmetic without the law reads volts off).
MODEL_CASES = [(LFP, 25.0), (SLA, 25.0), (with_arrhenius(LFP), -30.0), (with_arrhenius(SLA), -30.0)]


@pytest.mark.parametrize(("battery", "temperature_c"), MODEL_CASES)
def test_terminal_path_is_the_models_own_step_and_output(battery, temperature_c):
    """One step per interval: exactly TheveninModel.step, surface_step and terminal_voltage,
    elementwise over the currents, at the state's temperature; row 0 is the voltage the
    instant the current starts."""
    model = battery.thevenin_model()
    x, z, state = loaded_state(model, 0.5, 5.0, 30.0, temperature_c)
    if temperature_c < 0.0:  # else nothing here tests the law
        assert model.resistance_factor(temperature_c) > 2.0
    currents = np.array([0.0, 5.0, 20.0, -4.0])
    grid = terminal_path_v(model, state, currents, (0.0, 10.0), substeps=1)
    assert grid.shape == (2, 4)
    t = temperature_c
    for k, i in enumerate(currents):
        # 2e-5 V: ocv_array's interpolation of the cubic (models/ocv.py: below 10 uV).
        assert grid[0, k] == pytest.approx(model.terminal_voltage(x, i, t, sum(z)), abs=2e-5)
        x1 = model.step(x, i, 10.0, t)
        z1 = model.surface_step(z, i, 10.0, float(x[0]))
        assert grid[1, k] == pytest.approx(model.terminal_voltage(x1, i, t, sum(z1)), abs=2e-5)


@pytest.mark.parametrize(("battery", "temperature_c"), MODEL_CASES)
def test_steady_voltage_is_the_models_voltage_after_a_long_hold(battery, temperature_c):
    """``V_ss(s, I)``: the model's terminal voltage with every branch at ``R_i I_i`` and the
    lag at its steady value, from the scalar methods (the temperature law included)."""
    model = battery.thevenin_model()
    soc = np.array([0.15, 0.5, 0.5, 0.9, 0.9])
    currents = np.array([3.0, 0.0, 12.0, -2.0, 20.0])
    v = steady_voltage_v(model, soc, currents, temperature_c)
    for k, (s, i) in enumerate(zip(soc.tolist(), currents.tolist(), strict=True)):
        branches = [model.branch_at(j, s, temperature_c)[0] for j in range(model.n_rc)]
        drives = [b.drive_a(s, i, temperature_c) for b in model.params.branches]
        x = np.array([s, *(r * d for r, d in zip(branches, drives, strict=True))])
        lag = model.params.surface_lag
        z = 0.0 if lag is None else sum(lag.step((0.0,) * lag.n_modes, i, math.inf, s))
        want = model.terminal_voltage(x, i, temperature_c, z)
        assert v[k] == pytest.approx(want, abs=2e-5)  # the interpolation's, as above


# -- time to empty -----------------------------------------------------------------------------
def constant_power_time_domain(battery, soc0, soc_end, power_w, dt=1.0):
    """The model discharged at constant power in the time domain (the current set each step
    from the last terminal voltage): seconds until the SoC reaches ``soc_end``."""
    model = battery.thevenin_model()
    x, z = model.rested_state(soc0), model.surface_rest()
    v = model.terminal_voltage(x, 0.0, 25.0)
    t = 0.0
    while x[0] > soc_end:
        i = power_w / v
        soc = float(x[0])
        x = model.step(x, i, dt, 25.0)
        z = model.surface_step(z, i, dt, soc)
        v = model.terminal_voltage(x, i, 25.0, sum(z))
        t += dt
    return t


@pytest.mark.parametrize(("battery", "soc0", "power_w"), [(SLA, 0.9, 30.0), (LFP, 0.8, 40.0)])
def test_time_to_empty_equals_the_model_discharged_at_constant_power(battery, soc0, power_w):
    """The SoC integral of 3600 Q / I(s), I from P = I V_ss(s, I), against the model run at
    constant power in the time domain (its branches settling after the start): within 1 %."""
    model = battery.thevenin_model()
    soc_min = battery.limits.soc_min
    state = PackState(soc=soc0, soc_std=0.0, branch_v=(0.0,) * model.n_rc, temperature_c=25.0)
    tte = time_to_empty(model, state, soc_min, LoadForecast(power_w, 0.0, 5, 60.0))
    reference = constant_power_time_domain(battery, soc0, soc_min, power_w)
    assert tte.time_s == pytest.approx(reference, rel=0.01)
    # At constant power the current rises as the voltage falls.
    assert tte.current_end_a > tte.current_now_a
    assert tte.time_s < (soc0 - soc_min) * 3600 * battery.capacity_ah / tte.current_now_a


def test_time_to_empty_std_has_the_soc_part_and_the_load_part():
    model = SLA.thevenin_model()
    state = PackState(soc=0.8, soc_std=0.02, branch_v=(0.0, 0.0), temperature_c=25.0)
    quiet = LoadForecast(30.0, 0.0, 5, 60.0)  # a load with no spread: the SoC's part only
    tte = time_to_empty(model, state, 0.4, quiet)
    assert tte.load_part_s == 0.0
    assert tte.std_s == pytest.approx(3600 * SLA.capacity_ah * 0.02 / tte.current_now_a)
    # The load's part is |dT/dP| sigma_P, dT/dP as the finite difference of the time.
    spread = LoadForecast(30.0, 6.0, 5, 60.0)
    tte = time_to_empty(model, state, 0.4, spread)
    up = time_to_empty(model, state, 0.4, LoadForecast(30.3, 0.0, 5, 60.0)).time_s
    down = time_to_empty(model, state, 0.4, LoadForecast(29.7, 0.0, 5, 60.0)).time_s
    dt_dp = (up - down) / 0.6
    assert tte.load_part_s == pytest.approx(abs(dt_dp) * spread.power_std_w(tte.time_s), rel=1e-3)
    assert tte.std_s == pytest.approx(math.hypot(tte.soc_part_s, tte.load_part_s))


def test_time_to_empty_special_cases():
    model = SLA.thevenin_model()
    state = PackState(soc=0.7, soc_std=0.01, branch_v=(0.0, 0.0))
    idle = time_to_empty(model, state, 0.4, LoadForecast(1.0), min_power_w=1.2)
    assert idle.time_s == math.inf and idle.note == "no discharge load"
    charging = time_to_empty(model, state, 0.4, LoadForecast(-20.0))
    assert charging.time_s == math.inf
    low = time_to_empty(model, replace(state, soc=0.39), 0.4, LoadForecast(30.0))
    assert low.time_s == 0.0 and math.isfinite(low.std_s)
    # A power the pack cannot deliver near empty ends the time where it stops delivering.
    huge = time_to_empty(model, state, 0.4, LoadForecast(600.0, 0.0, 5, 60.0))
    assert "not deliverable" in huge.note and huge.time_s >= 0.0


# -- load window ---------------------------------------------------------------------------------
def test_power_window_mean_and_block_spread():
    w = PowerWindow(300.0, 5)
    for k in range(3001):  # 300 s at 10 Hz, 100 W then 20 W every other minute
        t = 0.1 * k
        w.add(t, 100.0 if int(t // 60) % 2 == 0 else 20.0)
    f = w.forecast()
    assert f.blocks == 5 and f.block_s == 60.0
    assert f.power_w == pytest.approx((3 * 100 + 2 * 20) / 5, rel=1e-3)
    assert f.block_std_w == pytest.approx(np.std([100, 20, 100, 20, 100], ddof=1), rel=1e-3)
    sigma = f.power_std_w(3600.0)
    assert sigma == pytest.approx(f.block_std_w * math.sqrt(1 / 5 + 60 / 3600))


def test_power_window_skips_gaps_and_keeps_only_its_blocks():
    w = PowerWindow(100.0, 5)  # 20-s blocks
    for k in range(1000):  # 100 s at 50 W
        w.add(0.1 * k, 50.0)
    w.add(1000.0, 999.0)  # a 900-s gap: not counted
    w.add(1000.1, 10.0)  # 999 W held for 0.1 s
    f = w.forecast()
    assert f.power_w == pytest.approx((50.0 * 99.9 + 999.0 * 0.1) / 100.0, rel=1e-9)
    for k in range(2, 2001):  # 200 s at 10 W: the old blocks leave the window
        w.add(1000.0 + 0.1 * k, 10.0)
    f = w.forecast()
    assert f.power_w == pytest.approx(10.0) and f.blocks == 5


def test_early_and_mission_forecast_std():
    w = PowerWindow(300.0, 5)
    w.add(0.0, 40.0)
    w.add(1.0, 40.0)
    f = w.forecast()
    assert f.blocks == 0 and f.power_std_w(1000.0) == EARLY_POWER_REL_STD * 40.0
    assert LoadForecast(50.0, source="mission").power_std_w(1e4) == MISSION_POWER_REL_STD * 50
    assert PowerWindow(300.0).forecast().source == "none"


# -- time to full --------------------------------------------------------------------------------
def cc_cv_time_domain(battery, soc0, current_a, v_cv, taper_a, dt=1.0):
    """The model charged CC at ``current_a`` to ``v_cv``, then CV (the current solved each
    step so the terminal voltage stays at ``v_cv``) until it tapers to ``taper_a``: seconds."""
    model = battery.thevenin_model()
    x, z = model.rested_state(soc0), model.surface_rest()
    t, i = 0.0, -current_a
    cv = False
    while t < 10 * 3600:
        if not cv:
            soc = float(x[0])
            x_new = model.step(x, i, dt, 25.0)
            z_new = model.surface_step(z, i, dt, soc)
            if model.terminal_voltage(x_new, i, 25.0, sum(z_new)) >= v_cv:
                cv = True
                continue
        else:
            lo, hi = -current_a, 0.0  # bisection: the current that ends the step at v_cv
            for _ in range(50):
                mid = 0.5 * (lo + hi)
                xm = model.step(x, mid, dt, 25.0)
                zm = model.surface_step(z, mid, dt, float(x[0]))
                if model.terminal_voltage(xm, mid, 25.0, sum(zm)) > v_cv:
                    lo = mid
                else:
                    hi = mid
            i = 0.5 * (lo + hi)
            if -i <= taper_a:
                return t
            x_new = model.step(x, i, dt, 25.0)
            z_new = model.surface_step(z, i, dt, float(x[0]))
        x, z, t = x_new, z_new, t + dt
    raise AssertionError("no CV end within 10 h")


def test_time_to_full_against_a_cc_cv_charge_of_the_model():
    """LFP from 60 % at 3 A (0.5 C) to 14.4 V, tapering to 0.3 A: the CC phase's time is the
    SoC's span over the current, the taper is the model's quasi-static time constant; the two
    together within 10 % of the model charged in the time domain."""
    model = LFP.thevenin_model()
    v_cv, taper = 14.4, 0.05 * LFP.nominal_capacity_ah
    state = PackState(soc=0.6, soc_std=0.01, branch_v=(0.0, 0.0), temperature_c=25.0)
    predicted = time_to_full(model, state, 3.0, v_cv, taper, in_cv=False)
    reference = cc_cv_time_domain(LFP, 0.6, 3.0, v_cv, taper)
    assert predicted == pytest.approx(reference, rel=0.10)
    # In CV now: only the taper (and the hold) remains.
    s_cv = cv_onset_soc(model, 0.6, 3.0, v_cv, 25.0)
    assert 0.9 < s_cv < 1.0
    at_cv = replace(state, soc=s_cv)
    left = time_to_full(model, at_cv, 3.0, v_cv, taper, in_cv=True, hold_left_s=60.0)
    assert 60.0 < left < predicted


def test_sla_model_never_reaches_the_charge_voltage_below_full():
    """The SLA file's circuit has no gassing overvoltage: at 1 A its voltage stays far below
    14.4 V up to a full pack, so the CV phase is taken to start at SoC 1 (a lower bound)."""
    model = SLA.thevenin_model()
    grid = np.linspace(0.5, 1.0, 11)
    v = steady_voltage_v(model, grid, np.full_like(grid, -1.0), 25.0)
    assert v.max() < 14.0
    assert cv_onset_soc(model, 0.5, 1.0, 14.4, 25.0) == 1.0
    state = PackState(soc=0.5, soc_std=0.01, branch_v=(0.0, 0.0), temperature_c=25.0)
    cc = 0.5 * 3600 * SLA.capacity_ah / (SLA.coulomb_efficiency_charge * 1.0)
    assert time_to_full(model, state, 1.0, 14.4, 0.25, in_cv=False) > cc
