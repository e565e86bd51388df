"""Cross-validation on score tables whose answer is known."""

from __future__ import annotations

import numpy as np
import pytest

from soc_estimator_ros.tuning.crossval import cross_validate, folds


def test_folds_hold_every_recording_out_once_and_follow_the_seed():
    f = folds(7, 3, seed=1)
    assert sorted(np.concatenate(f).tolist()) == list(range(7))
    assert [len(x) for x in f] == [3, 2, 2]
    assert all((a == b).all() for a, b in zip(f, folds(7, 3, seed=1), strict=True))
    with pytest.raises(ValueError, match="--folds"):
        folds(3, 4, seed=0)


def test_a_candidate_better_everywhere_is_chosen_in_every_fold_and_accepted():
    scores = np.array([[2.0] * 6, [3.0] * 6, [1.0] * 6])  # row 0: the file's tuning
    cv = cross_validate(scores, 3, seed=0)
    assert cv.chosen == 2 and all(f.chosen == 2 for f in cv.folds)
    assert cv.held_out_score == 1.0 and cv.file_held_out_score == 2.0 and cv.accepted


def test_a_tuning_that_only_fits_its_own_recordings_is_refused():
    """Candidate 1 is excellent on recordings 0-3 and awful on 4-5, candidate 2 the reverse:
    on all six each looks better than the file (mean 1.67 against 2). With seed 0 the folds
    are {2, 3}, {4, 5}, {0, 1}: the fold holding 4 and 5 out chooses candidate 1 on the rest
    (mean 0) and scores 5 on them, the others keep the file's, so the held-out mean is 3
    against the file's 2 and the tuning is refused."""
    scores = np.array(
        [
            [2.0, 2.0, 2.0, 2.0, 2.0, 2.0],
            [0.0, 0.0, 0.0, 0.0, 5.0, 5.0],
            [5.0, 5.0, 5.0, 5.0, 0.0, 0.0],
        ]
    )
    assert [f.tolist() for f in folds(6, 3, seed=0)] == [[2, 3], [4, 5], [0, 1]]
    cv = cross_validate(scores, 3, seed=0)
    assert cv.chosen_score < cv.file_score  # the fit looks better on all of them
    assert cv.held_out_score == 3.0 and cv.file_held_out_score == 2.0
    assert not cv.accepted


def test_non_finite_scores_count_as_the_worst():
    scores = np.array([[1.0, 1.0, 1.0], [np.nan, 0.0, 0.0], [np.inf, 0.5, 0.5]])
    cv = cross_validate(scores, 3, seed=0)
    assert cv.chosen == 0
