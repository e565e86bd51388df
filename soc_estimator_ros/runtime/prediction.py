"""What the robot asks next, computed from the pack's model (ROS-free): time to empty, time to
full, state of power, and the load forecast behind the time to empty.

Every function reads the battery file's Thevenin model (``models/thevenin.py``) and a
:class:`PackState` (the estimate now); none runs a filter. Core conventions (``units.py``):
current positive while discharging, SoC a fraction, seconds, volts, watts. The model's
steady-state terminal voltage under a constant current ``I`` at SoC ``s`` (the RC branches
charged, the surface lag settled) is::

    V_ss(s, I) = OCV(s - z_ss) + offset(s, T) - I R_0(s) - eta_k(s, I) - sum_i R_i(s) d_i(s, I)
    z_ss = sum_j g_j I [s <= soc_max_j],  eta_k = a asinh(I / i0),  d_i = s_i asinh(I / s_i)

(eq. 14 with the model's optional kinetic term, saturating branches and surface lag; each is
left out when the file has none).

**Time to empty** (:func:`time_to_empty`), to ``soc_empty`` (the battery file's
``limits.soc_min``) under a constant load power ``P``. At constant power the current rises as
the voltage falls: at each SoC the current solves ``P = I V_ss(s, I)``, and::

    T = integral from soc_empty to soc of  3600 Q / I(s)  ds          (eq. 11 with eta = 1)

on a grid of SoC midpoints. The rate dependence the model has is counted: its kinetic
(Butler-Volmer) term and its branches lower ``V_ss`` at high current, which raises the current
a power needs. Capacity lost at high current (Peukert) is **not modelled**: the model's charge
equation (eq. 11) has no rate term and a coulomb efficiency of 1 on discharge, so a discharge
removes the same charge at any current. The load is the mean, not its bursts: the ``I^2 R``
loss of a bursty load above that of its mean current is not counted. Its std::

    sigma_T^2 = (dT/dsoc sigma_soc)^2 + (dT/dP sigma_P)^2,   dT/dsoc = 3600 Q / I(soc),
    dT/dP = -integral 3600 Q / I^2 dI/dP ds,   dI/dP = 1 / (V_ss + I dV_ss/dI)

**Load forecast** (:class:`PowerWindow`): the recent mean discharge power ``P = I V`` (each
sample's power held until the next, as the estimators hold the current) over ``n`` blocks of
``window_s / n`` seconds. The blocks' means scatter with std ``sigma_b`` (the load's spread at
the block's scale). Read as independent blocks of a stationary load, the window's mean misses
the load's mean by ``sigma_b / sqrt(n)`` and the mean over a future horizon ``H`` scatters
around it by ``sigma_b sqrt(b / H)``, so ``sigma_P = sigma_b sqrt(1/n + b/H)``
(:meth:`LoadForecast.power_std_w`). A mission power the robot sets replaces the window, with a
std of ``MISSION_POWER_REL_STD`` of it.

**State of power** (:func:`state_of_power`): the largest constant current for the next 10 s
and 60 s that keeps the terminal voltage at or above ``limits.voltage_min_v`` (discharge) or at
or below ``limits.voltage_max_v`` (charge), from the present state: the model's own
zero-order-hold steps over the horizon (:meth:`TheveninModel.step`: the branches from their
present voltages, the SoC falling, the surface lag moving; ``SOP_SUBSTEPS`` steps per half
horizon, the parameters re-read at each step's SoC) and its terminal voltage (eq. 14),
checked at the start, half-way and the end of the horizon. The
current is found on a grid refined twice and interpolated; it is capped at the file's current
limits (``current_max_discharge_a``, ``current_max_charge_a``) and at the highest current the
model was fitted at (``thevenin.fitted_c_rate_max``, when the file records it): beyond it the
voltage is the model's extrapolation, not a measurement. The voltage is held to its limit with
a margin of ``SOP_CONFIDENCE_K`` (1.645, one-sided 95 %) standard deviations of the predicted
voltage (:func:`prediction_std_v`), from the estimate's own uncertainty::

    sigma_V(I)^2 = (dOCV/dsoc sigma_soc)^2 + sum_i sigma_Vi^2 + sigma_b^2 + (I sigma_dR)^2

the SoC's (through the OCV slope at the present SoC), the branch voltages' (held, not decayed:
the larger), the model-error voltage's and the series-resistance error's (the hybrid's
``bias_v`` and ``r_delta_ohm``, their variances from its covariance; 0 for an estimator
without them). A pack whose resistance the filter has not learned yet (the state's prior, 8.7 %
of the file's) gets a smaller prediction than one it has: the planner reads a current the pack
gives with that confidence, not the model's best guess (docs/accuracy.md, "State of power":
without the margin the 10-s prediction on SLA at 0 degC and 47 % SoC was 5.1 % above what
took the simulated pack to the limit, where the filter's own std of that voltage was 29 mV, and
the drawn current took it 30-40 mV below). Measured against the physics
(docs/accuracy.md, "State of power"): without that cap the 10-s prediction on the LFP pack at
32 % SoC was 60 A (the file's limit) where 50.8 A took the simulated cell to ``voltage_min_v``
(its voltage fell to 8.0 V at 60 A): the kinetic fit covered 5-s steps up to 6.2 C (36 A), and
the particles' surface runs out at 9-10 C, which no term of the model was fitted on.

**Time to full** (:func:`time_to_full`) during a CC-CV charge. CC: the present charge current
until ``V_ss`` reaches the charge voltage ``V_cv`` (at ``s_cv``; when the model stays below it
up to a full pack, as the SLA file's does, which has no gassing overvoltage, the CV phase is
taken to start at SoC 1). CV: the terminal voltage is held at ``V_cv`` while the OCV rises, so
``dOCV/dsoc dsoc/dt + R_d dI/dt = 0`` with ``dsoc/dt = eta_c I / (3600 Q)``: the current decays
with the time constant::

    tau(s, I) = 3600 Q R_d(s, I) / (eta_c dOCV/dsoc),   R_d = dV_ss/dI (differential)

(quasi-static: the branches follow the current), integrated over ``I`` on a log grid from the
CV's start to the taper current (``dt = tau dI / I``), plus what remains of the FULL
detector's hold time.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from ..models.thevenin import TheveninModel
from ..params import Limits
from ..units import SECONDS_PER_HOUR

#: Std of a mission power the robot sets, as a fraction of it (a plan, not a measurement).
MISSION_POWER_REL_STD = 0.1
#: Std of the window's power before two blocks are complete, as a fraction of its mean.
EARLY_POWER_REL_STD = 0.5
#: A sample's power is held at most this long (s): a longer gap is not counted (the power over
#: it is unknown; the estimators' ``max_step_s`` too).
MAX_HOLD_S = 5.0
#: State-of-power horizons (s).
SOP_HORIZONS_S = (10.0, 60.0)
#: Standard deviations of the predicted voltage kept between it and the limit (one-sided 95 %).
SOP_CONFIDENCE_K = 1.645
#: Grid points of each of the two passes of the state-of-power search.
_SOP_GRID = 33
#: Model steps between the times the state of power checks (parameters re-read each step).
SOP_SUBSTEPS = 3
#: SoC step of the time-to-empty integral (at most), and its number of points (bounds).
_TTE_DSOC = 0.02
_TTE_POINTS = (4, 50)


@dataclass(frozen=True)
class PackState:
    """The pack now, as the predictions read it.

    Attributes:
        soc, soc_std: the SoC estimate and its std (fractions).
        branch_v: the model's RC branch voltages ``V_1..V_n`` (V).
        surface_z: the surface lag's modes ``z_j`` (SoC; empty without a lag).
        bias_v: a model-error voltage added to the model's terminal voltage (the hybrid's
            ``bias_v``; 0 without one), held over the horizons.
        r_delta_ohm: an error on the model's series resistance (the hybrid's ``r_delta_ohm``;
            0 without one): the power predictions' voltage less ``I r_delta_ohm``.
        temperature_c: temperature (degC; None: the tables' 25 degC row).
        branch_std_v, bias_std_v, r_delta_std_ohm: the stds of ``branch_v``, ``bias_v`` and
            ``r_delta_ohm`` (the estimator's; 0 where it has no such state): with
            ``soc_std``, the state of power's margin (:func:`prediction_std_v`).
    """

    soc: float
    soc_std: float
    branch_v: tuple[float, ...]
    surface_z: tuple[float, ...] = ()
    bias_v: float = 0.0
    r_delta_ohm: float = 0.0
    temperature_c: float | None = None
    branch_std_v: tuple[float, ...] = ()
    bias_std_v: float = 0.0
    r_delta_std_ohm: float = 0.0


# -- the model's voltage, vectorized over SoC and current ---------------------------------------
# The model's own array methods (TheveninModel.*_batch, SurfaceLag.step_lanes), each element
# at its own current: one home for the model's arithmetic, the temperature law included.
def steady_voltage_v(
    model: TheveninModel,
    soc: np.ndarray,
    current_a: np.ndarray,
    temperature_c: float | None = None,
) -> np.ndarray:
    """``V_ss(s, I)`` of the module docstring, elementwise over equal-shaped 1-D ``soc`` and
    ``current_a`` (A, discharge positive): :meth:`TheveninModel.terminal_voltage_batch` with
    every branch at its steady voltage (:meth:`TheveninModel.branch_steady_batch`) and the
    surface lag at its steady ``z`` (:meth:`SurfaceLag.step_lanes` over an infinite step)."""
    soc = np.asarray(soc, dtype=float)
    i = np.asarray(current_a, dtype=float)
    xs = np.empty((soc.size, model.dim_x))
    xs[:, 0] = soc
    if model.n_rc:
        xs[:, 1:] = model.branch_steady_batch(soc, i, temperature_c).T
    lag = model.params.surface_lag
    z: float | np.ndarray = 0.0
    if lag is not None:
        z = lag.step_lanes(np.zeros((lag.n_modes, soc.size)), i, math.inf, soc).sum(axis=0)
    return model.terminal_voltage_batch(xs, i, temperature_c, z)


def terminal_path_v(
    model: TheveninModel,
    state: PackState,
    current_a: np.ndarray,
    times_s: tuple[float, ...],
    substeps: int = SOP_SUBSTEPS,
) -> np.ndarray:
    """The terminal voltage at each of ``times_s`` (increasing, s; 0 is the instant the
    current starts) of each constant current in ``current_a`` from ``state``: the model's
    zero-order-hold step (:meth:`TheveninModel.step_batch`, :meth:`SurfaceLag.step_lanes`) in
    ``substeps`` steps between consecutive times, its parameters re-read at each step's SoC,
    and :meth:`TheveninModel.terminal_voltage_batch`, plus the state's ``bias_v`` less ``I
    r_delta_ohm`` (the hybrid's ``_hx``). Shape ``(len(times_s), len(current_a))``."""
    i = np.atleast_1d(np.asarray(current_a, dtype=float))
    t_c = state.temperature_c
    xs = np.empty((i.size, model.dim_x))
    xs[:, 0] = state.soc
    xs[:, 1:] = state.branch_v
    lag = model.params.surface_lag
    z = np.empty((len(state.surface_z), i.size))
    z[:] = np.asarray(state.surface_z, dtype=float)[:, None]
    out = []
    t_prev = 0.0
    for t in times_s:
        span = t - t_prev
        if span > 0.0:
            dt_s = span / substeps
            for _ in range(substeps):
                if lag is not None:  # from the step's start SoC, as TheveninModel.surface_step
                    z = lag.step_lanes(z, i, dt_s, xs[:, 0])
                xs = model.step_batch(xs, i, dt_s, t_c)
        v = model.terminal_voltage_batch(xs, i, t_c, z.sum(axis=0) if z.size else 0.0)
        if state.r_delta_ohm:
            v = v - i * state.r_delta_ohm
        out.append(v + state.bias_v)
        t_prev = t
    return np.array(out)


# -- load forecast ------------------------------------------------------------------------------
@dataclass(frozen=True)
class LoadForecast:
    """The load power the time to empty assumes (W, discharge positive).

    Attributes:
        power_w: the mean power (NaN when nothing was seen yet).
        block_std_w: std of the complete blocks' mean powers (NaN with fewer than two).
        blocks: complete blocks behind the mean.
        block_s: the blocks' length (s).
        source: ``"window"`` (the recent mean), ``"mission"`` (set by the robot) or ``"none"``.
    """

    power_w: float
    block_std_w: float = math.nan
    blocks: int = 0
    block_s: float = math.nan
    source: str = "window"

    def power_std_w(self, horizon_s: float) -> float:
        """sigma_P for a prediction ``horizon_s`` ahead (module docstring)."""
        if self.source == "mission":
            return MISSION_POWER_REL_STD * abs(self.power_w)
        if self.blocks < 2 or not math.isfinite(self.block_std_w):
            return EARLY_POWER_REL_STD * abs(self.power_w)
        h = max(horizon_s, self.block_s) if math.isfinite(horizon_s) else math.inf
        return self.block_std_w * math.sqrt(1.0 / self.blocks + self.block_s / h)


class PowerWindow:
    """The recent mean power over ``n_blocks`` blocks of ``window_s / n_blocks`` seconds of
    sample time, and the spread of the blocks' means (module docstring)."""

    def __init__(self, window_s: float, n_blocks: int = 5) -> None:
        if not window_s > 0.0 or n_blocks < 2:
            raise ValueError(f"window_s must be > 0 and n_blocks >= 2, got {window_s}, {n_blocks}")
        self.window_s = window_s
        self.n_blocks = n_blocks
        self.block_s = window_s / n_blocks
        self._blocks: deque[tuple[float, float]] = deque(maxlen=n_blocks)  # (J, s)
        self._energy_j = 0.0
        self._time_s = 0.0
        self._last: tuple[float, float] | None = None

    def add(self, t_s: float, power_w: float) -> None:
        """A sample's power (W) at ``t_s``; the previous sample's is held until it."""
        if self._last is not None:
            t_prev, p_prev = self._last
            dt = t_s - t_prev
            if 0.0 < dt <= MAX_HOLD_S:
                self._energy_j += p_prev * dt
                self._time_s += dt
                if self._time_s >= self.block_s:
                    self._blocks.append((self._energy_j, self._time_s))
                    self._energy_j = self._time_s = 0.0
        self._last = (t_s, power_w)

    def forecast(self) -> LoadForecast:
        """The mean over the complete blocks and the current one, with the blocks' spread."""
        energy = self._energy_j + sum(e for e, _ in self._blocks)
        time_s = self._time_s + sum(t for _, t in self._blocks)
        if time_s <= 0.0:
            p = self._last[1] if self._last is not None else math.nan
            return LoadForecast(p, math.nan, 0, self.block_s, "window" if self._last else "none")
        means = [e / t for e, t in self._blocks]
        std = float(np.std(means, ddof=1)) if len(means) >= 2 else math.nan
        return LoadForecast(energy / time_s, std, len(means), self.block_s, "window")


# -- time to empty ------------------------------------------------------------------------------
def discharge_current_a(
    model: TheveninModel,
    soc: np.ndarray,
    power_w: float,
    temperature_c: float | None = None,
) -> np.ndarray:
    """The current (A) that draws ``power_w`` at each SoC: ``P = I V_ss(s, I)`` by fixed-point
    iteration from ``P / OCV``; NaN where it does not converge (the pack cannot deliver that
    power there)."""
    soc = np.asarray(soc, dtype=float)
    i = power_w / np.maximum(model.ocv.ocv_array(soc), 1e-3)
    for _ in range(60):
        v = steady_voltage_v(model, soc, i, temperature_c)
        i_new = np.where(v > 0.0, power_w / np.maximum(v, 1e-9), np.nan)
        done = np.all(np.abs(i_new - i) <= 1e-7 * np.abs(i) + 1e-12)
        i = i_new
        if done or not np.all(np.isfinite(i)):
            break
    v = steady_voltage_v(model, soc, np.nan_to_num(i), temperature_c)
    ok = np.isfinite(i) & (np.abs(i * v - power_w) <= 1e-5 * abs(power_w) + 1e-9)
    return np.where(ok, i, np.nan)


@dataclass(frozen=True)
class TimeToEmpty:
    """A time-to-empty prediction.

    Attributes:
        time_s: time until the SoC reaches ``soc_empty`` (s; ``inf`` without a discharge load).
        std_s: its std (s), from ``soc_part_s`` and ``load_part_s`` in quadrature.
        soc_part_s: the SoC's std through ``dT/dsoc``.
        load_part_s: the load's std through ``dT/dP``.
        current_now_a, current_end_a: the current the load draws now and at ``soc_empty``.
        note: why the prediction is special ("" when it is not).
    """

    time_s: float
    std_s: float
    soc_part_s: float = math.nan
    load_part_s: float = math.nan
    current_now_a: float = math.nan
    current_end_a: float = math.nan
    note: str = ""


def time_to_empty(
    model: TheveninModel,
    state: PackState,
    soc_empty: float,
    forecast: LoadForecast,
    min_power_w: float = 0.0,
) -> TimeToEmpty:
    """Time (s) until the SoC reaches ``soc_empty`` under ``forecast``'s power (module
    docstring), with its std. ``inf`` when the power is at or below ``min_power_w`` (no
    discharge load); 0 at or below ``soc_empty`` (std: the SoC's part)."""
    power = forecast.power_w
    t_c = state.temperature_c
    q_as = SECONDS_PER_HOUR * model.capacity_ah
    if not math.isfinite(power) or power <= min_power_w:
        return TimeToEmpty(math.inf, math.inf, note="no discharge load")
    if state.soc <= soc_empty:
        i_now = float(discharge_current_a(model, np.array([state.soc]), power, t_c)[0])
        part = q_as * state.soc_std / i_now if math.isfinite(i_now) else math.nan
        return TimeToEmpty(0.0, part, part, 0.0, i_now, i_now, note="at or below soc_empty")
    span = state.soc - soc_empty
    n = min(max(math.ceil(span / _TTE_DSOC), _TTE_POINTS[0]), _TTE_POINTS[1])
    edges = np.linspace(state.soc, soc_empty, n + 1)
    mids = 0.5 * (edges[:-1] + edges[1:])
    ds = span / n
    grid = np.concatenate([[state.soc], mids, [soc_empty]])
    i_all = discharge_current_a(model, grid, power, t_c)
    i_now, i_mid, i_end = float(i_all[0]), i_all[1:-1], float(i_all[-1])
    note = ""
    bad = ~np.isfinite(i_mid)
    if bad.any():  # the pack cannot deliver the power below this SoC: empty there
        first = int(np.argmax(bad))
        note = f"the load's power is not deliverable below SoC {edges[first]:.3f}"
        i_mid = i_mid[:first]
        i_end = float(i_mid[-1]) if first else math.nan
    if not i_mid.size:
        return TimeToEmpty(0.0, math.nan, note=note)
    time_s = float(np.sum(q_as * ds / i_mid))
    # dT/dP: dI/dP = 1 / (V + I dV/dI), dV/dI from a central difference.
    soc_mid = mids[: i_mid.size]
    h = 1e-4 * np.maximum(i_mid, 1e-3)
    dv_di = (
        steady_voltage_v(model, soc_mid, i_mid + h, t_c)
        - steady_voltage_v(model, soc_mid, i_mid - h, t_c)
    ) / (2.0 * h)
    v_mid = power / i_mid
    di_dp = 1.0 / (v_mid + i_mid * dv_di)
    dt_dp = -float(np.sum(q_as * ds / i_mid**2 * di_dp))
    soc_part = q_as * state.soc_std / i_now if math.isfinite(i_now) else math.nan
    load_part = abs(dt_dp) * forecast.power_std_w(time_s)
    std = math.hypot(soc_part, load_part)
    return TimeToEmpty(time_s, std, soc_part, load_part, i_now, i_end, note)


# -- state of power -----------------------------------------------------------------------------
def prediction_std_v(model: TheveninModel, state: PackState, current_a: np.ndarray) -> np.ndarray:
    """``sigma_V(I)`` of the module docstring: the std of the voltage predicted at each current
    of ``current_a`` (A, either sign) from ``state``'s uncertainty."""
    i = np.asarray(current_a, dtype=float)
    fixed = (model.ocv.slope(state.soc) * state.soc_std) ** 2 + state.bias_std_v**2
    fixed += sum(s * s for s in state.branch_std_v)
    return np.sqrt(fixed + (i * state.r_delta_std_ohm) ** 2)


@dataclass(frozen=True)
class StateOfPower:
    """The largest currents (A, magnitudes) the pack can take for each horizon within the
    voltage limits and the file's current limits."""

    max_discharge_current_10s_a: float
    max_discharge_current_60s_a: float
    max_charge_current_10s_a: float
    max_charge_current_60s_a: float


@dataclass(frozen=True)
class _Case:
    horizon_s: float
    voltage_limit_v: float
    current_cap_a: float
    charge: bool


def _max_currents(model: TheveninModel, state: PackState, cases: list[_Case]) -> list[float]:
    """:func:`max_current_a` for several cases at once: every case's grid in one model run
    (one :func:`terminal_path_v` per pass, the checks at every horizon's times)."""
    times = sorted({0.0, *(c.horizon_s for c in cases), *(0.5 * c.horizon_s for c in cases)})

    def worst(which: list[int], grids: list[np.ndarray]) -> list[np.ndarray]:
        """The worst voltage over each case's horizon, for cases ``which`` on their grids, less
        (charge: plus) its margin, ``SOP_CONFIDENCE_K`` times :func:`prediction_std_v`."""
        sel = [cases[n] for n in which]
        signed = np.concatenate([(-g if c.charge else g) for c, g in zip(sel, grids, strict=True)])
        vs = terminal_path_v(model, state, signed, tuple(times))
        out, k = [], 0
        for c, g in zip(sel, grids, strict=True):
            rows = vs[[j for j, t in enumerate(times) if t <= c.horizon_s], k : k + g.size]
            margin = SOP_CONFIDENCE_K * prediction_std_v(model, state, g)
            out.append(rows.max(axis=0) + margin if c.charge else rows.min(axis=0) - margin)
            k += g.size
        return out

    def ok(c: _Case, v: np.ndarray) -> np.ndarray:
        return v <= c.voltage_limit_v if c.charge else v >= c.voltage_limit_v

    grids = [np.linspace(0.0, c.current_cap_a, _SOP_GRID) for c in cases]
    results: list[float | None] = [None] * len(cases)
    refine: list[int] = []
    coarse = worst(list(range(len(cases))), grids)
    for n, (c, g, v) in enumerate(zip(cases, grids, coarse, strict=True)):
        good = ok(c, v)
        if good.all():
            results[n] = float(c.current_cap_a)
        elif not good[0]:
            results[n] = 0.0
        else:
            k = int(np.argmin(good))
            grids[n] = np.linspace(g[k - 1], g[k], _SOP_GRID)
            refine.append(n)
    if refine:
        fine = worst(refine, [grids[n] for n in refine])
        for n, v in zip(refine, fine, strict=True):
            c, g = cases[n], grids[n]
            good = ok(c, v)
            k = max(int(np.argmin(good)), 1) if not good.all() else g.size - 1
            lo, hi, v_lo, v_hi = g[k - 1], g[k], v[k - 1], v[k]
            frac = 0.0 if v_hi == v_lo else (v_lo - c.voltage_limit_v) / (v_lo - v_hi)
            results[n] = float(lo + (hi - lo) * min(max(frac, 0.0), 1.0))
    return [float(r) for r in results if r is not None]


def max_current_a(
    model: TheveninModel,
    state: PackState,
    horizon_s: float,
    voltage_limit_v: float,
    current_cap_a: float,
    charge: bool = False,
) -> float:
    """The largest constant current magnitude (A, at most ``current_cap_a``) whose terminal
    voltage over the next ``horizon_s`` stays at or above ``voltage_limit_v`` (discharge) or
    at or below it (``charge``) by ``SOP_CONFIDENCE_K`` times its std (:func:`prediction_std_v`;
    0 for a ``state`` without uncertainty), from ``state`` (module docstring): a grid over
    [0, ``current_cap_a``], refined once in the bracket where the limit is crossed, and
    interpolated there. 0 when even no current meets the limit."""
    return _max_currents(model, state, [_Case(horizon_s, voltage_limit_v, current_cap_a, charge)])[
        0
    ]


def state_of_power(model: TheveninModel, limits: Limits, state: PackState) -> StateOfPower:
    """:func:`max_current_a` for 10 s and 60 s, discharge against ``limits.voltage_min_v``
    and charge against ``limits.voltage_max_v`` (all four in one model run per pass), each
    capped at the file's current limit and at the model's current envelope
    (:attr:`TheveninModel.fitted_current_max_a`, module docstring)."""
    envelope_a = model.fitted_current_max_a
    discharge_cap_a = min(limits.current_max_discharge_a, envelope_a)
    charge_cap_a = min(limits.current_max_charge_a, envelope_a)
    cases = [_Case(h, limits.voltage_min_v, discharge_cap_a, False) for h in SOP_HORIZONS_S] + [
        _Case(h, limits.voltage_max_v, charge_cap_a, True) for h in SOP_HORIZONS_S
    ]
    d10, d60, c10, c60 = _max_currents(model, state, cases)
    return StateOfPower(d10, d60, c10, c60)


# -- time to full -------------------------------------------------------------------------------
def cv_taper_s(
    model: TheveninModel,
    soc: float,
    current_a: float,
    taper_current_a: float,
    temperature_c: float | None = None,
    steps: int = 20,
) -> float:
    """Seconds for a CV charge at ``soc`` drawing ``current_a`` (A, magnitude) to taper to
    ``taper_current_a``: ``dt = tau(s, I) dI / I`` over a log grid of currents, the SoC
    advancing by each segment's charge (module docstring)."""
    if current_a <= taper_current_a:
        return 0.0
    q_as = SECONDS_PER_HOUR * model.capacity_ah
    eta = model.coulomb_efficiency_charge
    currents = np.geomspace(current_a, taper_current_a, steps + 1)
    total = 0.0
    s = soc
    for i_hi, i_lo in zip(currents[:-1], currents[1:], strict=True):
        i_mid = math.sqrt(i_hi * i_lo)
        h = 1e-3 * i_mid
        v = steady_voltage_v(
            model, np.array([s, s]), np.array([-(i_mid + h), -(i_mid - h)]), temperature_c
        )
        r_d = max(float(v[0] - v[1]) / (2.0 * h), 1e-6)
        slope = max(model.ocv.slope(s), 1e-6)
        tau = q_as * r_d / (eta * slope)
        total += tau * math.log(i_hi / i_lo)
        s = min(s + eta * (i_hi - i_lo) * tau / q_as, 1.0)
    return total


def cv_onset_soc(
    model: TheveninModel,
    soc: float,
    charge_current_a: float,
    charge_voltage_v: float,
    temperature_c: float | None = None,
) -> float:
    """The SoC at which ``V_ss`` under ``charge_current_a`` (A, magnitude) reaches
    ``charge_voltage_v``, from ``soc`` up; 1.0 when the model stays below it up to a full pack;
    ``soc`` when it is there already."""
    if soc >= 1.0:
        return soc
    grid = np.linspace(soc, 1.0, 41)
    v = steady_voltage_v(model, grid, np.full_like(grid, -charge_current_a), temperature_c)
    above = v >= charge_voltage_v
    if above[0]:
        return soc
    if not above.any():
        return 1.0
    k = int(np.argmax(above))
    frac = (charge_voltage_v - v[k - 1]) / (v[k] - v[k - 1])
    return float(grid[k - 1] + (grid[k] - grid[k - 1]) * frac)


def time_to_full(
    model: TheveninModel,
    state: PackState,
    charge_current_a: float,
    charge_voltage_v: float,
    taper_current_a: float,
    in_cv: bool,
    hold_left_s: float = 0.0,
) -> float:
    """Seconds until a CC-CV charge drawing ``charge_current_a`` (A, magnitude) now ends: the
    CC phase to ``cv_onset_soc`` (unless ``in_cv``), the CV taper to ``taper_current_a``, and
    ``hold_left_s`` (module docstring)."""
    if not charge_current_a > 0.0:
        return math.nan
    t_c = state.temperature_c
    soc = state.soc
    t_cc = 0.0
    if not in_cv:
        s_cv = cv_onset_soc(model, soc, charge_current_a, charge_voltage_v, t_c)
        eta = model.coulomb_efficiency_charge
        q_as = SECONDS_PER_HOUR * model.capacity_ah
        t_cc = max(s_cv - soc, 0.0) * q_as / (eta * charge_current_a)
        soc = s_cv
    t_cv = cv_taper_s(model, soc, charge_current_a, taper_current_a, t_c)
    return t_cc + t_cv + max(hold_left_s, 0.0)
