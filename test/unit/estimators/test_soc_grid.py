"""The SoC's grid posterior (estimators/soc_grid.py): against closed forms where there is one."""

from __future__ import annotations

import math

import numpy as np
import pytest

from soc_estimator_ros.estimators.soc_grid import SocGrid

SLOPE_V = 0.5  # V per unit of SoC: a linear "OCV", so the posterior has a closed form


def readings(grid: SocGrid, volts: list[float], r_v2: float) -> None:
    """Each reading of a pack whose voltage is ``SLOPE_V soc`` (the points' prediction)."""
    for v in volts:
        grid.update(v - SLOPE_V * grid.soc, r_v2)


def gaussian_posterior(m0: float, s0: float, v: float, var_v2: float) -> tuple[float, float]:
    """The scalar Kalman update of N(m0, s0^2) by one reading ``v = SLOPE_V soc + e``."""
    p0 = s0 * s0
    k = p0 * SLOPE_V / (SLOPE_V * SLOPE_V * p0 + var_v2)
    return m0 + k * (v - SLOPE_V * m0), (1.0 - k * SLOPE_V) * p0


def test_without_a_persistent_error_one_reading_is_the_kalman_update() -> None:
    """No bias (variance 0): the grid's posterior is the Gaussian one. The prior N(0.5, 0.1^2)
    lies 5 std inside [0, 1] (the cut moves the moments by ~1e-6) and the points are 0.0025
    apart, 1/40 of the narrowest std: the Riemann sum of a Gaussian is exact to far below
    that; 1e-5 holds both."""
    grid = SocGrid(0.5, 0.1, 401, 0.0)
    readings(grid, [SLOPE_V * 0.55], 0.02**2)
    mean, var = grid.moments()
    want_mean, want_var = gaussian_posterior(0.5, 0.1, SLOPE_V * 0.55, 0.02**2)
    assert mean == pytest.approx(want_mean, abs=1e-5)
    assert var == pytest.approx(want_var, rel=1e-5)


def test_a_persistent_error_tells_once_however_often_it_is_read() -> None:
    """``b`` constant (decay 1, no drive) of variance B and white noise R: n readings tell as
    much as their mean, one reading of variance ``B + R / n`` (the scatter about the mean does
    not depend on the SoC). Taken as independent they would tell as one of ``(B + R) / n``.
    Equal to rounding: the two log-weights differ by a constant."""
    b_v2, r_v2, n = 0.02**2, 0.01**2, 50
    rng = np.random.default_rng(3)
    volts = list(SLOPE_V * 0.6 + 0.015 + rng.normal(0.0, 0.01, n))
    grid = SocGrid(0.5, 0.1, 401, b_v2)
    readings(grid, volts, r_v2)
    once = SocGrid(0.5, 0.1, 401, 0.0)
    readings(once, [float(np.mean(volts))], b_v2 + r_v2 / n)
    assert grid.moments() == pytest.approx(once.moments(), rel=1e-9, abs=1e-12)
    # the persistent error's variance is all but spent: what is left is R / n's share
    assert grid.bias_var_v2 == pytest.approx(b_v2 * (r_v2 / n) / (b_v2 + r_v2 / n), rel=1e-9)


def test_the_points_move_with_the_counted_charge_and_stay_in_range() -> None:
    """predict shifts every point by the SoC counted; the points are read clipped to [0, 1];
    the bias mean and variance decay as the Gauss-Markov process does."""
    grid = SocGrid(0.5, 0.1, 11, 0.01)
    grid.bias_mean_v[:] = 0.2
    a = math.exp(-60.0 / 600.0)  # a minute of a 10-minute correlation time
    grid.predict(-0.15, a, 0.003)
    assert grid.soc[0] == 0.0 and grid.soc[1] == 0.0 and grid.soc[2] == pytest.approx(0.05)
    assert grid.soc[-1] == pytest.approx(0.85)
    assert grid.bias_mean_v == pytest.approx(0.2 * a)
    assert grid.bias_var_v2 == pytest.approx(a * a * 0.01 + 0.003)
    mean, _ = grid.moments()
    assert mean == pytest.approx(0.35, abs=0.01)  # the prior's mean moved, a little mass cut


def test_the_squared_distance_is_variance_plus_bias_squared() -> None:
    grid = SocGrid(0.5, 0.1, 401, 0.0)
    mean, var = grid.moments()
    assert grid.squared_distance(0.3) == pytest.approx(var + (mean - 0.3) ** 2)


def test_a_grid_needs_points_and_a_width() -> None:
    with pytest.raises(ValueError, match="points"):
        SocGrid(0.5, 0.1, 1, 0.0)
    with pytest.raises(ValueError, match="std"):
        SocGrid(0.5, 0.0, 11, 0.0)
