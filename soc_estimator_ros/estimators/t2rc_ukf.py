"""T2RC+UKF: the 2-RC Thevenin model with an unscented Kalman filter (seed 000 §3.2).

State ``[SoC, V_1, V_2]``, measurement the terminal voltage (eq. 14), filterpy's
``UnscentedKalmanFilter`` with Van der Merwe's scaled sigma points. Parameters come from the
battery file's SoC (and temperature) tables, evaluated per sigma point.

Where the paper is wrong (eqs. 26-42), checked against Wan & van der Merwe (2000), which
filterpy implements:

* eqs. 30 and 34 print the weights with gamma; they are W0m = lambda / (N + lambda) and
  W0c = lambda / (N + lambda) + (1 - alpha^2 + beta), with lambda = alpha^2 (N + kappa) - N;
* eq. 35 prints ``1 / (2 (N + 9 gamma))``; Wic = Wim = 1 / (2 (N + lambda));
* eq. 38 drops the weights and the measurement noise: P_y = sum Wc (Y - y)(Y - y)^T + R;
  eq. 39 drops the weights too;
* eq. 40 prints the gain as P_y P_xy; it is L = P_xy P_y^-1;
* sums run over 2N + 1 points, i = 0..2N (the paper writes 2n + 1 as the upper index).

Process noise is per second (``q_diag``) and scaled by dt. filterpy's UKF update
(P - K S K^T) is not symmetric-preserving, so the base class symmetrizes and guards P after
every step (long-run test: 100 000 steps).
"""

from __future__ import annotations

import numpy as np
from filterpy.kalman import MerweScaledSigmaPoints, UnscentedKalmanFilter, unscented_transform

from ..models.thevenin import TheveninModel
from .base import Estimator, cholesky_lower
from .filterpy_state import FilterpyState


def batch_unscented_transform(sigmas, wm, wc, noise_cov=None, mean_fn=None, residual_fn=None):
    """filterpy's ``unscented_transform`` with the weights' diagonal matrix never built.

    filterpy computes ``y.T @ (diag(Wc) @ y)``; ``Wc[:, None] * y`` is that inner product
    exactly (one non-zero term per element), so the result is the same to the bit. Custom
    mean or residual functions go to filterpy's own transform.
    """
    if mean_fn is not None or residual_fn not in (None, np.subtract):
        return unscented_transform(sigmas, wm, wc, noise_cov, mean_fn, residual_fn)
    x = np.dot(wm, sigmas)
    y = sigmas - x[np.newaxis, :]
    cov = np.dot(y.T, wc[:, np.newaxis] * y)
    if noise_cov is not None:
        cov += noise_cov
    return x, cov


class BatchMerweScaledSigmaPoints(MerweScaledSigmaPoints):
    """filterpy's Van der Merwe sigma points and weights, generated without a Python loop."""

    def __init__(self, n, alpha, beta, kappa, sqrt_method=None, subtract=None):
        super().__init__(n, alpha, beta, kappa, sqrt_method, subtract)
        # [0, +I, -I] as columns: U @ this is [0, U, -U], exactly (one +-1 term per element).
        self._offsets_t = np.hstack([np.zeros((n, 1)), np.eye(n), -np.eye(n)])

    def sigma_points(self, x, P):  # noqa: N803 (filterpy's names)
        u = cholesky_lower((self.lambda_ + self.n) * P)  # lower: columns are the offsets
        # Rows x, x + U^T, x - U^T, built transposed: the (2n+1, n) result is column-major,
        # as np.vstack makes it from filterpy-style (x + U^T) blocks. The layout decides which
        # BLAS kernel the transform's products take, and so their last bit.
        x = np.asarray(x, dtype=float)
        return (x[:, np.newaxis] + u @ self._offsets_t).T

    @property
    def lambda_(self) -> float:
        return self.alpha**2 * (self.n + self.kappa) - self.n


def check_sigma_weights(name: str, points: MerweScaledSigmaPoints) -> None:
    """Refuse sigma-point parameters that give a covariance weight < 0.

    With every Wc >= 0 the predicted covariance is a sum of positive semi-definite terms plus
    Q, so it stays positive definite whatever the model does between the sigma points. A
    negative centre weight (alpha < 0.52 at beta 2, kappa 0: Wc0 = 4 - alpha^2 - 1/alpha^2)
    lets it lose that where the transition is nonlinear (branch tables changing with the SoC
    across the points): measured, the hybrid with alpha 0.03 on LFP field run 2 grew a branch
    variance to 1e74 V^2 and failed its Cholesky 34 minutes in.
    """
    if points.n + points.lambda_ <= 0.0 or float(np.min(points.Wc)) < 0.0:
        raise ValueError(
            f"{name}: sigma points alpha={points.alpha:g}, beta={points.beta:g}, "
            f"kappa={points.kappa:g} give a negative covariance weight (Wc0 = "
            f"{points.Wc[0]:.4g}); the filter needs every Wc >= 0 (with beta 2 and kappa 0: "
            "alpha between 0.52 and 1)"
        )


class BatchUnscentedKalmanFilter(UnscentedKalmanFilter):
    """filterpy's UKF with the per-sigma-point Python loops done in one batched call.

    ``fx(sigmas, dt, **args)`` and ``hx(sigmas, **args)`` take and return arrays with one
    sigma point per row. The algebra is filterpy's (same sigma points, weights, unscented
    transform and update equations, evaluated to the same bits); only the loops over sigma
    points are batched and the per-call overhead trimmed (:func:`batch_unscented_transform`,
    LAPACK's Cholesky called directly, ``S^-1`` as ``1 / S`` for a scalar measurement), which
    is what makes the replay fast enough (see benchmarks/).
    """

    x: np.ndarray  # filterpy's state and covariance (its class is untyped)
    P: np.ndarray

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self._wc_col = self.Wc[:, np.newaxis]

    def compute_process_sigmas(self, dt, fx=None, **fx_args):
        fx = self.fx if fx is None else fx
        sigmas = self.points_fn.sigma_points(self.x, self.P)
        self.sigmas_f = fx(sigmas, dt, **fx_args)

    def cross_variance(self, x, z, sigmas_f, sigmas_h):
        return ((sigmas_f - x) * self.Wc[:, np.newaxis]).T @ (sigmas_h - z)

    def predict(self, dt=None, UT=None, fx=None, **fx_args):  # noqa: N803 (filterpy's names)
        """filterpy's predict, with :func:`batch_unscented_transform` as the default UT."""
        super().predict(dt, batch_unscented_transform if UT is None else UT, fx, **fx_args)

    def update(self, z, R=None, UT=None, hx=None, **hx_args):  # noqa: N803 (filterpy's names)
        hx = self.hx if hx is None else hx
        R = self.R if R is None else R  # noqa: N806
        self.sigmas_h = sigmas_h = hx(self.sigmas_f, **hx_args)
        if UT is None and self.z_mean is None and self.residual_z is np.subtract:
            # batch_unscented_transform inline, its residuals reused for the cross-covariance
            # (filterpy computes the same differences twice).
            wc = self._wc_col
            zp = np.dot(self.Wm, sigmas_h)
            dz = sigmas_h - zp
            self.S = np.dot(dz.T, wc * dz) + R
            pxz = ((self.sigmas_f - self.x) * wc).T @ dz
        else:
            UT = batch_unscented_transform if UT is None else UT  # noqa: N806
            zp, self.S = UT(self.sigmas_h, self.Wm, self.Wc, R, self.z_mean, self.residual_z)
            pxz = self.cross_variance(self.x, zp, self.sigmas_f, sigmas_h)
        # A 1x1 inverse is 1 / s (what LAPACK's solve of s x = 1 returns), without the call.
        self.SI = 1.0 / self.S if self.S.shape == (1, 1) else np.linalg.inv(self.S)
        self.K = pxz @ self.SI
        self.y = np.asarray(z, dtype=float) - zp
        self.x = self.x + self.K @ self.y
        self.P = self.P - self.K @ self.S @ self.K.T
        self.z = np.array(z, dtype=float)
        self.x_post = self.x.copy()
        self.P_post = self.P.copy()


class T2rcUkf(FilterpyState, Estimator):
    """UKF on the 2-RC Thevenin model (SoC is a state)."""

    name = "t2rc_ukf"
    count_floor = True  # the published variance floored by a charge count (base.py)
    state_names: tuple[str, ...] = ("soc", "v1_v", "v2_v")
    soc_index = 0
    default_tuning = {
        "q_diag": (1.0e-10, 1.0e-6, 1.0e-6),  # per second: SoC^2/s, V^2/s, V^2/s
        # V^2: (1 V)^2. Not the ADC's noise (2 mV) but the 2RC model's error: identified from
        # 0.2 C pulses alone, it misses the voltage by 0.4-2 V under the field runs' 10-30 A
        # bursts (docs/accuracy.md; the LFP file). With (20 mV)^2 the filter follows that
        # error: 27-34 % MAE on SLA with such a file.
        "r": 1.0,
        "p0_v": 1.0e-4,  # V^2: initial branch-voltage variance
        "alpha": 1.0,
        "beta": 2.0,
        "kappa": 0.0,
    }
    positive_tuning = frozenset({"alpha"})  # the sigma points' spread divides the weights
    signed_tuning = frozenset({"kappa"})

    def _make_model(self) -> TheveninModel:
        return self.battery.thevenin_model()

    def _init_state(self, soc: float, soc_var: float) -> None:
        if not hasattr(self, "kf"):
            self.model = self._make_model()
            q_len, model_dim = len(self.tuning["q_diag"]), self.model.dim_x
            if q_len != model_dim:  # the tuning's q_diag is the 2-RC model's (SoC, V_1, V_2)
                raise ValueError(
                    f"{self.name}: its tuning is for a {q_len - 1}-RC model (q_diag), the "
                    f"battery file's has {model_dim - 1} RC branch(es): use a 2-RC file, or "
                    "ekf, rc_kf or coulomb"
                )
            n = self._rested_state(0.5).size
            points = BatchMerweScaledSigmaPoints(
                n, self.tuning["alpha"], self.tuning["beta"], self._sigma_kappa()
            )
            check_sigma_weights(self.name, points)
            self.kf = BatchUnscentedKalmanFilter(
                dim_x=n, dim_z=1, dt=0.1, hx=self._hx, fx=self._fx, points=points
            )
            self.kf.R = np.array([[self.tuning["r"]]])
        self.kf.x = self._rested_state(soc)
        self.kf.P = self._initial_covariance(soc_var)
        # The surface lag (models/thevenin.py): driven by the current alone, carried beside the
        # state; a (re)start is a pack at rest, whose surface has caught up. ``z_modes`` are
        # its modes, ``z_soc`` their sum (what the voltage reads).
        self.z_modes = self.model.surface_rest()
        self.z_soc = 0.0

    def _sigma_kappa(self) -> float:
        """Van der Merwe's ``kappa`` for the sigma points: the tuning's."""
        return float(self.tuning["kappa"])

    def _rested_state(self, soc: float) -> np.ndarray:
        """The filter's state for a pack at rest at ``soc``."""
        return self.model.rested_state(soc)

    def _initial_covariance(self, soc_var: float) -> np.ndarray:
        """P0: ``soc_var`` for the SoC, ``p0_v`` for each branch voltage."""
        return np.diag([soc_var] + [self.tuning["p0_v"]] * self.model.n_rc)

    def _fx(self, xs: np.ndarray, dt: float, current_a: float = 0.0, temp_c=None) -> np.ndarray:
        return self.model.step_batch(xs, current_a, dt, temp_c)

    def _hx(self, xs: np.ndarray, current_a: float = 0.0, temp_c=None) -> np.ndarray:
        return self.model.terminal_voltage_batch(xs, current_a, temp_c, self.z_soc)[:, np.newaxis]

    def rest_ocv_v(self, current_a: float, voltage_v: float, temp_c) -> float:
        """``voltage_v`` less what the model adds to the OCV curve at the present state (the
        branches' remaining relaxation, the surface lag, the temperature offset): the voltage
        the curve shows at the filter's SoC."""
        x = self.kf.x[np.newaxis, : self.model.dim_x]
        v_model = float(self.model.terminal_voltage_batch(x, current_a, temp_c, self.z_soc)[0])
        return voltage_v - (v_model - self.model.ocv.ocv(float(self.kf.x[self.soc_index])))

    def _process_noise(self, dt_s: float) -> np.ndarray:
        q = self.tuning["q_diag"]
        if q is not getattr(self, "_q_key", None):  # diag(q) built once per tuning value
            self._q_key = q
            self._q_matrix = np.diag(np.asarray(q, dtype=float))
        return self._q_matrix * dt_s  # == diag(q * dt): the zeros stay zeros

    def _predict(self, dt_s: float, current_a: float, next_current_a: float, temp_c) -> None:
        soc = float(self.kf.x[0])
        self.kf.Q = self._process_noise(dt_s)
        self.kf.predict(dt=dt_s, current_a=current_a, temp_c=temp_c)
        self.z_modes = self.model.surface_step(self.z_modes, current_a, dt_s, soc)
        self.z_soc = sum(self.z_modes)

    def _measurement_variance(self, current_a: float) -> float:
        return float(self.tuning["r"])

    def _update(self, current_a: float, voltage_v: float, temp_c) -> tuple[float, float, float]:
        if self.t_last_s is None:
            # First sample: sigma points for the update come from the initial x, P.
            self.kf.sigmas_f = self.kf.points_fn.sigma_points(self.kf.x, self.kf.P)
        var = self._measurement_variance(current_a) + self.voltage_offset_var_v2
        if var != getattr(self, "_r_var", None):  # a new 1x1 R only when the variance changes
            self._r_var = var
            self._r = np.array([[var]])
        self.kf.update(np.array([voltage_v]), R=self._r, current_a=current_a, temp_c=temp_c)
        innov = float(self.kf.y[0])
        s = float(self.kf.S[0, 0])
        return voltage_v - innov, innov, innov * innov / s
