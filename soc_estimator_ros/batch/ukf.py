"""t2rc_ukf for K independent filters in lock-step: one :meth:`BatchT2rcUkf.step` advances all.

The arithmetic of :class:`~soc_estimator_ros.estimators.t2rc_ukf.T2rcUkf` stepped through
:meth:`Estimator.step <soc_estimator_ros.estimators.base.Estimator.step>` (filterpy 2's
``UnscentedKalmanFilter``, Van der Merwe's scaled sigma points), with every operation
vectorized over the lanes (arrays whose last axis is the lane). Per lane and sample, after
Wan & van der Merwe (2000), "The unscented Kalman filter for nonlinear estimation", with
``N`` states, ``lambda = alpha^2 (N + kappa) - N``:

* sigma points ``X_0 = x``, ``X_i = x + [sqrt((N + lambda) P)]_i``,
  ``X_{N+i} = x - [sqrt((N + lambda) P)]_i`` (the lower Cholesky factor's columns);
* weights ``W0m = lambda / (N + lambda)``, ``W0c = W0m + 1 - alpha^2 + beta``,
  ``Wim = Wic = 1 / (2 (N + lambda))`` (filterpy's ``MerweScaledSigmaPoints``, reused);
* predict: ``X'_i = f(X_i)`` (the Thevenin step over ``dt``), ``x- = sum Wm X'``,
  ``P- = sum Wc (X' - x-)(X' - x-)^T + Q dt``; filterpy 2 then redraws the sigma points from
  ``(x-, P-)`` and the update reads those;
* update: ``Z_i = h(X_i)`` (terminal voltage), ``z = sum Wm Z``,
  ``S = sum Wc (Z - z)^2 + R``, ``P_xz = sum Wc (X - x-)(Z - z)``, ``K = P_xz / S``,
  ``x = x- + K (v - z)``, ``P = P- - K S K^T``.

Around it :mod:`~soc_estimator_ros.estimators.base`'s rules, per lane: the first sample runs
an update only; ``dt <= 0`` (or NaN) is rejected (state untouched); ``dt > max_step_s`` is a
gap (the mean current over it, the SoC variance grown after the redraw, as ``step`` does);
the covariance is symmetrized and its eigenvalues floored after the update (after the
predict, ``P-`` is symmetric by construction and positive definite wherever the redraw's
factor exists, where the per-sample path raises otherwise: its conditioning there changes
nothing, so it is not repeated); the SoC is clipped to [0, 1] with the clipped amount added
to its variance (up to 1). The surface lag's modes are carried beside the state, stepped from
the SoC before the predict.

The sums over the 2N + 1 points are taken in closed form where the points share a value,
which is what makes the engine fast (the arrays are ``(N, K)``, not ``(N, 2N + 1, K)``). The
lower factor ``L`` has zeros above its diagonal, so only column 0 moves the SoC: the pair
``x +- L_0`` and the centre read the tables and the OCV at their own SoC (three values per
lane), and every other pair ``x +- L_i`` (i >= 1) sits at the centre's SoC, where the model is
linear in the branch voltages. With ``w = Wim = Wic`` and ``c = 2 w (N - 1)``:

* predict: ``X'_0 = f(x)``, ``X'_+- = f(x +- L_0)``, and for i >= 1
  ``f(x +- L_i) = X'_0 +- M_i``, ``M_i = [0, a(x_0) L_i[1:]]`` (the branches' decay ``a``);
  so ``x- = (W0m + c) X'_0 + w (X'_+ + X'_-)`` and, with ``D = X' - x-``,
  ``P- = (W0c + c) D_0 D_0^T + w (D_+ D_+^T + D_- D_-^T) + 2 w sum_i M_i M_i^T + Q dt``;
* update: ``Z_0 = h(x-)``, ``Z_+- = h(x- +- L_0)``, for i >= 1 ``h(x- +- L_i) = Z_0 -+ l_i``
  with ``l_i`` the sum of ``L_i``'s branch rows (the voltage subtracts the branches); so
  ``z = (W0m + c) Z_0 + w (Z_+ + Z_-)``, ``S = (W0c + c) dz_0^2 + w (dz_+^2 + dz_-^2) +
  2 w sum_i l_i^2 + R`` and ``P_xz = w L_0 (dz_+ - dz_-) - 2 w sum_i l_i L_i``.

These are the equations above with equal terms added once; the per-sample path adds them
one by one, so the two differ by rounding only.

Agreement with the per-sample path: the same equations in a different rounding order (numpy
reductions for BLAS dot products, ``np.exp`` for ``math.exp``, the tables' bilinear
interpolation in another order), a few ulp per operation; over the bundled recordings the SoC
stays within 1e-9 of the filterpy path (``test/unit/batch/test_ukf.py``).

Not reproduced (refused at construction or documented): estimators other than t2rc_ukf (the
hybrid's gates, model-error state and guard), a model without RC branches, ``set_health``
(the engine's model is the battery file's: its capacity, ``r0_factor`` 1), and the tracker
around the estimator (``tracking/``: the input gate, the OCV start, FULL), which
``replay/batch.py`` keeps the tracker's, applying its resets with :meth:`reset_soc`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from enum import IntEnum
from typing import Any

import numpy as np

from ..errors import SocEstimatorError
from ..estimators.base import StepStatus, TimePolicy
from ..estimators.t2rc_ukf import BatchMerweScaledSigmaPoints, T2rcUkf, check_sigma_weights
from ..models.thevenin import TheveninModel
from ..params import BatteryParams
from ..units import MAX_SOC_VAR, SECONDS_PER_HOUR
from .linalg import cholesky_lanes, condition_lanes


class BatchError(SocEstimatorError, ValueError):
    """A batch run that cannot be set up, or a lane whose filter failed (lane named)."""


class LaneStatus(IntEnum):
    """What one lane did at one step (:class:`StepStatus` and ``FROZEN``)."""

    FROZEN = 0  # no sample for this lane at this step (its recording ended or skips it)
    INITIALIZED = 1
    OK = 2
    GAP = 3
    REJECTED_DT = 4

    @property
    def step_status(self) -> StepStatus | None:
        """The per-sample path's status (None for ``FROZEN``: no sample)."""
        return _STEP_STATUS[self]


_STEP_STATUS = {
    LaneStatus.FROZEN: None,
    LaneStatus.INITIALIZED: StepStatus.INITIALIZED,
    LaneStatus.OK: StepStatus.OK,
    LaneStatus.GAP: StepStatus.GAP,
    LaneStatus.REJECTED_DT: StepStatus.REJECTED_DT,
}


@dataclass(frozen=True)
class UkfTuning:
    """One lane's t2rc_ukf tuning (``T2rcUkf.default_tuning`` with a file's block over it).

    Attributes:
        q_diag: process noise per second, one per state (SoC^2/s, V^2/s, ...).
        r_v2: measurement variance, V^2.
        p0_v2: initial branch-voltage variance, V^2.
        alpha, beta, kappa: Van der Merwe's sigma-point parameters.
    """

    q_diag: tuple[float, ...]
    r_v2: float
    p0_v2: float
    alpha: float
    beta: float
    kappa: float

    @classmethod
    def of(cls, tuning: Mapping[str, Any] | None = None) -> UkfTuning:
        """From a tuning mapping (a battery file's ``filters.t2rc_ukf`` block, or entries of
        it) over the defaults; unknown entries are refused as ``T2rcUkf`` refuses them."""
        m = T2rcUkf.merged_tuning(tuning)
        return cls(
            tuple(float(q) for q in m["q_diag"]),
            float(m["r"]),
            float(m["p0_v"]),
            float(m["alpha"]),
            float(m["beta"]),
            float(m["kappa"]),
        )


def file_tuning(battery: BatteryParams) -> Mapping[str, Any] | None:
    """The tuning ``make_estimator("t2rc_ukf", battery, ...)`` uses: the file's block."""
    return battery.filters.get(T2rcUkf.name)


@dataclass(frozen=True)
class LaneStep:
    """Every lane's output of one :meth:`BatchT2rcUkf.step` (arrays of shape ``(K,)``).

    ``soc``/``soc_var`` are the lane's state after the step (a frozen or rejected lane's is
    unchanged); ``voltage_pred_v``, ``innovation_v`` and ``nis`` are NaN where no update ran.
    """

    soc: np.ndarray
    soc_var: np.ndarray
    status: np.ndarray  # LaneStatus values (int8)
    voltage_pred_v: np.ndarray
    innovation_v: np.ndarray
    nis: np.ndarray


class BatchT2rcUkf:
    """K t2rc_ukf filters of one battery, each with its own start and tuning.

    Args:
        battery: the battery file (its Thevenin model, capacity, charge efficiency).
        initial_soc: each lane's start, shape ``(K,)`` (a scalar for all).
        initial_soc_std: its standard deviation (``Estimator``'s default 0.05).
        tunings: one :class:`UkfTuning` (or mapping) per lane, or one for all; default the
            battery file's ``filters.t2rc_ukf`` block over the estimator's defaults.
        time_policy: as ``Estimator``'s (default: 0.1 C of unknown current in a gap).
    """

    def __init__(
        self,
        battery: BatteryParams,
        initial_soc: np.ndarray | float,
        initial_soc_std: np.ndarray | float = 0.05,
        tunings: Sequence[UkfTuning | Mapping[str, Any]]
        | UkfTuning
        | Mapping[str, Any]
        | None = None,
        time_policy: TimePolicy | None = None,
    ) -> None:
        soc0 = np.atleast_1d(np.asarray(initial_soc, dtype=float))
        k = soc0.size
        std0 = np.broadcast_to(np.asarray(initial_soc_std, dtype=float), (k,)).copy()
        if not np.all((soc0 >= 0.0) & (soc0 <= 1.0)):
            raise BatchError(f"initial_soc must be within [0, 1] on every lane, got {soc0}")
        if not np.all(std0 > 0.0):
            raise BatchError(f"initial_soc_std must be > 0 on every lane, got {std0}")
        self.model: TheveninModel = battery.thevenin_model()
        self.n = n = self.model.dim_x
        if self.model.n_rc == 0:
            raise BatchError(f"{battery.name}: the batch engine needs a model with RC branches")
        self.k = k
        self.capacity_ah = battery.capacity_ah
        self.time_policy = time_policy or TimePolicy(gap_current_std_a=0.1 * battery.capacity_ah)
        self._set_tunings(self._lane_tunings(battery, tunings, k))
        # State, lane last: x (n, K), P (n, n, K), the surface lag's modes (n_modes, K).
        self.x = np.zeros((n, k))
        self.x[0] = soc0
        self.p = np.zeros((n, n, k))
        self.p[0, 0] = std0 * std0
        for i in range(1, n):
            self.p[i, i] = self.p0_v2
        self.z_modes = np.zeros((len(self.model.surface_rest()), k))
        self.t_last_s = np.full(k, math.nan)  # NaN: not started
        self.current_last_a = np.zeros(k)
        self.clip_count = np.zeros(k, dtype=np.int64)

    # -- configuration -----------------------------------------------------------------------
    @staticmethod
    def _lane_tunings(battery, tunings, k: int) -> list[UkfTuning]:
        if tunings is None:
            return [UkfTuning.of(file_tuning(battery))] * k
        if isinstance(tunings, UkfTuning | Mapping):
            one = tunings if isinstance(tunings, UkfTuning) else UkfTuning.of(tunings)
            return [one] * k
        lanes = [t if isinstance(t, UkfTuning) else UkfTuning.of(t) for t in tunings]
        if len(lanes) != k:
            raise BatchError(f"tunings: one per lane needed, got {len(lanes)} for {k} lanes")
        return lanes

    def _set_tunings(self, lanes: list[UkfTuning]) -> None:
        n, k = self.n, self.k
        s = 2 * n + 1
        self.wm = np.empty((s, k))
        self.wc = np.empty((s, k))
        self.scale = np.empty(k)  # N + lambda
        weights: dict[tuple[float, float, float], tuple[np.ndarray, np.ndarray, float]] = {}
        for lane, t in enumerate(lanes):
            if len(t.q_diag) != n:
                raise BatchError(f"lane {lane}: q_diag needs {n} values, got {t.q_diag}")
            key = (t.alpha, t.beta, t.kappa)
            if key not in weights:
                points = BatchMerweScaledSigmaPoints(n, t.alpha, t.beta, t.kappa)
                check_sigma_weights(T2rcUkf.name, points)
                weights[key] = (points.Wm, points.Wc, points.lambda_ + n)
            self.wm[:, lane], self.wc[:, lane], self.scale[lane] = weights[key]
        self.q_diag = np.array([t.q_diag for t in lanes]).T  # (n, K)
        self.r_v2 = np.array([t.r_v2 for t in lanes])
        self.p0_v2 = np.array([t.p0_v2 for t in lanes])

    # -- the state ---------------------------------------------------------------------------
    @property
    def soc(self) -> np.ndarray:
        return self.x[0].copy()

    @property
    def soc_var(self) -> np.ndarray:
        return self.p[0, 0].copy()

    def reset_soc(self, lanes: np.ndarray, soc: np.ndarray, soc_var: np.ndarray) -> None:
        """``Estimator.reset_soc`` on the lanes ``lanes`` (a boolean mask or indices): a pack
        at rest at ``soc`` with variance ``soc_var`` (the branch voltages and the surface lag
        relaxed, ``p0_v`` on the branches); the time base and the last current are kept."""
        soc = np.asarray(soc, dtype=float)
        var = np.asarray(soc_var, dtype=float)
        if not np.all((soc >= 0.0) & (soc <= 1.0)) or not np.all(var > 0.0):
            raise BatchError(f"reset_soc needs soc in [0, 1] and variance > 0, got {soc}, {var}")
        idx = np.flatnonzero(lanes) if np.asarray(lanes).dtype == bool else np.asarray(lanes)
        self.x[:, idx] = 0.0
        self.x[0, idx] = soc
        self.p[:, :, idx] = 0.0
        self.p[0, 0, idx] = var
        for i in range(1, self.n):
            self.p[i, i, idx] = self.p0_v2[idx]
        self.z_modes[:, idx] = 0.0

    # -- one step of every lane ----------------------------------------------------------------
    def step(
        self,
        t_s: np.ndarray,
        current_a: np.ndarray,
        voltage_v: np.ndarray,
        temperature_c: np.ndarray | None = None,
        active: np.ndarray | None = None,
    ) -> LaneStep:
        """One sample per lane (arrays of shape ``(K,)``; temperature NaN or None: unknown,
        as ``None`` in ``Estimator.step``). A lane where ``active`` is False has no sample:
        it is left as it is (status ``FROZEN``); so is a lane whose ``dt`` is rejected (status
        ``REJECTED_DT``)."""
        k = self.k
        t = np.asarray(t_s, dtype=float)
        cur = np.asarray(current_a, dtype=float)
        volt = np.asarray(voltage_v, dtype=float)
        temp = np.full(k, math.nan) if temperature_c is None else np.asarray(temperature_c, float)
        act = np.ones(k, dtype=bool) if active is None else np.asarray(active, dtype=bool)
        status = np.zeros(k, dtype=np.int8)
        nan = np.full(k, math.nan)
        v_pred, innov, nis = nan, nan.copy(), nan.copy()
        started = ~np.isnan(self.t_last_s)
        with np.errstate(invalid="ignore"):
            dt = t - self.t_last_s
            accepted = ~started | (dt > 0.0)
        status[act & ~accepted] = LaneStatus.REJECTED_DT
        work = act & accepted
        if work.any():
            lanes = slice(None) if work.all() else np.flatnonzero(work)
            out = self._advance(lanes, t, cur, volt, temp, dt, started)
            status[lanes], v_pred[lanes], innov[lanes], nis[lanes] = out
        return LaneStep(self.x[0].copy(), self.p[0, 0].copy(), status, v_pred, innov, nis)

    def _advance(self, lanes, t, cur, volt, temp, dt, started):
        """Predict (where started) and update the lanes ``lanes``; write their state back."""
        x, p, z = self.x[:, lanes], self.p[:, :, lanes], self.z_modes[:, lanes]
        scale = self.scale[lanes]
        i_k, v_k, temp_k, dt_k = cur[lanes], volt[lanes], temp[lanes], dt[lanes]
        started_k = started[lanes]
        i_last = self.current_last_a[lanes]
        status = np.full(i_k.shape, LaneStatus.INITIALIZED, dtype=np.int8)
        gap = np.zeros(i_k.shape, dtype=bool)
        w0m, w0c, w = self.wm[0, lanes], self.wc[0, lanes], self.wc[1, lanes]
        if started_k.any():
            gap = started_k & (dt_k > self.time_policy.max_step_s)
            status[started_k] = LaneStatus.OK
            status[gap] = LaneStatus.GAP
            # the current held over the step (zero-order hold), the ends' mean over a gap
            i_held = np.where(gap, 0.5 * (i_last + i_k), i_last)
            dt_safe = np.where(started_k, dt_k, 1.0)  # a starting lane does not predict
            low = self._factor(p, scale, lanes)
            x_pred, p_pred = self._predict(
                x, low, w0m, w0c, w, self.q_diag[:, lanes], i_held, dt_safe, temp_k
            )
            lag = self.model.params.surface_lag
            z_new = z if lag is None else lag.step_lanes(z, i_held, dt_safe, x[0])
            if not started_k.all():
                x_pred = np.where(started_k, x_pred, x)
                p_pred = np.where(started_k, p_pred, p)
                z_new = np.where(started_k, z_new, z)
            x, p, z = x_pred, p_pred, z_new
        # The update's sigma points: from (x-, P-) before a gap's inflation (filterpy 2 redraws
        # them inside predict; a starting lane's from its initial x, P). P- is symmetric by
        # construction and positive definite where this factor exists (the per-sample path
        # raises otherwise), so its conditioning after the predict changes nothing.
        low = self._factor(p, scale, lanes)
        if gap.any():
            q = self.time_policy.gap_current_std_a * dt_k / (SECONDS_PER_HOUR * self.capacity_ah)
            p[0, 0] = np.where(gap, p[0, 0] + q * q, p[0, 0])
        z_soc = z.sum(axis=0) if z.shape[0] else np.zeros(i_k.shape)
        x, p, y, s = self._update(x, p, low, w0m, w0c, w, i_k, v_k, temp_k, z_soc, lanes)
        # SoC clipped to [0, 1], the clipped amount added to its variance (up to MAX_SOC_VAR)
        soc = x[0]
        clipped = np.clip(soc, 0.0, 1.0)
        moved = clipped != soc
        if moved.any():
            grow = np.minimum((soc - clipped) ** 2, np.maximum(MAX_SOC_VAR - p[0, 0], 0.0))
            p[0, 0] = np.where(moved, p[0, 0] + grow, p[0, 0])
            x[0] = clipped
            if isinstance(lanes, slice):
                self.clip_count += moved
            else:
                self.clip_count[lanes] += moved
        p = condition_lanes(p)
        self.x[:, lanes], self.p[:, :, lanes], self.z_modes[:, lanes] = x, p, z
        self.t_last_s[lanes] = t[lanes]
        self.current_last_a[lanes] = i_k
        return status, v_k - y, y, y * y / s

    def _factor(self, p, scale, lanes) -> np.ndarray:
        """The lower Cholesky factor of ``(N + lambda) P``, whose columns the sigma points add
        to the mean. A lane without one fails (the per-sample path raises numpy's
        LinAlgError there)."""
        low, ok = cholesky_lanes(scale * p)
        if not ok.all():
            bad = np.flatnonzero(~ok)
            lane = bad[0] if isinstance(lanes, slice) else lanes[bad[0]]
            raise BatchError(
                f"lane {lane}: the covariance is not positive definite (as the per-sample "
                f"filter, which raises LinAlgError there); {bad.size} lane(s) failed"
            )
        return low

    def _predict(self, x, low, w0m, w0c, w, q_diag, i_held, dt, temp):
        """``(x-, P-)``: the unscented transform of the Thevenin step over ``dt`` with
        ``i_held`` and ``Q = diag(q) dt`` (module docstring's closed-form sums)."""
        n = self.n
        model = self.model
        col = low[:, 0]  # L_0: the only column that moves the SoC
        soc3 = np.stack([x[0], x[0] + col[0], x[0] - col[0]])
        a, b = model.branch_step_lanes(soc3, i_held, dt, temp)  # (n_rc, 3, K)
        soc_new = model.soc_step_lanes(soc3, i_held, dt)
        f0 = np.concatenate([soc_new[:1], a[:, 0] * x[1:] + b[:, 0]])
        fp = np.concatenate([soc_new[1:2], a[:, 1] * (x[1:] + col[1:]) + b[:, 1]])
        fm = np.concatenate([soc_new[2:], a[:, 2] * (x[1:] - col[1:]) + b[:, 2]])
        c = 2.0 * (n - 1) * w
        x_pred = (w0m + c) * f0 + w * (fp + fm)
        d0, dp, dm = f0 - x_pred, fp - x_pred, fm - x_pred
        m = a[:, 0, np.newaxis] * low[1:, 1:]  # M_i's branch rows: (n_rc, n - 1, K)
        mm = 2.0 * w * np.einsum("ick,jck->ijk", m, m)  # 2 w sum_i M_i M_i^T, branch block
        p_pred = np.empty((n, n, x.shape[1]))
        for i in range(n):
            for j in range(i, n):
                v = (w0c + c) * d0[i] * d0[j] + w * (dp[i] * dp[j] + dm[i] * dm[j])
                if i:
                    v = v + mm[i - 1, j - 1]
                p_pred[i, j] = p_pred[j, i] = v
            p_pred[i, i] += q_diag[i] * dt
        return x_pred, p_pred

    def _update(self, x, p, low, w0m, w0c, w, i_k, v_k, temp_k, z_soc, lanes):
        """``(x, P, innovation, S)`` after the voltage update (closed-form sums)."""
        n = self.n
        col = low[:, 0]
        soc3 = np.stack([x[0], x[0] + col[0], x[0] - col[0]])
        g = self.model.open_voltage_lanes(soc3, i_k, temp_k, z_soc)  # (3, K)
        # h(X) = g(SoC) - the branch voltages, added left to right as the model adds them
        v0, vp, vm = x[1], x[1] + col[1], x[1] - col[1]
        ell = low[1].copy()  # l_i: the sum of column i's branch rows
        for r in range(2, n):
            v0, vp, vm = v0 + x[r], vp + (x[r] + col[r]), vm + (x[r] - col[r])
            ell = ell + low[r]
        h0, hp, hm = g[0] - v0, g[1] - vp, g[2] - vm
        c = 2.0 * (n - 1) * w
        zp = (w0m + c) * h0 + w * (hp + hm)
        dz0, dzp, dzm = h0 - zp, hp - zp, hm - zp
        ell = ell[1:]  # columns i >= 1
        s = (w0c + c) * dz0 * dz0 + w * (dzp * dzp + dzm * dzm) + 2.0 * w * (ell * ell).sum(0)
        s = s + self.r_v2[lanes]
        pxz = w * col * (dzp - dzm) - 2.0 * w * (low[:, 1:] * ell).sum(axis=1)
        gain = pxz * (1.0 / s)
        y = v_k - zp
        x = x + gain * y
        ks = gain * s
        p = p - ks[:, np.newaxis] * gain[np.newaxis, :]
        return x, p, y, s
