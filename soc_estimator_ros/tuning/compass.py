"""The local search repeated: a compass search that walks until no move improves.

One round is ``search.local_candidates``: the current tuning and each dimension moved by
``step`` of its range down and up. The walk moves to the best of them when it is strictly
better on the recordings it chooses on (the current tuning wins ties) and stops when it is
not, or after ``rounds`` rounds: a compass search with a fixed step (Kolda, Lewis & Torczon,
"Optimization by direct search", SIAM Review 45, 2003, algorithm 3.2 without the step's
contraction, so the result lies on the step's grid around the file's tuning and the cost is
one round per move).

Cross-validation wraps the whole walk (Hastie, Tibshirani & Friedman, 2009, §7.10.2, "the
wrong and the right way"): each fold walks from the file's tuning on its training recordings
alone, and its end point is scored on its held-out recordings. Choosing every move on all
recordings and only then holding some out would judge a walk on recordings that steered it.
The walks of the folds and the one on all recordings advance in lock-step, and every new
tuning of a round is scored on every recording in one batch (the walks mostly share their
moves, so a round costs about one walk's).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np

from .cache import Key, tuning_key
from .crossval import CrossValidation, finite, folds, judge, training
from .search import Dimension, apply, describe, local_candidates, value_of

Values = dict[str, float]


class ScoreTable:
    """Every tuning scored so far (``values`` by label over the file's tuning) and its score
    on every recording; ``evaluate`` scores a batch of new ones (rows of recordings)."""

    def __init__(self, evaluate: Callable[[list[Values]], np.ndarray]) -> None:
        self.candidates: list[Values] = []
        self._rows: list[np.ndarray] = []
        self._index: dict[Key, int] = {}
        self._evaluate = evaluate

    def indices(self, batch: Sequence[Values]) -> list[int]:
        """The rows of ``batch``, scoring the tunings not yet in the table in one call."""
        new = []
        for values in batch:
            key = tuning_key(values)
            if key not in self._index:
                self._index[key] = len(self.candidates)
                self.candidates.append(dict(values))
                new.append(dict(values))
        if new:
            self._rows.extend(np.atleast_2d(self._evaluate(new)))
        return [self._index[tuning_key(v)] for v in batch]

    @property
    def scores(self) -> np.ndarray:
        """``scores[c, r]``, non-finite (a tuning that broke the filter) as the worst."""
        return finite(np.array(self._rows, dtype=float))


def _neighbours(
    space: Sequence[Dimension], base: Mapping[str, Any], point: Values, step: float
) -> list[Values]:
    """``point`` and its compass moves, each as the labels that differ from ``base``."""
    at = apply(base, point)
    out = []
    for move in local_candidates(space, at, step):
        values = {**point, **move}
        out.append(
            {
                d.label: values[d.label]
                for d in space
                if d.label in values
                and not math.isclose(values[d.label], value_of(base, d), rel_tol=1e-9)
            }
        )
    return out


def compass_cross_validate(
    table: ScoreTable,
    space: Sequence[Dimension],
    base: Mapping[str, Any],
    step: float,
    rounds: int,
    n_recordings: int,
    k: int,
    seed: int,
    log: Callable[[str], None] = lambda line: None,
) -> tuple[CrossValidation, list[int]]:
    """The walks of the ``k`` folds and the one on all recordings from the file's tuning
    (``table``'s row 0 after this call); returns the verdict and each walk's number of moves
    (folds first, the walk on all last). ``log`` gets a line per round: where each walk
    went, so a long search that is stopped still says how far it came."""
    if rounds < 1:
        raise ValueError(f"--rounds {rounds}: expected >= 1")
    fold_list = folds(n_recordings, k, seed)
    trains = [training(f, n_recordings) for f in fold_list] + [np.arange(n_recordings)]
    points: list[Values] = [{} for _ in trains]
    moves = [0] * len(trains)
    active = [True] * len(trains)
    table.indices([{}])
    names = [f"fold {i + 1}" for i in range(k)] + ["all"]
    for r in range(rounds):
        walking = [i for i, a in enumerate(active) if a]
        if not walking:
            break
        around = {i: _neighbours(space, base, points[i], step) for i in walking}
        rows = table.indices([v for i in walking for v in around[i]])
        scores = table.scores
        for i in walking:
            mine, rows = rows[: len(around[i])], rows[len(around[i]) :]
            best = int(np.argmin(scores[np.ix_(np.array(mine), trains[i])].mean(axis=1)))
            if best == 0:  # around[i][0] is the point itself: no move is strictly better
                active[i] = False
            else:
                points[i] = around[i][best]
                moves[i] += 1
        log(
            f"round {r + 1}: "
            + "; ".join(
                f"{names[i]} {describe(points[i]) if active[i] else 'stopped'}" for i in walking
            )
        )
    ends = table.indices(points)
    return judge(table.scores, fold_list, ends[:-1], ends[-1]), moves
