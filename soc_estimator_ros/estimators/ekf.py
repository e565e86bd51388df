"""EKF: the 1-RC Thevenin model with an extended Kalman filter (seed 001 §2, after [22]).

State ``[SoC, V_p]``; filterpy's ``ExtendedKalmanFilter``. The 1-RC parameters are the
battery file's n-RC tables reduced by :func:`~soc_estimator_ros.models.thevenin.one_rc_equivalent`
(seed 001 identifies a 1-RC model directly; the file keeps one set of tables). For a current
held over the step the transition is exactly affine in the state, ``x' = F x + b(I)``, so the
EKF's prediction is exact and its only linearization is the output's OCV slope
(``H = [dOCV/dSoC - I dR0/dSoC, -1]``).

Preset ``ekf_paper`` carries seed 001 Table 1 as far as the text we have can be read: the
initial SoC covariance 2.5e-1, process noise 1 on both states and measurement noise 1e-5 (the
table's exponent signs are lost in our copy; these are the readings that reproduce the paper's
behaviour: the filter follows the voltage almost sample by sample, fast at rest, biased under
load). Its "covariance V_p = 0" is replaced by 1e-9 to keep P positive definite.
"""

from __future__ import annotations

import numpy as np
from filterpy.kalman import ExtendedKalmanFilter

from ..models.coulomb import coulomb_efficiency
from ..models.thevenin import one_rc_equivalent
from ..units import SECONDS_PER_HOUR
from .base import Estimator
from .filterpy_state import FilterpyState


class Ekf(FilterpyState, Estimator):
    """EKF on the 1-RC Thevenin model."""

    name = "ekf"
    count_floor = True  # the published variance floored by a charge count (base.py)
    state_names = ("soc", "v1_v")
    soc_index = 0
    default_tuning = {
        "q_diag": (1.0e-10, 1.0e-6),  # per second: SoC^2/s, V^2/s
        "r": 4.0e-4,  # V^2
        "p0_v": 1.0e-4,  # V^2
    }

    def _init_state(self, soc: float, soc_var: float) -> None:
        if not hasattr(self, "kf"):
            self.model = self.battery.thevenin_model(one_rc_equivalent(self.battery.thevenin))
            self.kf = ExtendedKalmanFilter(dim_x=2, dim_z=1, dim_u=1)
            self.kf.R = np.array([[self.tuning["r"]]])
        self.kf.x = self.model.rested_state(soc)
        self.kf.P = np.diag([soc_var, self.tuning["p0_v"]])
        # The surface lag's modes and their sum, beside the state (t2rc_ukf.py).
        self.z_modes = self.model.surface_rest()
        self.z_soc = 0.0

    def _predict(self, dt_s: float, current_a: float, next_current_a: float, temp_c) -> None:
        m = self.model
        x = self.kf.x
        f = m.transition_jacobian(x, current_a, dt_s, temp_c)
        r1, _ = m.branch_at(0, float(x[0]), temp_c)
        eta = coulomb_efficiency(current_a, m.coulomb_efficiency_charge)
        self.kf.F = f
        self.kf.B = np.array(
            [
                [-eta * dt_s / (SECONDS_PER_HOUR * m.capacity_ah)],
                [r1 * (1.0 - f[1, 1])],
            ]
        )
        self.kf.Q = np.diag(np.asarray(self.tuning["q_diag"], dtype=float) * dt_s)
        self.kf.predict(u=np.array([current_a]))
        self.z_modes = m.surface_step(self.z_modes, current_a, dt_s, float(x[0]))
        self.z_soc = sum(self.z_modes)

    def _jacobian(self, x: np.ndarray, current_a: float, temp_c) -> np.ndarray:
        return self.model.output_jacobian(x, current_a, temp_c, self.z_soc)

    def _hx(self, x: np.ndarray, current_a: float, temp_c) -> np.ndarray:
        return np.array([self.model.terminal_voltage(x, current_a, temp_c, self.z_soc)])

    def _update(self, current_a: float, voltage_v: float, temp_c) -> tuple[float, float, float]:
        self.kf.update(
            np.array([voltage_v]),
            self._jacobian,
            self._hx,
            args=(current_a, temp_c),
            hx_args=(current_a, temp_c),
        )
        innov = float(np.ravel(self.kf.y)[0])
        s = float(np.ravel(self.kf.S)[0])
        return voltage_v - innov, innov, innov * innov / s
