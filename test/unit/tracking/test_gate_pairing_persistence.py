"""The node's ROS-free parts: input gate, current/voltage pairing, state persistence (no rclpy)."""

from __future__ import annotations

import math
import os
from pathlib import Path

import pytest
import yaml
from conftest import REPO_ROOT

from soc_estimator_ros.params import load_battery_params
from soc_estimator_ros.tracking.gate import REJECTIONS, GateConfig, InputGate, Verdict
from soc_estimator_ros.tracking.pairing import ScalarPairer
from soc_estimator_ros.tracking.persistence import (
    SavedState,
    StateFileError,
    load_state,
    resume_decision,
    save_state,
)

SLA = REPO_ROOT / "config" / "sla_12v5ah.yaml"
S = 1_000_000_000  # ns per s
T0 = 1_778_151_600 * S


@pytest.fixture(scope="module")
def limits():
    return load_battery_params(SLA).limits


@pytest.fixture()
def gate(limits) -> InputGate:
    return InputGate(GateConfig.from_limits(limits, stale_timeout_s=2.0))


# -- input gate ------------------------------------------------------------------------------
def test_gate_thresholds_come_from_the_battery_limits(limits) -> None:
    cfg = GateConfig.from_limits(limits)
    assert cfg.voltage_min_v == pytest.approx(0.5 * limits.voltage_min_v)
    assert cfg.voltage_max_v == pytest.approx(1.5 * limits.voltage_max_v)
    assert cfg.current_max_discharge_a == pytest.approx(2.0 * limits.current_max_discharge_a)
    assert cfg.current_max_charge_a == pytest.approx(2.0 * limits.current_max_charge_a)
    override = GateConfig.from_limits(limits, voltage_min_v=9.0, voltage_max_v=16.0)
    assert (override.voltage_min_v, override.voltage_max_v) == (9.0, 16.0)


def test_gate_rejects_bad_configs() -> None:
    with pytest.raises(ValueError, match="voltage_max_v"):
        GateConfig(12.0, 10.0, 1.0, 1.0)
    with pytest.raises(ValueError, match="current"):
        GateConfig(5.0, 20.0, 0.0, 1.0)
    with pytest.raises(ValueError, match="stale_timeout_s"):
        GateConfig(5.0, 20.0, 1.0, 1.0, stale_timeout_s=0.0)
    with pytest.raises(ValueError, match="finite"):
        GateConfig(math.nan, 20.0, 1.0, 1.0)


def test_gate_accepts_a_normal_stream(gate: InputGate) -> None:
    for k in range(10):
        assert gate.check(T0 + k * S // 10, 2.0, 12.4) is Verdict.ACCEPTED
    assert gate.accepted_count == 10 and gate.rejected_count == 0
    assert gate.newest_stamp_ns == T0 + 9 * S // 10


@pytest.mark.parametrize(
    ("kwargs", "verdict"),
    [
        ({"present": False}, Verdict.NOT_PRESENT),
        ({"voltage_v": math.nan}, Verdict.NON_FINITE),
        ({"current_a": math.inf}, Verdict.NON_FINITE),
        ({"current_a": -math.inf}, Verdict.NON_FINITE),
        ({"voltage_v": 80.0}, Verdict.VOLTAGE_RANGE),
        ({"voltage_v": 3.0}, Verdict.VOLTAGE_RANGE),
        ({"current_a": 121.0}, Verdict.CURRENT_RANGE),  # > 2 x 60 A discharge
        ({"current_a": -10.5}, Verdict.CURRENT_RANGE),  # > 2 x 5 A charge
        ({"stamp_ns": T0 + S - 3 * S}, Verdict.STALE),  # 3 s before the newest
        ({"stamp_ns": T0 + S - S // 2}, Verdict.OUT_OF_ORDER),
        ({"stamp_ns": T0 + S}, Verdict.DUPLICATE),
    ],
)
def test_gate_rejects_each_kind_and_changes_nothing(
    gate: InputGate, kwargs: dict, verdict: Verdict
) -> None:
    assert gate.check(T0 + S, 1.0, 12.4) is Verdict.ACCEPTED
    sample = {"stamp_ns": T0 + 2 * S, "current_a": 1.0, "voltage_v": 12.4, "present": True}
    sample.update(kwargs)
    assert gate.check(**sample) is verdict
    assert not verdict.accepted
    assert gate.counts[verdict] == 1
    assert gate.rejected_count == 1
    assert gate.newest_stamp_ns == T0 + S  # a rejection never moves the newest stamp
    # The stream continues normally afterwards.
    assert gate.check(T0 + 3 * S, 1.0, 12.4) is Verdict.ACCEPTED


def test_gate_limits_are_inclusive(gate: InputGate, limits) -> None:
    cfg = gate.config
    assert gate.check(T0, 1.0, cfg.voltage_max_v) is Verdict.ACCEPTED
    assert gate.check(T0 + 1, cfg.current_max_discharge_a, 12.0) is Verdict.ACCEPTED
    assert gate.check(T0 + 2, -cfg.current_max_charge_a, 12.0) is Verdict.ACCEPTED


def test_gate_stale_against_the_clock(gate: InputGate) -> None:
    assert gate.check(T0, 1.0, 12.4, now_ns=T0 + S) is Verdict.ACCEPTED
    assert gate.check(T0 + S, 1.0, 12.4, now_ns=T0 + 4 * S) is Verdict.STALE
    # Without a clock the same sample is fine.
    assert gate.check(T0 + S, 1.0, 12.4) is Verdict.ACCEPTED


def test_gate_first_check_wins_and_record_counts_outside_verdicts(gate: InputGate) -> None:
    # Absent and NaN: "not present" is checked first.
    assert gate.check(T0, math.nan, 12.4, present=False) is Verdict.NOT_PRESENT
    assert gate.evaluate(T0, 1.0, 12.4) is Verdict.ACCEPTED
    assert gate.accepted_count == 0  # evaluate() counts nothing
    gate.record(Verdict.ESTIMATOR_DT)
    assert gate.counts[Verdict.ESTIMATOR_DT] == 1
    assert set(REJECTIONS) == set(Verdict) - {Verdict.ACCEPTED}


# -- pairing ---------------------------------------------------------------------------------
def test_pairing_within_tolerance() -> None:
    p = ScalarPairer(pair_tolerance_s=0.05)
    assert p.add_current(T0, 2.0) is None
    sample = p.add_voltage(T0 + 10_000_000, 12.3)
    assert sample is not None
    assert (sample.stamp_ns, sample.current_a, sample.voltage_v) == (T0 + 10_000_000, 2.0, 12.3)
    assert p.paired == 1 and p.dropped == 0
    # Voltage first works too; the stamp is the later receive time.
    assert p.add_voltage(T0 + S, 12.2) is None
    sample = p.add_current(T0 + S + 1_000, 1.5)
    assert sample is not None and sample.stamp_ns == T0 + S + 1_000


def test_pairing_newest_wins_and_old_readings_are_dropped() -> None:
    p = ScalarPairer(pair_tolerance_s=0.05)
    p.add_current(T0, 1.0)
    p.add_current(T0 + 10_000_000, 2.0)  # replaces the first (newest wins)
    sample = p.add_voltage(T0 + 20_000_000, 12.0)
    assert sample is not None and sample.current_a == 2.0
    assert p.dropped == 1
    # A reading older than the tolerance is not paired with a much later one.
    p.add_current(T0 + S, 3.0)
    assert p.add_voltage(T0 + S + 200_000_000, 12.1) is None
    assert p.dropped == 2
    sample = p.add_current(T0 + S + 210_000_000, 4.0)
    assert sample is not None and (sample.current_a, sample.voltage_v) == (4.0, 12.1)


def test_pairing_each_reading_used_once() -> None:
    p = ScalarPairer(pair_tolerance_s=0.05)
    p.add_current(T0, 1.0)
    assert p.add_voltage(T0 + 1, 12.0) is not None
    assert p.add_voltage(T0 + 2, 12.0) is None  # the current is used up
    p.reset()
    assert p.add_current(T0 + 3, 1.0) is None


def test_pairing_rejects_a_negative_tolerance() -> None:
    with pytest.raises(ValueError):
        ScalarPairer(-1.0)


# -- persistence -----------------------------------------------------------------------------
STATE = SavedState(soc=0.7312, soc_var=1.2e-5, stamp_s=1_778_152_330.1, estimator="hybrid",
                   battery="AJC 12 V 5 Ah SLA (seed 000)")  # fmt: skip


def test_save_and_load_round_trip(tmp_path: Path) -> None:
    path = tmp_path / "deep" / "dir" / "state.yaml"
    save_state(path, STATE)
    assert load_state(path) == STATE
    # Overwrite atomically: no temporary file left behind.
    save_state(path, SavedState(0.5, 1e-4, STATE.stamp_s + 10, "coulomb", STATE.battery))
    assert load_state(path).soc == 0.5
    assert sorted(os.listdir(path.parent)) == ["state.yaml"]


def test_save_keeps_the_old_file_when_writing_fails(tmp_path: Path, monkeypatch) -> None:
    path = tmp_path / "state.yaml"
    save_state(path, STATE)

    def broken_fsync(fd: int) -> None:
        raise OSError("disk on fire")

    monkeypatch.setattr(os, "fsync", broken_fsync)
    with pytest.raises(OSError, match="disk on fire"):
        save_state(path, SavedState(0.1, 1e-4, 0.0, "x", "y"))
    monkeypatch.undo()
    assert load_state(path) == STATE
    assert sorted(os.listdir(tmp_path)) == ["state.yaml"]


@pytest.mark.parametrize(
    ("content", "problem"),
    [
        ("", "mapping"),
        ("[1, 2]", "mapping"),
        ("format: 2\nsoc: 0.5", "format"),
        ("{format: 1, soc: 1.5, soc_var: 0.1, stamp_s: 1, estimator: h, battery: b}", "soc ="),
        ("{format: 1, soc: .nan, soc_var: 0.1, stamp_s: 1, estimator: h, battery: b}", "finite"),
        ("{format: 1, soc: 0.5, soc_var: 0, stamp_s: 1, estimator: h, battery: b}", "soc_var"),
        ("{format: 1, soc: 0.5, soc_var: 0.1, stamp_s: x, estimator: h, battery: b}", "stamp_s"),
        ("{format: 1, soc: 0.5, soc_var: 0.1, stamp_s: 1, estimator: '', battery: b}", "estim"),
        ("{format: 1, soc: 0.5, soc_var: 0.1, stamp_s: 1, estimator: h}", "battery"),
        ("soc: [unclosed", "YAML"),
    ],
)
def test_load_validates(tmp_path: Path, content: str, problem: str) -> None:
    path = tmp_path / "state.yaml"
    path.write_text(content)
    with pytest.raises(StateFileError, match=problem):
        load_state(path)


def test_load_missing_file(tmp_path: Path) -> None:
    with pytest.raises(StateFileError, match="no such file"):
        load_state(tmp_path / "nope.yaml")


def test_resume_decision(tmp_path: Path) -> None:
    path = tmp_path / "state.yaml"
    save_state(path, STATE)
    fresh = resume_decision(path, STATE.stamp_s + 30.0, 600.0, STATE.battery)
    assert fresh.resume and fresh.state == STATE and "resuming" in fresh.reason
    old = resume_decision(path, STATE.stamp_s + 601.0, 600.0, STATE.battery)
    assert not old.resume and "older than resume_max_age_s" in old.reason
    other = resume_decision(path, STATE.stamp_s + 1.0, 600.0, "another pack")
    assert not other.resume and "another pack" in other.reason
    future = resume_decision(path, STATE.stamp_s - 100.0, 600.0, STATE.battery)
    assert not future.resume and "future" in future.reason
    jitter = resume_decision(path, STATE.stamp_s - 0.5, 600.0, STATE.battery)
    assert jitter.resume
    missing = resume_decision(tmp_path / "none.yaml", 0.0, 600.0, STATE.battery)
    assert not missing.resume and "no such file" in missing.reason


def test_state_file_is_plain_yaml(tmp_path: Path) -> None:
    path = tmp_path / "state.yaml"
    save_state(path, STATE)
    raw = yaml.safe_load(path.read_text())
    assert raw == {"format": 1, **{k: getattr(STATE, k) for k in STATE.__dataclass_fields__}}
