"""The search space: parsing, deterministic candidates within their bounds, tuple entries."""

from __future__ import annotations

import math

import pytest

from soc_estimator_ros.tuning.search import (
    DEFAULT_SPACES,
    Dimension,
    apply,
    candidates,
    local_candidates,
    parse_dimension,
)


def test_parse_dimension_reads_bounds_log_and_tuple_elements():
    assert parse_dimension("r=0.01:10:log") == Dimension("r", 0.01, 10.0, True)
    assert parse_dimension("q_diag.0=1e-12:1e-8") == Dimension("q_diag", 1e-12, 1e-8, False, 0)
    for bad in ("r", "r=1", "r=1:2:lin", "r=2:1", "r=0:1:log", "r=a:b"):
        with pytest.raises(ValueError, match="--space"):
            parse_dimension(bad)


def test_candidates_start_with_the_file_and_are_the_same_for_a_seed():
    space = DEFAULT_SPACES["hybrid"]
    a, b, c = candidates(space, 50, 7), candidates(space, 50, 7), candidates(space, 50, 8)
    assert a == b and a != c
    assert a[0] == {} and len(a) == 51
    for cand in a[1:]:
        for d in space:
            assert d.lo <= cand[d.label] <= d.hi
    # Log-uniform: over 50 draws of a 4-decade range, the median falls in the middle decades,
    # not in the top one a uniform draw would put it in (its median: hi / 2).
    r = sorted(x["r"] for x in a[1:])
    assert 1e-3 < r[25] < 1e-1


def test_apply_sets_an_entry_and_one_element_of_a_tuple_entry():
    base = {"r": 1.0, "q_diag": (1.0, 2.0, 3.0)}
    out = apply(base, {"r": 0.5, "q_diag.1": 9.0})
    assert out == {"r": 0.5, "q_diag": (1.0, 9.0, 3.0)}
    assert base["q_diag"] == (1.0, 2.0, 3.0)  # not changed in place
    assert math.isclose(apply(base, {})["r"], 1.0)


def test_local_candidates_move_one_dimension_a_step_either_way_within_the_box():
    r = Dimension("r", 1e-3, 1.0, log=True)  # three decades: a step of 1/3 is a factor of 10
    q = Dimension("q_diag", 0.0, 1.0, index=1)  # linear
    base = {"r": 0.01, "q_diag": (5.0, 0.95)}
    out = local_candidates((r, q), base, 1.0 / 3.0)
    assert out[0] == {}  # the file's own first
    assert [set(c) for c in out[1:]] == [{"r"}, {"r"}, {"q_diag.1"}, {"q_diag.1"}]
    assert math.isclose(out[1]["r"], 1e-3) and math.isclose(out[2]["r"], 0.1)
    # Linear: 0.95 - 1/3 is inside; 0.95 + 1/3 is clipped to the bound, a move that is kept.
    assert math.isclose(out[3]["q_diag.1"], 0.95 - 1.0 / 3.0)
    assert math.isclose(out[4]["q_diag.1"], 1.0)
    at_bound = local_candidates((q,), {"q_diag": (5.0, 1.0)}, 0.2)
    assert len(at_bound) == 2 and math.isclose(at_bound[1]["q_diag.1"], 0.8)  # no move at 1.0
    assert local_candidates((r,), base, 0.1) == local_candidates((r,), base, 0.1)  # no seed
    # Above the box (r = 10, a third of the box beyond its top): a step down toward it only.
    above = local_candidates((r,), {"r": 10.0}, 0.2)
    assert len(above) == 2 and math.isclose(above[1]["r"], 10 ** (1 - 0.6))
    with pytest.raises(ValueError, match="--step"):
        local_candidates((r,), base, 0.0)
