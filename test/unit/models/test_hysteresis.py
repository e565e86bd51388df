"""Plett's one-state OCV hysteresis on the discharge branch (models/hysteresis.py)."""

from __future__ import annotations

import math

import pytest

from soc_estimator_ros.models.hysteresis import Hysteresis, HysteresisState

HYST = Hysteresis(gap_v=0.08, rate_per_soc=50.0)
Q_AH = 6.0


def test_a_charge_moves_the_state_toward_the_charge_branch_by_the_charge_moved() -> None:
    # 6 A for 36 s into 6 Ah: dz = 0.01, so A = exp(-50 * 0.01) (the model's equation, exact
    # up to the float arithmetic: 1e-15).
    after = HYST.step(HysteresisState(0.0, 0.0), -6.0, 36.0, Q_AH)
    assert after.branch == pytest.approx(1.0 - math.exp(-0.5), abs=1e-15)


def test_a_discharge_moves_it_toward_the_discharge_branch_and_contracts_its_variance() -> None:
    start = HysteresisState.unknown()
    after = HYST.step(start, 6.0, 36.0, Q_AH)
    a = math.exp(-0.5)
    assert after.branch == pytest.approx(a * 0.5, abs=1e-15)
    assert after.var == pytest.approx(a * a / 4.0, abs=1e-15)


def test_a_rest_and_a_zero_step_change_nothing() -> None:
    s = HysteresisState(0.3, 0.01)
    assert HYST.step(s, 0.0, 3600.0, Q_AH) is s
    assert HYST.step(s, 5.0, 0.0, Q_AH) is s


def test_the_charge_counts_at_the_charge_efficiency() -> None:
    after = HYST.step(HysteresisState(0.0), -6.0, 36.0, Q_AH, eta_charge=0.5)
    assert after.branch == pytest.approx(1.0 - math.exp(-0.25), abs=1e-15)


def test_the_offset_and_its_std() -> None:
    s = HysteresisState.unknown()
    assert HYST.offset_v(s) == pytest.approx(0.04)
    assert HYST.std_v(s) == pytest.approx(0.08 / 2.0)


@pytest.mark.parametrize(("gap", "rate"), [(-0.01, 10.0), (math.nan, 10.0), (0.05, 0.0)])
def test_bad_parameters_are_refused(gap: float, rate: float) -> None:
    with pytest.raises(ValueError):
        Hysteresis(gap, rate)
