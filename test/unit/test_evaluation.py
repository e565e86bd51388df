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


def _charged_pack(eta: float, gain: float, offset_a: float) -> tuple[np.ndarray, ...]:
    """A 5 Ah pack discharged at 2 A, charged at 1.5 A and discharged again, 1 s samples: the
    reference SoC counted exactly with ``eta``, the current read with ``gain`` and ``offset_a``."""
    from soc_estimator_ros.models.coulomb import coulomb_step

    t = np.arange(0.0, 9000.0, 1.0)
    true_a = np.where(t < 3000, 2.0, np.where(t < 6000, -1.5, 1.0))
    soc = np.empty(t.size)
    soc[0] = 0.9
    for k in range(1, t.size):
        soc[k] = coulomb_step(soc[k - 1], float(true_a[k - 1]), 1.0, 5.0, eta)
    return t, gain * true_a + offset_a, soc


def test_charge_efficiency_is_the_ratio_whatever_the_gain_and_capacity() -> None:
    from soc_estimator_ros.evaluation import charge_efficiency

    t, read_a, soc = _charged_pack(0.93, 1.03, 0.0)
    fit = charge_efficiency(t, read_a, soc, 5.4)  # capacity 8 % off: it cancels too
    # 1e-9: the equation holds exactly, least squares only rounds.
    assert fit.efficiency == pytest.approx(0.93, abs=1e-9)
    assert fit.discharge_scale == pytest.approx(5.4 / 5.0 / 1.03, rel=1e-9)
    assert fit.charge_ah == pytest.approx(1.03 * 1.5 * 3000 / 3600, rel=1e-9)


def test_charge_efficiency_with_a_sensor_offset() -> None:
    from soc_estimator_ros.evaluation import charge_efficiency

    t, read_a, soc = _charged_pack(0.93, 1.0, 0.02)
    fit = charge_efficiency(t, read_a, soc, 5.0)
    # The one offset term cannot hold the offset's share of the charge exactly ((1 - eta) of
    # 20 mA against 1.5 A: 1e-3 of eta); 2e-3 bounds it.
    assert fit.efficiency == pytest.approx(0.93, abs=2e-3)
    assert fit.offset_a == pytest.approx(-0.02, abs=5e-3)


def test_charge_efficiency_needs_a_charge() -> None:
    from soc_estimator_ros.evaluation import charge_efficiency

    t = np.arange(0.0, 100.0)
    with pytest.raises(ValueError, match="charge"):
        charge_efficiency(t, np.full(t.size, 1.0), 0.9 - t * 1e-4, 5.0)
