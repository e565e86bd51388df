"""tracking/pairing.py: separate current and voltage readings paired into samples."""

from __future__ import annotations

import pytest

from soc_estimator_ros.tracking.pairing import ScalarPairer

S = 1_000_000_000  # ns per s
T0 = 1_778_151_600 * S


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
