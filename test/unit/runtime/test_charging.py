"""runtime/charging.py: the charge voltage rule, CC confirmation, FULL at a CC-CV end, and
what never looks like one (regenerative braking, a full LFP pack at rest)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from conftest import REPO_ROOT

from soc_estimator_ros import messages as m
from soc_estimator_ros.params import ChargeSettings, load_battery_params
from soc_estimator_ros.runtime.charging import (
    CHARGE_CONFIRM_S,
    TERMINATION_TAPER_FACTOR,
    ChargeMonitor,
    ChargePhase,
    ChargeSpec,
)

SLA = load_battery_params(REPO_ROOT / "config" / "sla_12v5ah.yaml")
LFP = load_battery_params(REPO_ROOT / "config" / "lfp_12v6ah.yaml")


def spec(battery=LFP, **settings) -> ChargeSpec:
    b = replace(battery, charge=ChargeSettings(**settings)) if settings else battery
    return ChargeSpec.resolve(b, charging_current_a=0.5, idle_current_a=0.1)


def test_charge_voltage_rule_and_file_key():
    sla, lfp = spec(SLA), spec(LFP)
    assert sla.voltage_v == pytest.approx(14.4) and "0.05 V x 6 cells" in sla.voltage_source
    assert lfp.voltage_v == pytest.approx(14.4) and "0.05 V x 4 cells" in lfp.voltage_source
    assert sla.voltage_tolerance_v == pytest.approx(0.15)
    assert lfp.voltage_tolerance_v == pytest.approx(0.10)
    assert sla.taper_current_a == pytest.approx(0.25)  # 0.05 C of 5 Ah
    assert lfp.taper_current_a == pytest.approx(0.30)
    custom = spec(LFP, voltage_v=14.2, voltage_tolerance_v=0.05, taper_c_rate=0.02, hold_s=10)
    assert custom.voltage_v == 14.2 and custom.voltage_source == "battery file charge.voltage_v"
    assert (custom.voltage_tolerance_v, custom.hold_s) == (0.05, 10)
    assert custom.taper_current_a == pytest.approx(0.12)


def run(monitor: ChargeMonitor, segments, t0=0.0, dt=0.1):
    """(duration s, current A core sign, voltage V) at 10 Hz; the changes and the phases."""
    changes, phases = [], []
    t = t0
    for duration, current, voltage in segments:
        for _ in range(round(duration / dt)):
            change = monitor.update(t, current, voltage)
            if change is not None:
                changes.append(change.kind)
            phases.append(monitor.phase)
            t += dt
    return changes, phases, t


def test_a_cc_cv_charge_ends_in_full_and_full_holds_until_the_pack_discharges():
    cm = ChargeMonitor(spec(LFP))
    taper = np.geomspace(3.0, 0.2, 50)
    segments = [(120.0, -3.0, 13.6), (60.0, -3.0, 14.2)]  # CC
    segments += [(4.0, -float(i), 14.4) for i in taper]  # CV: the current tapers at 14.4 V
    segments += [(61.0, -0.15, 14.4)]  # below the taper current for the hold
    changes, phases, t = run(cm, segments)
    assert changes == ["confirmed", "full"]
    assert ChargePhase.CC in phases and ChargePhase.CV in phases and cm.full
    # A 40 mA-noise sensor around zero at float: FULL stays.
    rng = np.random.default_rng(1)
    float_noise = [(0.1, float(x), 14.4) for x in rng.normal(0.0, 0.04, 600)]
    changes, _, t = run(cm, float_noise, t0=t)
    assert changes == [] and cm.full
    # Off the dock: the electronics' 0.35 A discharge releases it within seconds.
    changes, phases, t = run(cm, [(5.0, 0.35, 13.3)], t0=t)
    assert changes == ["released"] and not cm.full
    assert phases.index(ChargePhase.NONE) < 30  # 3 s: the low-pass, not the first sample


def cc_cv_to(end_a: float) -> list[tuple[float, float, float]]:
    """A CC phase at 3 A, then the CV phase at 14.4 V tapering to ``end_a`` (charge, A) at
    1 Hz with a 40 mA-noise sensor (the corpus' current sensor)."""
    rng = np.random.default_rng(3)
    segments = [(120.0, -3.0, 13.6), (60.0, -3.0, 14.2)]
    taper = np.geomspace(3.0, end_a, 90) + rng.normal(0.0, 0.04, 90)
    return segments + [(1.0, -float(i), 14.4) for i in taper]


@pytest.mark.parametrize(
    ("after", "expected"),
    [
        ((30.0, 0.0, 13.6), ["confirmed", "full"]),  # the charger off, the robot parked
        ((30.0, 8.0, 13.2), ["confirmed", "full", "released"]),  # driving away at once
    ],
)
def test_a_charger_that_stops_at_its_taper_ends_in_full(after, expected):
    """The usual CC-CV charger stops the moment its reading reaches the taper (0.30 A here):
    the pack is never below the taper for the hold, and the end is still a full pack."""
    cm = ChargeMonitor(spec(LFP))
    changes, phases, _ = run(cm, [*cc_cv_to(0.30), after], dt=1.0)
    assert changes == expected
    assert ChargePhase.CV in phases and phases[-1] is (
        ChargePhase.FULL if after[1] <= 0.1 else ChargePhase.NONE
    )


def test_the_stop_read_through_a_filter_interval_is_full():
    """With filter_rate_hz the monitor reads interval means: the interval holding the stop is
    half the CV end, half the charger off (0.15 A at 14.0 V, out of the band)."""
    cm = ChargeMonitor(spec(LFP))
    changes, _, _ = run(cm, [*cc_cv_to(0.30), (1.0, -0.15, 14.0), (5.0, 0.0, 13.6)], dt=1.0)
    assert changes == ["confirmed", "full"]


def test_a_charge_interrupted_in_its_cv_phase_is_not_full():
    """Off the dock at 0.6 A, above TERMINATION_TAPER_FACTOR x the taper (0.45 A): not full."""
    assert 0.6 > TERMINATION_TAPER_FACTOR * spec(LFP).taper_current_a
    cm = ChargeMonitor(spec(LFP))
    changes, _, _ = run(cm, [*cc_cv_to(0.6), (30.0, 0.0, 13.6), (10.0, 2.0, 13.2)], dt=1.0)
    assert changes == ["confirmed", "released"] and not cm.full


def test_a_new_charge_releases_full_at_once():
    cm = ChargeMonitor(spec(LFP, hold_s=5.0))
    _, _, t = run(cm, [(40.0, -2.0, 13.8), (6.0, -0.1, 14.4)])
    assert cm.full
    changes, _, _ = run(cm, [(0.1, -1.0, 14.45)], t0=t)
    assert changes == ["released"] and not cm.full
    assert m.supply_status(1.0, 0.1, 0.5, full=cm.full) == m.STATUS_CHARGING


def test_regenerative_braking_at_full_never_confirms_a_charge():
    """A full LFP pack (14.4 V at rest, the CV band) braking downhill: 1-4 A of charge for
    1-4 s between stretches of driving, then resting at 14.4 V with a noisy zero current."""
    cm = ChargeMonitor(spec(LFP))
    rng = np.random.default_rng(2)
    segments = []
    for _ in range(200):
        segments.append((float(rng.uniform(1, 4)), -float(rng.uniform(1, 4)), 14.45))
        segments.append((float(rng.uniform(1, 10)), float(rng.uniform(0.35, 6)), 13.9))
    segments += [(0.1, float(x), 14.40) for x in rng.normal(0.0, 0.04, 3000)]
    changes, phases, _ = run(cm, segments)
    assert changes == [] and set(phases) == {ChargePhase.NONE}


def test_a_charge_that_stops_before_the_taper_is_not_full():
    cm = ChargeMonitor(spec(LFP))
    changes, _, _ = run(
        cm, [(CHARGE_CONFIRM_S + 5, -3.0, 13.6), (30.0, -1.5, 14.4), (10.0, 2.0, 13.2)]
    )
    assert changes == ["confirmed", "released"] and not cm.full


def test_status_rule_agrees_with_nav2_docking_on_every_current():
    """CHARGING exactly when the current (ROS sign) is above 0.5 A, what Nav2's docking plugin
    reads; a CV taper below it is NOT_CHARGING; FULL and UNKNOWN override."""
    for current in np.linspace(-3.0, 3.0, 601):
        status = m.supply_status(float(current), 0.1, 0.5)
        assert (status == m.STATUS_CHARGING) == (current > 0.5)
        if current < -0.1:
            assert status == m.STATUS_DISCHARGING
    assert m.supply_status(0.3, 0.1, 0.5) == m.STATUS_NOT_CHARGING
    assert m.supply_status(0.05, 0.1, 0.5, full=True) == m.STATUS_FULL
    assert m.supply_status(2.0, 0.1, 0.5, full=True, stale=True) == m.STATUS_UNKNOWN
