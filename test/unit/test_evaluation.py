"""evaluation.py: the accuracy metrics (seed 000 section 4) on hand-made series."""

from __future__ import annotations

import math

import numpy as np
import pytest

from soc_estimator_ros.evaluation import accuracy


def test_metrics_after_the_window_and_convergence_times() -> None:
    t = np.arange(0.0, 1200.0, 1.0)
    ref = np.full(t.size, 0.5)
    est = ref + np.where(t < 100, 0.1, 0.01)  # 10 points off for 100 s, then 1 point
    acc = accuracy(t, est, ref, window_s=600.0)
    assert acc.mae == pytest.approx(0.01) and acc.max_abs == pytest.approx(0.01)
    assert acc.rmse == pytest.approx(0.01)
    assert acc.t_converge_s == 100.0 and acc.t_settle_s == 100.0
    assert acc.n_samples == 600


def test_never_converged_and_nan_references() -> None:
    t = np.arange(0.0, 700.0, 1.0)
    ref = np.full(t.size, 0.5)
    ref[::2] = math.nan  # ignored samples
    acc = accuracy(t, ref + 0.05, ref, window_s=600.0)
    assert acc.t_converge_s == math.inf and acc.mae == pytest.approx(0.05)
    with pytest.raises(ValueError, match="window"):
        accuracy(t, ref, ref, window_s=1e4)
