"""k-fold cross-validation over recordings, on a table of scores.

Every candidate is scored on every recording once (``scores[c, r]``, the objective of
``objective.py``); a fold's tuning is then the candidate with the lowest mean score on the
other folds' recordings, and its held-out score is its mean on the fold's own. The mean of the
held-out scores over the folds (each recording held out once) is what the tuning is expected
to score on recordings it was not chosen on; the file's own tuning (candidate 0) is scored the
same way, on the same held-out recordings. The tuning finally written is the candidate with the
lowest mean over all recordings, and only when its held-out estimate is no worse than the
file's (Hastie, Tibshirani & Friedman, *The Elements of Statistical Learning*, 2009, §7.10).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


def folds(n_recordings: int, k: int, seed: int) -> list[np.ndarray]:
    """The recordings' indices in ``k`` folds of near-equal size, shuffled by ``seed``."""
    if not 2 <= k <= n_recordings:
        raise ValueError(f"--folds {k}: needs 2 <= k <= the {n_recordings} recordings")
    order = np.random.default_rng(seed).permutation(n_recordings)
    return [np.sort(f) for f in np.array_split(order, k)]


@dataclass(frozen=True)
class Fold:
    """One fold: its held-out recordings, the candidate chosen on the rest, the scores."""

    held_out: tuple[int, ...]
    chosen: int
    train_score: float
    held_out_score: float
    file_held_out_score: float


@dataclass(frozen=True)
class CrossValidation:
    """The folds, the tuning chosen on every recording, and the verdict."""

    folds: tuple[Fold, ...]
    chosen: int
    chosen_score: float
    file_score: float
    held_out_score: float  # mean over recordings, each held out once
    file_held_out_score: float

    @property
    def accepted(self) -> bool:
        """The tuning is written only if it does no worse than the file's on held-out data."""
        return self.held_out_score <= self.file_held_out_score


def cross_validate(scores: np.ndarray, k: int, seed: int) -> CrossValidation:
    """:class:`CrossValidation` of ``scores[c, r]`` (candidate 0 the file's tuning; a
    non-finite score counts as the worst), each fold choosing the candidate with the lowest
    mean on its training recordings."""
    s = finite(scores)
    fold_list = folds(s.shape[1], k, seed)
    chosen = [int(np.argmin(s[:, training(f, s.shape[1])].mean(axis=1))) for f in fold_list]
    return judge(s, fold_list, chosen, int(np.argmin(s.mean(axis=1))))


def finite(scores: np.ndarray) -> np.ndarray:
    """``scores`` with every non-finite entry (a tuning that broke the filter) the worst."""
    return np.where(np.isfinite(scores), scores, np.inf)


def training(held_out: np.ndarray, n_recordings: int) -> np.ndarray:
    """The recordings a fold chooses on: all but its held-out ones."""
    return np.setdiff1d(np.arange(n_recordings), held_out)


def judge(
    scores: np.ndarray, fold_list: list[np.ndarray], fold_chosen: list[int], chosen: int
) -> CrossValidation:
    """The verdict on ``scores[c, r]`` (finite or inf) when fold ``i`` chose candidate
    ``fold_chosen[i]`` on its training recordings and ``chosen`` was chosen on all: each
    fold's choice is scored on its held-out recordings beside the file's (candidate 0)."""
    s = scores
    n_rec = s.shape[1]
    out = []
    held, held_file = np.empty(n_rec), np.empty(n_rec)
    for f, c in zip(fold_list, fold_chosen, strict=True):
        held[f], held_file[f] = s[c, f], s[0, f]
        out.append(
            Fold(
                tuple(int(i) for i in f),
                c,
                float(s[c, training(f, n_rec)].mean()),
                float(s[c, f].mean()),
                float(s[0, f].mean()),
            )
        )
    all_means = s.mean(axis=1)
    return CrossValidation(
        tuple(out),
        chosen,
        float(all_means[chosen]),
        float(all_means[0]),
        float(held.mean()),
        float(held_file.mean()),
    )
