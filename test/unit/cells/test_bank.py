"""The cell bank (cells/bank.py): the cell gate, usable SoC, weakest and strongest cells."""

from __future__ import annotations

import math

import numpy as np
from conftest import REPO_ROOT

from soc_estimator_ros.cells import CellBank, cell_field_names, cell_limits_v
from soc_estimator_ros.params import load_battery_params

LFP = load_battery_params(REPO_ROOT / "config" / "lfp_12v6ah.yaml")


def test_cell_limits_default_to_the_pack_limits_per_cell() -> None:
    lo, hi = cell_limits_v(LFP, 4)
    assert (lo, hi) == (LFP.limits.voltage_min_v / 4, LFP.limits.voltage_max_v / 4)


def test_one_bad_cell_is_rejected_alone_and_counted() -> None:
    bank = CellBank(LFP, 4)
    good = np.array([3.30, 3.31, 3.29, 3.30])
    bad_values = [math.nan, math.inf, 99.0, -1.0]
    for k in range(40):
        v = good.copy()
        if k % 4 == 0:
            v[2] = bad_values[(k // 4) % len(bad_values)]
        ce = bank.step(float(k), 0.3, v, 0.6, 1e-4)
        assert ce.accepted[2] == (k % 4 != 0)
        assert np.all(ce.accepted[[0, 1, 3]])
        assert np.all(np.isfinite(ce.soc))
    np.testing.assert_array_equal(bank.rejected, [0, 0, 10, 0])


def test_usable_soc_is_the_weakest_cells_remaining_charge() -> None:
    bank = CellBank(LFP, 4)
    bank.step(0.0, 0.3, np.full(4, 3.3), 0.5, 1e-4)
    f = bank.filter
    f.x[:, 0] = [0.02, -0.04, 0.0, 0.03]
    f.x[:, 1] = [0.0, 0.05, 0.0, -0.02]
    ok = np.ones(4, dtype=bool)
    ce = bank._estimate(np.full(4, 3.3), ok, ~ok, 0.5, 1e-4)
    soc = 0.5 + f.x[:, 0]
    remaining = soc * (1 + f.x[:, 1])
    room = (1 - soc) * (1 + f.x[:, 1])
    assert ce.weakest == int(np.argmin(remaining)) == 1
    assert ce.strongest == int(np.argmin(room)) == 3
    assert math.isclose(ce.usable_soc, remaining[1], rel_tol=1e-12)
    assert math.isclose(ce.usable_charge_soc, 1 - room[3], rel_tol=1e-12)
    assert math.isclose(ce.imbalance_soc, 0.07, rel_tol=1e-9)
    assert math.isclose(ce.usable_soc_std, math.sqrt(1e-4 + f.p[1, 0, 0]), rel_tol=1e-12)
    assert list(ce.fields()) == cell_field_names(4)
    assert ce.fields()["weakest"] == 2.0  # 1-based in the vector


def test_cell_over_and_under_voltage_flags() -> None:
    bank = CellBank(LFP, 4)
    ce = bank.step(0.0, 0.3, np.array([3.3, 3.7, 2.4, 3.3]), 0.5, 1e-4)
    np.testing.assert_array_equal(ce.over_voltage, [False, True, False, False])
    np.testing.assert_array_equal(ce.under_voltage, [False, False, True, False])
    assert math.isclose(ce.spread_v, 3.7 - 2.4, rel_tol=1e-6)


def test_a_cell_at_its_cut_off_empties_the_pack_until_the_load_stops() -> None:
    bank = CellBank(LFP, 4)
    lo, _ = cell_limits_v(LFP, 4)
    v = np.array([3.20, 3.21, 3.19, 3.20])
    assert bank.step(0.0, 4.0, v, 0.08, 1e-4).usable_soc > 0.05
    # The weakest cell's voltage reaches its limit under the 4-A load, and is still there a
    # second later (cells.cutoff_hold_s): the pack's cut-off.
    ce = bank.step(1.0, 4.0, np.array([3.0, 3.0, lo, 3.0]), 0.07, 1e-4)
    assert ce.usable_soc > 0.05  # one reading is not yet a cut-off
    np.testing.assert_array_equal(ce.under_voltage, [False, False, True, False])
    ce = bank.step(2.0, 4.0, np.array([3.0, 3.0, lo - 0.01, 3.0]), 0.07, 1e-4)
    assert ce.usable_soc == 0.0
    assert ce.weakest == 2
    # Back above its limit under a lighter load, still a load: still no usable charge.
    assert bank.step(3.0, 2.0, np.array([3.1, 3.1, lo + 0.2, 3.1]), 0.07, 1e-4).usable_soc == 0.0
    # The robot stopped (0.3 A <= 0.1 C), every cell above its limit: the estimate again.
    ce = bank.step(4.0, 0.3, v, 0.07, 1e-4)
    assert math.isclose(ce.usable_soc, 0.07 + float(bank.filter.x[:, 0].min()), rel_tol=1e-12)


def test_one_low_reading_under_load_is_not_a_cut_off() -> None:
    bank = CellBank(LFP, 4)
    lo, _ = cell_limits_v(LFP, 4)
    v = np.array([3.20, 3.21, 3.19, 3.20])
    bank.step(0.0, 4.0, v, 0.5, 1e-4)
    ce = bank.step(1.0, 4.0, np.array([3.2, 3.2, lo - 0.3, 3.2]), 0.5, 1e-4)
    assert ce.usable_soc > 0.4
    assert ce.under_voltage[2]  # diagnosed, but the weakest cell is still the estimate's
    assert ce.weakest == int(np.argmin(ce.soc))
    for k in range(2, 5):  # the glitch passed: the load goes on, the estimate stays
        assert bank.step(float(k), 4.0, v, 0.5, 1e-4).usable_soc > 0.4


def test_a_held_current_predicts_as_that_current_from_the_last_step() -> None:
    """``held_current_a`` (a filter rate below the input rate) replaces the last step's current
    in the prediction and nothing else: a bank told to hold 5 A over the second equals one
    whose last step carried 5 A, to the bit."""
    v = np.array([3.30, 3.31, 3.29, 3.30])
    carried, held = CellBank(LFP, 4), CellBank(LFP, 4)
    carried.step(0.0, 5.0, v, 0.6, 1e-4)
    held.step(0.0, 1.0, v, 0.6, 1e-4)
    for bank in (carried, held):  # capacity deltas: the prediction then depends on the current
        bank.filter.x[:, 1] = [0.0, 0.05, 0.0, -0.02]
    a = carried.step(100.0, 5.0, v, 0.6, 1e-4)
    b = held.step(100.0, 5.0, v, 0.6, 1e-4, held_current_a=5.0)
    np.testing.assert_array_equal(a.soc, b.soc)
    np.testing.assert_array_equal(a.soc_std, b.soc_std)
    ignored = CellBank(LFP, 4)  # the same without the held current: the last step's 1 A
    ignored.step(0.0, 1.0, v, 0.6, 1e-4)
    ignored.filter.x[:, 1] = [0.0, 0.05, 0.0, -0.02]
    assert not np.array_equal(ignored.step(100.0, 5.0, v, 0.6, 1e-4).soc, a.soc)
