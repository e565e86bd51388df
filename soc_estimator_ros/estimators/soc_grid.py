"""A grid posterior of the SoC with the model's persistent voltage error marginalized.

The hybrid's UKF carries one Gaussian for the SoC. From a wide start on LFP's curve the true
posterior is not one: a reading "below the step near 0.72" cuts the prior there, and the UKF
turned it into 0.683 with std 5.3 % where the truth was 11.9 points below (2.2 std off;
``lfp_validation_1001`` +30 %, docs/accuracy.md "From a wrong start"). This module keeps the
exact posterior of the same error model on a grid of SoC values (a point-mass filter: Bucy
and Senne, "Digital synthesis of non-linear filters", Automatica 7, 1971), so the hybrid can
publish a variance no smaller than the squared distance the grid puts between its SoC and the
pack's (hybrid item 12).

The reading's error is the hybrid's: a persistent part ``b`` (item 5's Gauss-Markov state,
std ``bias_std_v``, correlation time ``bias_tau_s``) and a white part of variance ``R``. For a
grid point ``s`` the residual ``y_k(s) = v_k - h(s)`` (``h`` the model's voltage with ``b``
left out) is ``b_k + w_k``, so ``b`` is marginalized by one scalar Kalman filter per point
(a Rao-Blackwellized point-mass filter). Its measurement matrix is 1 and ``R`` does not depend
on ``s``, so every point shares the variance ``P_b``; only the means ``m_b(s)`` differ:

    predict:  m_b <- a m_b,   P_b <- a^2 P_b + std^2 (1 - a^2),   a = exp(-dt / tau)
    update:   S = P_b + R,    log w(s) <- log w(s) - (y(s) - m_b(s))^2 / (2 S)
              m_b(s) <- m_b(s) + (P_b / S) (y(s) - m_b(s)),   P_b <- P_b R / S

which is the exact marginal likelihood of the voltages under that error model (the ``log
det S`` term is the same for every point and drops). Taking each sample as independent
instead (``b`` as white noise) is what narrows the UKF where the error persists; taking one
reading per ``bias_tau_s`` (tried first) left the grid at its prior under LFP's 0.1 V/A load
noise and published 20-30 % std at the end of missions the UKF had right (tuning half).

The grid moves with the counted charge (every point by the same ``dsoc``: the count's error
is small against the widths the grid is kept for) and is clipped to [0, 1] where it is read.
"""

from __future__ import annotations

import numpy as np


class SocGrid:
    """The SoC's posterior on ``points`` equally spaced values of [0, 1] (module docstring)."""

    def __init__(self, soc: float, soc_std: float, points: int, bias_var_v2: float) -> None:
        """A Gaussian prior ``N(soc, soc_std^2)`` cut to [0, 1]; ``b`` starts at 0 with
        ``bias_var_v2`` (the UKF's own start of its bias state)."""
        if points < 2 or not soc_std > 0.0:
            raise ValueError(f"SocGrid needs >= 2 points and std > 0, got {points}, {soc_std}")
        self._base = np.linspace(0.0, 1.0, points)
        self._shift = 0.0  # the charge counted since the start, as SoC
        self.log_w = -0.5 * ((self._base - soc) / soc_std) ** 2
        self.bias_mean_v = np.zeros(points)
        self.bias_var_v2 = bias_var_v2
        self._moments: tuple[float, float] | None = None  # until the next predict or update

    @property
    def soc(self) -> np.ndarray:
        """The points' SoC now, clipped to [0, 1]."""
        return np.clip(self._base + self._shift, 0.0, 1.0)

    def predict(self, dsoc: float, decay: float, bias_q_v2: float) -> None:
        """Move every point by ``dsoc``; ``b``'s means by ``decay`` (``a``), its variance by
        ``a^2 P_b + bias_q_v2``."""
        self._shift += dsoc
        self._moments = None
        self.bias_mean_v *= decay
        self.bias_var_v2 = decay * decay * self.bias_var_v2 + bias_q_v2

    def update(self, residual_v: np.ndarray, r_v2: float) -> None:
        """One reading: ``residual_v`` the voltage less each point's prediction without
        ``b``; ``r_v2`` the white variance (module docstring's update)."""
        innovation = residual_v - self.bias_mean_v
        self._moments = None
        s = self.bias_var_v2 + r_v2
        self.log_w = self.log_w - 0.5 * innovation * innovation / s
        self.log_w -= self.log_w.max()  # the weights' scale is free: keep the largest at 1
        gain = self.bias_var_v2 / s
        self.bias_mean_v = self.bias_mean_v + gain * innovation
        self.bias_var_v2 *= 1.0 - gain

    def moments(self) -> tuple[float, float]:
        """The posterior's mean and variance of the SoC."""
        if self._moments is None:
            w = np.exp(self.log_w)
            w /= w.sum()
            s = self.soc
            mean = float(w @ s)
            d = s - mean
            self._moments = (mean, float(w @ (d * d)))
        return self._moments

    def squared_distance(self, soc: float) -> float:
        """The posterior's mean squared distance from ``soc``: variance plus bias squared, what
        an estimate ``soc`` is off by in expectation."""
        mean, var = self.moments()
        return var + (mean - soc) ** 2
