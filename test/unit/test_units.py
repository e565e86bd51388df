"""units.py: the one home of the sign convention and the stamp helpers."""

from __future__ import annotations

from soc_estimator_ros.units import (
    NS_PER_S,
    CurrentSign,
    core_current_from,
    core_current_from_ros,
    ns_to_stamp,
    ros_current_from_core,
    stamp_to_ns,
)


def test_ros_current_is_negative_while_discharging() -> None:
    assert core_current_from_ros(-2.5) == 2.5
    assert ros_current_from_core(2.5) == -2.5
    assert core_current_from(2.5, CurrentSign.DISCHARGE_POSITIVE) == 2.5
    assert core_current_from(-2.5, CurrentSign.CHARGE_POSITIVE) == 2.5


def test_stamps_round_trip_exactly() -> None:
    stamp_ns = 1_778_152_330 * NS_PER_S + 123_456_789  # 1.7e18: beyond a float's 2^53
    assert stamp_to_ns(*ns_to_stamp(stamp_ns)) == stamp_ns
    assert ns_to_stamp(stamp_ns) == (1_778_152_330, 123_456_789)
