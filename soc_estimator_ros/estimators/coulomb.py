"""Coulomb counting as an estimator: the reference method (seed 000 eq. 11, seed 001's CC).

No voltage update. The variance is what the current sensor allows: white noise of
``current_std_a`` integrates as a random walk, and a gain error ``gain_error`` (0.8 % for the
LEM CAS 25-NP of seed 000) grows linearly with the charge moved; an unknown offset
``offset_a`` grows linearly with time. So coulomb counting's covariance honestly widens with
time and throughput, which is why it needs an OCV anchor (seed 000 §1).
"""

from __future__ import annotations

import math

import numpy as np

from ..models.coulomb import coulomb_step
from ..units import SECONDS_PER_HOUR
from .base import Estimator


class CoulombCounter(Estimator):
    """SoC by integrating the current from a given initial SoC."""

    name = "coulomb"
    state_names = ("soc",)
    default_tuning = {"current_std_a": 0.05, "gain_error": 0.008, "offset_a": 0.02}

    def _init_state(self, soc: float, soc_var: float) -> None:
        self.x = np.array([soc])
        self.p = np.array([[soc_var]])
        self._var0 = soc_var
        self._random_var = 0.0
        self._throughput_ah = 0.0
        self._elapsed_s = 0.0
        self._model_var = soc_var

    def _predict(self, dt_s: float, current_a: float, next_current_a: float, temp_c) -> None:
        b = self.battery
        self.x[0] = coulomb_step(
            float(self.x[0]), current_a, dt_s, self.capacity_ah, b.coulomb_efficiency_charge
        )
        q = self.capacity_ah * SECONDS_PER_HOUR
        self._random_var += (self.tuning["current_std_a"] * dt_s / q) ** 2
        self._throughput_ah += abs(current_a) * dt_s / SECONDS_PER_HOUR
        self._elapsed_s += dt_s
        systematic = (
            self.tuning["gain_error"] * self._throughput_ah / self.capacity_ah
            + self.tuning["offset_a"] * self._elapsed_s / q
        )
        # Add only the growth since the last step, so gaps and clipping added elsewhere stay.
        new_var = self._var0 + self._random_var + systematic**2
        self.p[0, 0] += max(new_var - self._model_var, 0.0)
        self._model_var = new_var

    def _update(self, current_a: float, voltage_v: float, temp_c) -> tuple[float, float, float]:
        return math.nan, math.nan, math.nan
