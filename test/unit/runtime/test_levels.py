"""runtime/levels.py: thresholds from the battery file and the node, hysteresis, debounce."""

from __future__ import annotations

from dataclasses import replace

import pytest
from conftest import REPO_ROOT

from soc_estimator_ros.params import LevelSettings, load_battery_params
from soc_estimator_ros.runtime.levels import (
    DEFAULT_DEBOUNCE_S,
    DEFAULT_HYSTERESIS_SOC,
    BatteryLevel,
    LevelMonitor,
    LevelThresholds,
)

SLA = load_battery_params(REPO_ROOT / "config" / "sla_12v5ah.yaml")
LFP = load_battery_params(REPO_ROOT / "config" / "lfp_12v6ah.yaml")
OK, WARN, CRITICAL, EMERGENCY = (
    BatteryLevel.OK,
    BatteryLevel.WARN,
    BatteryLevel.CRITICAL,
    BatteryLevel.EMERGENCY,
)


def test_defaults_follow_soc_min():
    sla = LevelThresholds.resolve(SLA.limits, SLA.levels)
    assert (sla.warn_soc, sla.critical_soc, sla.emergency_soc) == pytest.approx((0.5, 0.4, 0.35))
    lfp = LevelThresholds.resolve(LFP.limits, LFP.levels)
    assert (lfp.warn_soc, lfp.critical_soc, lfp.emergency_soc) == pytest.approx((0.3, 0.2, 0.15))
    assert (lfp.hysteresis_soc, lfp.debounce_s) == (DEFAULT_HYSTERESIS_SOC, DEFAULT_DEBOUNCE_S)
    low = replace(SLA.limits, soc_min=0.02)
    assert LevelThresholds.resolve(low, SLA.levels).emergency_soc == 0.0  # clipped at 0


def test_battery_file_then_node_parameters_override_and_keep_the_order():
    file = LevelSettings(warn_soc=0.6, critical_soc=0.45, debounce_s=10.0)
    th = LevelThresholds.resolve(SLA.limits, file)
    assert (th.warn_soc, th.critical_soc, th.emergency_soc) == pytest.approx((0.6, 0.45, 0.40))
    assert th.debounce_s == 10.0
    node = LevelSettings(critical_soc=0.1)  # warn stays the file's; emergency follows critical
    th = LevelThresholds.resolve(SLA.limits, file, node)
    assert (th.warn_soc, th.critical_soc, th.emergency_soc) == pytest.approx((0.6, 0.1, 0.05))
    th = LevelThresholds.resolve(SLA.limits, LevelSettings(), node)
    assert th.warn_soc == pytest.approx(0.2)  # critical + 0.1 when nobody sets warn
    with pytest.raises(ValueError, match="warn >= critical >= emergency"):
        LevelThresholds.resolve(SLA.limits, LevelSettings(), LevelSettings(warn_soc=0.3))


def feed(monitor: LevelMonitor, points, dt=0.1):
    """(duration s, SoC) segments at 10 Hz from the monitor's last time; the changes made."""
    changes = []
    t = getattr(monitor, "_t", 0.0)
    for duration, soc in points:
        for _ in range(round(duration / dt)):
            change = monitor.update(t, soc)
            if change is not None:
                changes.append((t, change))
            t += dt
    monitor._t = t  # type: ignore[attr-defined]  # the test's clock
    return changes


def test_first_estimate_sets_the_level_at_once():
    th = LevelThresholds(0.5, 0.4, 0.35)
    m = LevelMonitor(th)
    change = m.update(0.0, 0.38)
    assert m.level is CRITICAL and change is not None and change.old is None
    m.reset()
    assert m.update(1.0, 0.9) is not None and m.level is OK


def test_a_sag_shorter_than_the_debounce_does_not_trip():
    """A burst pulls the estimate below warn for 2 s (or 29 s): no trip; 31 s: a trip, at the
    debounce, not before."""
    m = LevelMonitor(LevelThresholds(0.5, 0.4, 0.35, debounce_s=30.0))
    feed(m, [(10.0, 0.52)])
    assert feed(m, [(2.0, 0.49), (10.0, 0.52), (29.0, 0.49), (5.0, 0.51)]) == []
    assert m.level is OK
    changes = feed(m, [(31.0, 0.49)])
    assert [(c.old, c.new) for _, c in changes] == [(OK, WARN)]
    assert changes[0][1].held_s == pytest.approx(30.0, abs=0.11)


def test_a_rebound_at_rest_does_not_clear_and_a_real_rise_does():
    m = LevelMonitor(LevelThresholds(0.5, 0.4, 0.35, hysteresis_soc=0.02, debounce_s=30.0))
    feed(m, [(1.0, 0.395)])
    assert m.level is CRITICAL
    # At rest the estimate rebounds 1.5 points above the threshold for minutes: no clear.
    assert feed(m, [(600.0, 0.415)]) == []
    # Above the threshold + hysteresis, but only for 20 s: no clear.
    assert feed(m, [(20.0, 0.43), (5.0, 0.41)]) == []
    # A charge lifts it for good: cleared after the debounce, to the level the SoC is in.
    changes = feed(m, [(60.0, 0.43)])
    assert [(c.old, c.new) for _, c in changes] == [(CRITICAL, WARN)]
    changes = feed(m, [(60.0, 0.55)])
    assert [(c.old, c.new) for _, c in changes] == [(WARN, OK)]


def test_a_fast_fall_trips_to_the_level_the_soc_is_in():
    m = LevelMonitor(LevelThresholds(0.5, 0.4, 0.35, debounce_s=5.0))
    feed(m, [(1.0, 0.6)])
    changes = feed(m, [(10.0, 0.30)])
    assert [(c.old, c.new) for _, c in changes] == [(OK, EMERGENCY)]


def test_zero_debounce_changes_on_the_sample():
    m = LevelMonitor(LevelThresholds(0.5, 0.4, 0.35, hysteresis_soc=0.0, debounce_s=0.0))
    m.update(0.0, 0.6)
    assert m.update(0.1, 0.45) is not None and m.level is WARN
    assert m.update(0.2, 0.5) is not None and m.level is OK
