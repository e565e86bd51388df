"""tracking/gate.py: the input gate's verdicts, thresholds and counts."""

from __future__ import annotations

import math

import pytest
from conftest import REPO_ROOT

from soc_estimator_ros.params import load_battery_params
from soc_estimator_ros.tracking.gate import REJECTIONS, GateConfig, InputGate, Verdict

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
