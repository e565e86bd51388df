"""RC+KF: the Saft RC model with a linear Kalman filter (seed 000 §3.1, eqs. 19-25).

States ``[V_cb, V_cs, V_o]`` of :class:`~soc_estimator_ros.models.rc_saft.SaftRcModel`,
measurement ``V_o`` (H = [0 0 1], eq. 2), filterpy's ``KalmanFilter``. The prediction uses the
exact discretization, including the ``R_eq dI/dt`` feed-through the paper's eq. 1 drops
(``u = [I_{k-1}, I_k - I_{k-1}]``). SoC is read out as OCV^-1(V_cb), with variance
``P[0,0] / slope^2`` capped at the uninformative value (``OcvCurve.soc_at_with_std``): on LFP's
plateau the readout is honest about how little V_cb says -- the paper's finding that RC+KF fails
on LFP (§4.2) shows up as a large SoC variance, not a hidden error.

Where the paper is wrong: eq. 22 prints the gain with the posterior ``P_k^+``; it is the prior
``K = P^- C^T (C P^- C^T + R)^-1``. Eq. 24 multiplies by ``L_k^T``, a name from the UKF
section; it is ``K_k^T``. filterpy implements the correct forms (Joseph update).

Process noise is given per second (``q_diag``, V^2/s) and scaled by dt, so the tuning does not
depend on the sample rate. Preset ``rc_kf_paper`` carries eq. 25 (Q = diag(1e-5, 1e-3, 0.9),
R = 0.8), read as per-second values because the paper does not give its sample period.
"""

from __future__ import annotations

import math

import numpy as np
from filterpy.kalman import KalmanFilter

from ..models.rc_saft import SaftRcModel
from ..units import MAX_SOC_VAR
from .base import Estimator
from .filterpy_state import FilterpyState


class RcKf(FilterpyState, Estimator):
    """Linear KF on the Saft RC model; SoC = OCV^-1(V_cb)."""

    name = "rc_kf"
    count_floor = True  # the published variance floored by a charge count (base.py)
    state_names = ("v_cb_v", "v_cs_v", "v_o_v")
    soc_index = 0
    default_tuning = {
        "q_diag": (1.0e-9, 1.0e-5, 1.0e-3),  # V^2/s; tuned on the bags (README table)
        "r": 4.0e-4,  # V^2: (20 mV)^2, ADC noise plus the RC model's mismatch
        "p0_vo": 2.5e-3,  # V^2: initial terminal-voltage variance
    }

    def _init_state(self, soc: float, soc_var: float) -> None:
        b = self.battery
        self.model = SaftRcModel(b.rc_model)
        self.curve = b.ocv_curve()
        if not hasattr(self, "kf"):
            self.kf = KalmanFilter(dim_x=3, dim_z=1, dim_u=2)
            self.kf.H = self.model.h.reshape(1, 3)
        v = self.curve.ocv(soc)
        var_v = soc_var * self.curve.slope(soc) ** 2
        self.kf.x = self.model.rested_state(v, self.current_last_a)
        self.kf.P = np.diag([var_v, var_v, self.tuning["p0_vo"]])
        self.kf.P[0, 1] = self.kf.P[1, 0] = var_v  # bulk and surface start equal
        self.kf.P = self.kf.P + np.eye(3) * 1e-10
        self.kf.R = np.array([[self.tuning["r"]]])

    # SoC lives in the OCV of V_cb, not in the state vector.
    @property
    def soc(self) -> float:
        return self.curve.soc_at(float(self.kf.x[0]))

    @property
    def soc_var(self) -> float:
        """Readout variance; a V_cb beyond the OCV table adds its excess (the clip shows)."""
        v_cb = float(self.kf.x[0])
        soc, std = self.curve.soc_at_with_std(v_cb, math.sqrt(max(self.kf.P[0, 0], 0.0)))
        excess_v = max(v_cb - self.curve.ocv_max_v, self.curve.ocv_min_v - v_cb, 0.0)
        excess_soc = excess_v / self.curve.slope(soc)
        return min(std * std + excess_soc * excess_soc, MAX_SOC_VAR)

    def _clip_soc(self) -> None:
        v_cb = float(self.kf.x[0])
        if v_cb < self.curve.ocv_min_v or v_cb > self.curve.ocv_max_v:
            self.clip_count += 1  # the readout clips to [0, 1]; V_cb itself is left alone

    def _inflate_soc_variance(self, var: float) -> None:
        slope = self.curve.slope(self.soc)
        self.kf.P[0, 0] += var * slope * slope

    def _predict(self, dt_s: float, current_a: float, next_current_a: float, temp_c) -> None:
        f, g_hold, g_jump = self.model.discretize(dt_s)
        b = np.column_stack([g_hold, g_jump])
        q = np.diag(np.asarray(self.tuning["q_diag"], dtype=float) * dt_s)
        self.kf.predict(u=np.array([current_a, next_current_a - current_a]), B=b, F=f, Q=q)

    def _update(self, current_a: float, voltage_v: float, temp_c) -> tuple[float, float, float]:
        v_pred = float(self.kf.x[2])
        self.kf.update(np.array([voltage_v]))
        innov = float(np.ravel(self.kf.y)[0])
        s = float(np.ravel(self.kf.S)[0])
        return v_pred, innov, innov * innov / s
