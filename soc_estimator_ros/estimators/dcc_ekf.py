"""DCC-EKF: dual coulomb counting and EKF (seed 001 §2, Algorithm 2).

The EKF of ``ekf.py`` runs every sample for the first ``converge_time_s`` (the paper: 4500
iterations at 0.04 s, i.e. 180 s) so it converges from the user's initial SoC. After that, the
SoC is coulomb counted while current flows (``|I| > rest_current_a``: the paper's "non-null
current", which for a 40 mA ACS712 means a few of its steps) and the EKF corrects it again while
the pack rests or the current is low. The covariance keeps propagating in both modes, so it
widens under load and narrows at rest.
"""

from __future__ import annotations

import math

from .ekf import Ekf


class DccEkf(Ekf):
    """EKF until converged, then coulomb counting under load and EKF corrections at rest."""

    name = "dcc_ekf"
    default_tuning = {
        **Ekf.default_tuning,
        "converge_time_s": 180.0,  # seed 001: 4500 samples x 0.04 s
        "rest_current_a": 0.1,  # "null current": below this the EKF corrects
    }

    def _init_state(self, soc: float, soc_var: float) -> None:
        super()._init_state(soc, soc_var)
        self.elapsed_s = 0.0

    def _predict(self, dt_s: float, current_a: float, next_current_a: float, temp_c) -> None:
        super()._predict(dt_s, current_a, next_current_a, temp_c)
        self.elapsed_s += dt_s

    @property
    def converging(self) -> bool:
        """Still in the initial EKF-only phase."""
        return self.elapsed_s < self.tuning["converge_time_s"]

    def _update(self, current_a: float, voltage_v: float, temp_c) -> tuple[float, float, float]:
        if self.converging or abs(current_a) <= self.tuning["rest_current_a"]:
            return super()._update(current_a, voltage_v, temp_c)
        v_pred = float(self._hx(self.kf.x, current_a, temp_c)[0])
        return v_pred, math.nan, math.nan
