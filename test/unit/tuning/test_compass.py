"""The repeated local search on score functions whose walk is known in closed form.

The tuning is one log dimension ``r`` in [1e-3, 1] whose file value is the bound 1e-3
(position 0); a step of 0.1 is a tenth of the three decades. Recording ``i`` scores a tuning
at position ``u`` as ``w_i (u - t_i)^2``, so every walk's moves and end can be counted by hand.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from soc_estimator_ros.tuning.compass import ScoreTable, compass_cross_validate
from soc_estimator_ros.tuning.crossval import folds
from soc_estimator_ros.tuning.search import Dimension

R = Dimension("r", 1e-3, 1.0, log=True)
BASE = {"r": 1e-3}


def table_for(targets: list[float], weights: list[float]) -> tuple[ScoreTable, list[int]]:
    calls: list[int] = []

    def evaluate(batch: list[dict[str, float]]) -> np.ndarray:
        calls.append(len(batch))
        u = np.array([R.position(v.get("r", BASE["r"])) for v in batch])[:, None]
        return np.array(weights) * (u - np.array(targets)) ** 2

    return ScoreTable(evaluate), calls


def test_the_walk_moves_a_step_a_round_until_no_move_is_better():
    """Every recording's best is position 0.5: from 0, five moves up, and the sixth round finds
    0.6 worse and stops. The folds walk the same way, so the table holds the seven positions
    0..0.6 once each (a move back down is the tuning it came from, not scored again)."""
    table, calls = table_for([0.5] * 6, [1.0] * 6)
    lines: list[str] = []
    cv, moves = compass_cross_validate(table, (R,), BASE, 0.1, 10, 6, 3, seed=0, log=lines.append)
    assert moves == [5, 5, 5, 5]
    assert len(lines) == 6 and lines[0] == "round 1: " + "; ".join(
        f"{w} r {10**-2.7:.4g}" for w in ("fold 1", "fold 2", "fold 3", "all")
    )
    assert lines[-1] == "round 6: fold 1 stopped; fold 2 stopped; fold 3 stopped; all stopped"
    assert math.isclose(table.candidates[cv.chosen]["r"], 10**-1.5, rel_tol=1e-9)
    assert len(table.candidates) == 7 and sum(calls) == 7
    assert cv.held_out_score < 1e-20 and cv.file_held_out_score == 0.25 and cv.accepted


def test_rounds_bound_the_walk():
    table, _ = table_for([0.5] * 6, [1.0] * 6)
    cv, moves = compass_cross_validate(table, (R,), BASE, 0.1, 3, 6, 3, seed=0)
    assert moves == [3, 3, 3, 3]
    assert math.isclose(table.candidates[cv.chosen]["r"], 10**-2.1, rel_tol=1e-9)
    with pytest.raises(ValueError, match="--rounds"):
        compass_cross_validate(table, (R,), BASE, 0.1, 0, 6, 3, seed=0)


def test_each_fold_walks_on_its_own_training_recordings_and_is_judged_on_the_rest():
    """Recordings 0-3 want position 0.5, recordings 4 and 5 want 0 ten times as strongly.
    On all six the mean (4 (u - 0.5)^2 + 20 u^2) / 6 is 0.167 at 0, 0.140 at 0.1, 0.193 at
    0.2: one move. With seed 0 the folds are {2, 3}, {4, 5}, {0, 1}. The fold holding 4 and
    5 out walks on 0-3 alone to 0.5 (five moves) and scores 10 x 0.25 = 2.5 on them, where the
    file scores 0; the other two folds stay at the file's tuning (0.125 at 0 against 0.13 at
    0.1 on their training four). Held out: (2 x 2.5 + 4 x 0.25) / 6 = 1.0 against the file's
    (4 x 0.25) / 6 = 0.167: refused, although the walk on all six looks better than the file.
    Choosing the moves on all six and holding out afterwards would have judged 0.1 instead."""
    targets, weights = [0.5] * 4 + [0.0] * 2, [1.0] * 4 + [10.0] * 2
    assert [f.tolist() for f in folds(6, 3, seed=0)] == [[2, 3], [4, 5], [0, 1]]
    table, _ = table_for(targets, weights)
    cv, moves = compass_cross_validate(table, (R,), BASE, 0.1, 10, 6, 3, seed=0)
    assert moves == [0, 5, 0, 1]
    assert cv.chosen_score < cv.file_score
    assert math.isclose(cv.held_out_score, 1.0) and math.isclose(cv.file_held_out_score, 1 / 6)
    assert not cv.accepted
