"""Thevenin model with n RC branches (seed 000 §2.3, eqs. 11-14; n = 1 is seed 001's model).

State ``x = [SoC, V_1, ..., V_n]`` (SoC as a fraction, branch voltages in volts). With the
core's discharge-positive current I (the same sign as the paper's Thevenin model)::

    dSoC/dt = -eta(I) I / (3600 Q_ah)                 (eq. 11; the paper omits d/dt and 3600)
    dV_i/dt = -V_i / (R_i C_i) + I_i / C_i            (eqs. 12-13, with I_i = I)
    V_o = OCV(SoC) - sum_i V_i - I R_0 - eta(I)       (eq. 14; the paper calls R_0 "R_t")
    eta(I) = a asinh(I / i0)                          (optional; not in the papers)
    I_i = s_i asinh(I / s_i)                          (optional per branch; not in the papers)

eta is the charge-transfer overpotential of a symmetric Butler-Volmer reaction (a = n 2RT/F
for n cells at transfer coefficient 0.5, i0 twice the exchange current; both are fitted, per
SoC and temperature, from a rate test). Without it the model is the papers': R_0 constant in
the current. The packs' instantaneous drop is far from linear in the current (PyBaMM, 25 degC,
SoC 0.5: the SLA pack's drop per ampere falls from 217 mohm at 1 A to 55 mohm at 30 A, the
LFP pack's from 57 to 22 mohm), so an R_0 identified at 0.2 C over-predicts the drop under
the robot's 10-30 A by volts.

The fastest branch saturates the same way. Fitted to 0.2 C pulses it holds a few seconds of
the charge-transfer response (at low current the double layer charges through a large
charge-transfer resistance, so part of eta builds over seconds); under 30 A that part is
already in eta, and PyBaMM's packs 5 s into a 30 A step sit 150-250 mV (SLA) above a linear
branch. A branch with a saturation current s_i is driven by I_i = s_i asinh(I / s_i): the
linear branch below s_i, logarithmic above (identification/kinetics.py fits s_i to the rate
test's pulses). Without s_i the branch is the papers'.

Discretization, exact for a current held over the step (zero-order hold) and parameters frozen
at the start of the step, for any dt::

    a_i = exp(-dt / (R_i C_i))
    V_i <- a_i V_i + R_i (1 - a_i) I_i
    SoC <- SoC - eta(I) I dt / (3600 Q_ah)

R_0, R_i, C_i are tables over SoC with an optional temperature axis (:class:`ParamTable`), and
so is the optional OCV shift with temperature: OCV(SoC, T) = OCV(SoC) + offset(T, SoC).

Outside the temperatures the tables were identified at (beyond a margin), the tables are held
at their edge row and, when the battery file gives an activation energy, every resistance is
scaled by an Arrhenius factor (not in the papers; :class:`TemperatureExtrapolation`):
R(T) = R_edge exp(Ea / R_g (1/T - 1/T_edge)), T in kelvin, T_edge the identified range's end
widened by the margin (so the factor is 1 at the band's edge), the time constants kept (C
scaled by 1/f) and the Butler-Volmer exchange current divided by f. Without Ea the edge values
are held (the factor is 1): the simulated SLA pack's resistances do not change with
temperature (its 5 and 25 degC tables agree within 5 %), while the real NCR18650PF's R0 doubles
from 25 to 0 degC (Ea about 20 kJ/mol, its branches 25-43), so no one prior fits every pack.
Inside the band nothing changes either way.

Optionally (not in the papers) the OCV is read at the particles' surface SoC, ``SoC - z``, with
``z`` a sum of first-order lags of the current (:class:`SurfaceLag`, one per electrode's
diffusion): under load the surface empties ahead of the mean, and where the OCV bends (LFP's
knee near full, the graphite's stage bends below it) the voltage follows the surface within
seconds to minutes while the mean SoC takes tens of minutes. ``z`` is driven by the current
alone, so the filters carry it beside their state, not in it (a state without noise would make
their covariance singular).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..units import SECONDS_PER_HOUR
from .coulomb import coulomb_efficiency, coulomb_efficiency_lanes
from .ocv import UNINFORMATIVE_SOC_STD, OcvCurve
from .tables import LaneTables, ParamTable


def _zero_current(current_a: float | np.ndarray) -> bool:
    """A current of exactly 0 given as one number: the array methods skip the terms it zeroes
    (an array of currents computes them; each element's term is then 0 where its current is)."""
    return isinstance(current_a, float) and current_a == 0.0


@dataclass(frozen=True)
class RcBranch:
    """One parallel RC branch: resistance (ohm), capacitance (farad) and the optional
    saturation current (ampere, > 0; ``None`` is the papers' linear branch) tables."""

    r_ohm: ParamTable
    c_f: ParamTable
    i_sat_a: ParamTable | None = None

    def drive_a(self, soc: float, current_a: float, temperature_c: float | None = None) -> float:
        """The current ``I_i`` that charges the branch (module docstring), amperes."""
        if self.i_sat_a is None or current_a == 0.0:
            return current_a
        s = self.i_sat_a.at(soc, temperature_c)
        return s * math.asinh(current_a / s)

    def drive_array(
        self,
        soc: np.ndarray,
        current_a: float | np.ndarray,
        temperature_c: float | None = None,
    ) -> np.ndarray | float:
        """:meth:`drive_a` for an array of SoC at one current, or at each element's current
        (an array shaped as ``soc``)."""
        if self.i_sat_a is None or _zero_current(current_a):
            return current_a
        s = self.i_sat_a.at_array(soc, temperature_c)
        return s * np.arcsinh(current_a / s)


@dataclass(frozen=True)
class KineticParams:
    """The Butler-Volmer overpotential ``eta(I) = a asinh(I / i0)`` (module docstring).

    Attributes:
        a_v: the overpotential's scale, volts (its slope at I = 0 is ``a / i0`` ohms).
        i0_a: the current scale, amperes (> 0): below it eta is nearly linear, above it
            logarithmic (Tafel).
    """

    a_v: ParamTable
    i0_a: ParamTable


@dataclass(frozen=True)
class SurfaceLag:
    """The particles' surface SoC's lag behind the mean SoC (not in the papers):
    ``z = z_1 + ... + z_n``, one first-order lag per diffusion mode::

        dz_j/dt = (g_j(SoC) I - z_j) / tau_j,   OCV read at SoC - z
        z_j <- a_j z_j + (1 - a_j) g_j(SoC) I,   a_j = exp(-dt / tau_j)   (exact for I held)
        g_j(SoC) = g_j where SoC <= soc_max_j, else 0

    One mode per electrode that shapes the OCV: in a LFP/graphite cell the cathode's small
    particles (tau ~ R^2 / 30 D: 14 s for PyBaMM's Prada2013 LFP) make the knee near full,
    where the graphite sits on a flat stage and its own, slower lag (278 s) reads nothing; below
    it the graphite's stage bends take over. ``soc_max_j`` is where a mode starts to read
    (``identification/surface.py`` fits the first mode on the knee, the second below it).

    Attributes:
        gain_soc_per_a: g_j, each mode's steady surface offset per ampere of discharge (SoC / A).
        tau_s: tau_j, seconds, one per gain.
        soc_max: the SoC above which mode j is not driven (1.0: everywhere), one per gain.
    """

    gain_soc_per_a: tuple[float, ...]
    tau_s: tuple[float, ...]
    soc_max: tuple[float, ...]

    def __post_init__(self) -> None:
        n = len(self.gain_soc_per_a)
        if not n or len(self.tau_s) != n or len(self.soc_max) != n:
            raise ValueError(
                f"SurfaceLag needs one tau and one soc_max per gain (at least one mode), got "
                f"{n} gains, {len(self.tau_s)} taus, {len(self.soc_max)} soc_max"
            )

    @property
    def n_modes(self) -> int:
        return len(self.tau_s)

    def step(
        self, z_modes: tuple[float, ...], current_a: float, dt_s: float, soc: float
    ) -> tuple[float, ...]:
        """Each mode's ``z_j`` after ``dt_s`` seconds of ``current_a`` (discharge positive)
        from a pack at ``soc`` (the step's start)."""
        out = []
        modes = zip(z_modes, self.gain_soc_per_a, self.tau_s, self.soc_max, strict=True)
        for z, g, tau, soc_max in modes:
            a = math.exp(-dt_s / tau)
            drive = g * current_a if soc <= soc_max else 0.0
            out.append(a * z + (1.0 - a) * drive)
        return tuple(out)

    def step_lanes(
        self,
        z_modes: np.ndarray,
        current_a: np.ndarray,
        dt_s: float | np.ndarray,
        soc: np.ndarray,
    ) -> np.ndarray:
        """:meth:`step` for K independent lanes: ``z_modes`` of shape ``(n_modes, K)``, the
        other arguments ``(K,)`` or one ``dt_s`` for all (``np.exp`` for ``math.exp``: a few
        ulp apart; an infinite ``dt_s`` gives the modes' steady values)."""
        out = np.empty_like(z_modes)
        modes = zip(self.gain_soc_per_a, self.tau_s, self.soc_max, strict=True)
        for j, (g, tau, soc_max) in enumerate(modes):
            a = np.exp(-dt_s / tau)
            drive = np.where(soc <= soc_max, g * current_a, 0.0)
            out[j] = a * z_modes[j] + (1.0 - a) * drive
        return out


#: The gas constant, J/(mol K).
GAS_CONSTANT_J_PER_MOL_K = 8.314462618
KELVIN_AT_0_C = 273.15


@dataclass(frozen=True)
class TemperatureExtrapolation:
    """How the resistances go beyond the identified temperatures (module docstring).

    Attributes:
        activation_energy_j_per_mol: Ea of the Arrhenius law (J/mol); 0 (the default) holds
            the edge values; a battery file sets it for a pack known to follow the law (30
            kJ/mol is a Li-ion prior between the electrolyte's ohmic part, 15-25, and charge
            transfer, 40-60).
        margin_c: how far outside the identified range (degC) the tables are still trusted.
    """

    activation_energy_j_per_mol: float = 0.0
    margin_c: float = 3.0


@dataclass(frozen=True)
class TheveninParams:
    """Thevenin model parameters (pack level).

    Attributes:
        r0_ohm: series (terminal) resistance table, ohms; with ``kinetic`` the ohmic part only.
        branches: the RC branches, fastest first by convention.
        kinetic: the optional Butler-Volmer overpotential; ``None`` is the papers' model.
        surface_lag: the optional surface-SoC lag of the OCV; ``None`` is the papers' model.
        extrapolation: the resistances' law beyond the identified temperatures.
        fitted_c_rate_max: the highest C-rate (amperes per Ah of ``capacity_ah``) the model
            was fitted at and holds at: the current envelope of the identification, as the
            temperature tables' rows are its temperature envelope (``soc_identify``: the rate
            tests' top step, else the pulses' highest rate where the linear model holds,
            ``identification/tuning.py``). ``None``: not recorded (a file written before it).
            The state of power does not extrapolate beyond it (``runtime/prediction.py``).
    """

    r0_ohm: ParamTable
    branches: tuple[RcBranch, ...]
    kinetic: KineticParams | None = None
    surface_lag: SurfaceLag | None = None
    extrapolation: TemperatureExtrapolation = TemperatureExtrapolation()
    fitted_c_rate_max: float | None = None


class TheveninModel:
    """n-RC Thevenin model: transition, output and their Jacobians."""

    def __init__(
        self,
        ocv: OcvCurve,
        params: TheveninParams,
        capacity_ah: float,
        coulomb_efficiency_charge: float = 1.0,
        ocv_offset: ParamTable | None = None,
    ) -> None:
        if capacity_ah <= 0.0:
            raise ValueError(f"capacity_ah must be > 0, got {capacity_ah}")
        self.ocv = ocv
        self.params = params
        self.capacity_ah = capacity_ah
        self.coulomb_efficiency_charge = coulomb_efficiency_charge
        self.ocv_offset = ocv_offset  # volts over (temperature, SoC), or None
        self.n_rc = len(params.branches)
        self.dim_x = 1 + self.n_rc
        # The branch tables in one tuple, R_1..R_n then C_1..C_n, for step_batch.
        self._rc_tables = tuple(b.r_ohm for b in params.branches) + tuple(
            b.c_f for b in params.branches
        )
        self._saturating = any(b.i_sat_a is not None for b in params.branches)
        temps = params.r0_ohm.temperature_c
        margin = params.extrapolation.margin_c
        #: The temperatures (degC) inside which the tables are used as identified.
        self.trusted_c = (temps[0] - margin, temps[-1] + margin)
        self._factors: dict[float, float] = {}
        #: The learned factor on ``R_0`` (``health/``: ageing, another pack), on top of the
        #: tables and their temperature law; 1.0 is the file's model, bit for bit.
        self.r0_factor = 1.0
        # Without Ea the factor is always 1: the hot paths skip the call (no per-step cost).
        self._arrhenius = params.extrapolation.activation_energy_j_per_mol != 0.0

    # -- K independent lanes (batch/): per-lane current, step and temperature ---------------
    # Each method below is its scalar sibling's arithmetic on arrays whose last axis is the
    # lane (one filter of the batch engine) and whose leading axes are points of that lane
    # (sigma points); per-lane arguments have shape (K,). numpy's exp and arcsinh stand for
    # math's, and the tables are read by :class:`LaneTables`: values agree with the scalar
    # path to a few ulp, not to the bit.
    def _lanes(self) -> tuple[LaneTables, LaneTables, tuple[int, ...]]:
        lanes = getattr(self, "_lane_tables", None)
        if lanes is None:
            branches = self.params.branches
            sat = tuple(i for i, b in enumerate(branches) if b.i_sat_a is not None)
            sat_tables = [b.i_sat_a for b in branches if b.i_sat_a is not None]
            step = LaneTables([*self._rc_tables, *sat_tables])
            kin = self.params.kinetic
            out_tables = [self.params.r0_ohm]
            if kin is not None:
                out_tables += [kin.a_v, kin.i0_a]
            if self.ocv_offset is not None:
                out_tables.append(self.ocv_offset)
            lanes = (step, LaneTables(out_tables), sat)
            self._lane_tables = lanes
        return lanes

    def resistance_factor_lanes(self, temperature_c: np.ndarray) -> np.ndarray | None:
        """:meth:`resistance_factor` per lane (NaN: 1.0); None without Ea (always 1)."""
        if not self._arrhenius:
            return None
        t = np.asarray(temperature_c, dtype=float)
        lo, hi = self.trusted_c
        d = np.where(t < lo, t - lo, np.where(t > hi, t - hi, 0.0))  # NaN compares False: 0
        edge_k = t - d + KELVIN_AT_0_C
        t_k = t + KELVIN_AT_0_C
        ea = self.params.extrapolation.activation_energy_j_per_mol
        with np.errstate(invalid="ignore"):
            f = np.exp(ea / GAS_CONSTANT_J_PER_MOL_K * (1.0 / t_k - 1.0 / edge_k))
        return np.where(d == 0.0, 1.0, f)

    def soc_step_lanes(
        self, soc: np.ndarray, current_a: np.ndarray, dt_s: np.ndarray
    ) -> np.ndarray:
        """The SoC row of :meth:`step`: ``SoC - eta(I) I dt / (3600 Q)`` per lane."""
        eta = coulomb_efficiency_lanes(current_a, self.coulomb_efficiency_charge)
        return soc - eta * current_a * dt_s / (SECONDS_PER_HOUR * self.capacity_ah)

    def branch_step_lanes(
        self,
        soc: np.ndarray,
        current_a: np.ndarray,
        dt_s: np.ndarray,
        temperature_c: np.ndarray,
    ) -> tuple[np.ndarray, np.ndarray]:
        """The branch rows of :meth:`step` as ``V_i <- a_i V_i + b_i``: ``(a, b)``, each of
        shape ``(n_rc, *soc.shape)``, for a step from ``soc`` (the parameters' SoC)."""
        step_tables, _, sat = self._lanes()
        n = self.n_rc
        v = step_tables.at(soc, temperature_c)
        r, c = v[:n], v[n : 2 * n]
        a = np.exp(-dt_s / (r * c))  # tau kept outside the range: C scales by 1/f
        f = self.resistance_factor_lanes(temperature_c)
        if f is not None:
            r = r * f
        drive = np.empty_like(r)
        drive[...] = current_a  # a linear branch's drive is the current
        for k, i in enumerate(sat):
            s = v[2 * n + k]
            drive[i] = s * np.arcsinh(current_a / s)
        return a, r * (1.0 - a) * drive

    def open_voltage_lanes(
        self,
        soc: np.ndarray,
        current_a: np.ndarray,
        temperature_c: np.ndarray,
        z_soc: np.ndarray,
    ) -> np.ndarray:
        """:meth:`terminal_voltage` before its branch voltages are subtracted: the OCV at
        ``SoC - z_soc``, less ``I R_0 + eta(I)``, plus the temperature offset."""
        _, out_tables, _ = self._lanes()
        v = out_tables.at(soc, temperature_c)
        f = self.resistance_factor_lanes(temperature_c)
        drop = current_a * v[0]
        if f is not None:
            drop = drop * f
        if self.r0_factor != 1.0:
            drop = drop * self.r0_factor
        k = 1
        if self.params.kinetic is not None:
            i0 = v[2] if f is None else v[2] / f
            drop = drop + v[1] * np.arcsinh(current_a / i0)
            k = 3
        out = self.ocv.ocv_array(soc - z_soc) - drop
        if self.ocv_offset is not None:
            out = out + v[k]
        return out

    # -- the identified range ----------------------------------------------------------------
    @property
    def fitted_current_max_a(self) -> float:
        """The highest current (A, magnitude) the model was fitted at
        (``TheveninParams.fitted_c_rate_max`` times the capacity); ``inf`` when the file
        records none."""
        c_rate = self.params.fitted_c_rate_max
        return math.inf if c_rate is None else c_rate * self.capacity_ah

    def extrapolation_c(self, temperature_c: float | None) -> float:
        """How far (degC) ``temperature_c`` lies outside the trusted range: negative below,
        positive above, 0 inside (and for an unknown temperature)."""
        if temperature_c is None or temperature_c != temperature_c:
            return 0.0
        lo, hi = self.trusted_c
        if temperature_c < lo:
            return temperature_c - lo
        if temperature_c > hi:
            return temperature_c - hi
        return 0.0

    def resistance_factor(self, temperature_c: float | None) -> float:
        """The Arrhenius factor on every resistance at ``temperature_c`` (1.0 inside)."""
        d = self.extrapolation_c(temperature_c)
        if d == 0.0 or self.params.extrapolation.activation_energy_j_per_mol == 0.0:
            return 1.0
        assert temperature_c is not None
        f = self._factors.get(temperature_c)
        if f is None:
            edge_k = temperature_c - d + KELVIN_AT_0_C
            t_k = temperature_c + KELVIN_AT_0_C
            ea = self.params.extrapolation.activation_energy_j_per_mol
            f = math.exp(ea / GAS_CONSTANT_J_PER_MOL_K * (1.0 / t_k - 1.0 / edge_k))
            if len(self._factors) < 4096:
                self._factors[temperature_c] = f
        return f

    # -- parameters --------------------------------------------------------------------------
    def r0_ohm(self, soc: float, temperature_c: float | None = None) -> float:
        """``R_0`` in ohms at ``soc`` and ``temperature_c``: the table, its temperature law and
        the learned :attr:`r0_factor`."""
        r = self.params.r0_ohm.at(soc, temperature_c)
        if self._arrhenius:
            r *= self.resistance_factor(temperature_c)
        return r * self.r0_factor

    def series_drop_v(
        self, soc: float, current_a: float, temperature_c: float | None = None
    ) -> float:
        """The instantaneous drop ``I R_0 + eta(I)`` in volts (module docstring)."""
        f = self.resistance_factor(temperature_c) if self._arrhenius else 1.0
        drop = current_a * self.params.r0_ohm.at(soc, temperature_c)
        if f != 1.0:
            drop *= f
        if self.r0_factor != 1.0:
            drop *= self.r0_factor
        kin = self.params.kinetic
        if kin is not None and current_a != 0.0:
            i0 = kin.i0_a.at(soc, temperature_c)
            if f != 1.0:
                i0 /= f
            drop += kin.a_v.at(soc, temperature_c) * math.asinh(current_a / i0)
        return drop

    def series_drop_array(
        self, soc: np.ndarray, current_a: float | np.ndarray, temperature_c: float | None = None
    ) -> np.ndarray:
        """:meth:`series_drop_v` for an array of SoC at one current, or at each element's
        current (an array shaped as ``soc``)."""
        f = self.resistance_factor(temperature_c) if self._arrhenius else 1.0
        drop = current_a * self.params.r0_ohm.at_array(soc, temperature_c)
        if f != 1.0:
            drop = drop * f
        if self.r0_factor != 1.0:
            drop = drop * self.r0_factor
        kin = self.params.kinetic
        if kin is not None and not _zero_current(current_a):
            i0 = kin.i0_a.at_array(soc, temperature_c)
            if f != 1.0:
                i0 = i0 / f
            drop = drop + kin.a_v.at_array(soc, temperature_c) * np.arcsinh(current_a / i0)
        return drop

    def branch_at(
        self, i: int, soc: float, temperature_c: float | None = None
    ) -> tuple[float, float]:
        """(R_i in ohms, tau_i = R_i C_i in seconds) of branch ``i``."""
        b = self.params.branches[i]
        r = b.r_ohm.at(soc, temperature_c)
        tau = r * b.c_f.at(soc, temperature_c)  # kept outside the range: C scales by 1/f
        if self._arrhenius:
            f = self.resistance_factor(temperature_c)
            if f != 1.0:
                r = r * f
        return r, tau

    def surface_rest(self) -> tuple[float, ...]:
        """The lag's modes of a pack at rest (all 0; none without a :class:`SurfaceLag`)."""
        lag = self.params.surface_lag
        return () if lag is None else (0.0,) * lag.n_modes

    def surface_step(
        self, z_modes: tuple[float, ...], current_a: float, dt_s: float, soc: float
    ) -> tuple[float, ...]:
        """The lag's modes after the step from ``soc`` (:meth:`SurfaceLag.step`); their sum is
        the ``z_soc`` the voltage functions take."""
        lag = self.params.surface_lag
        return () if lag is None else lag.step(z_modes, current_a, dt_s, soc)

    # -- dynamics ----------------------------------------------------------------------------
    def step(
        self, x: np.ndarray, current_a: float, dt_s: float, temperature_c: float | None = None
    ) -> np.ndarray:
        """State after ``dt_s`` seconds of ``current_a`` (discharge positive)."""
        soc = float(x[0])
        out = np.empty(self.dim_x)
        eta = coulomb_efficiency(current_a, self.coulomb_efficiency_charge)
        out[0] = soc - eta * current_a * dt_s / (SECONDS_PER_HOUR * self.capacity_ah)
        for i in range(self.n_rc):
            r, tau = self.branch_at(i, soc, temperature_c)
            a = math.exp(-dt_s / tau)
            drive = self.params.branches[i].drive_a(soc, current_a, temperature_c)
            out[1 + i] = a * float(x[1 + i]) + r * (1.0 - a) * drive
        return out

    def step_batch(
        self,
        xs: np.ndarray,
        current_a: float | np.ndarray,
        dt_s: float,
        temperature_c: float | None = None,
    ) -> np.ndarray:
        """:meth:`step` applied to every row of ``xs`` (shape ``(m, dim_x)``) at once, at one
        current or at each row's (``current_a`` of shape ``(m,)``: the runtime predictions'
        candidate currents).

        All branches in one set of array operations (rows of ``(n_rc, m)`` arrays); each
        element gets the arithmetic of :meth:`step`, in the same order. The result has the
        memory layout of ``xs``.
        """
        xt = xs.T  # (dim_x, m): row 0 the SoC, rows 1.. the branch voltages
        soc = xt[0]
        out = np.empty_like(xs)
        ot = out.T
        eff = self.coulomb_efficiency_charge
        if isinstance(current_a, np.ndarray):
            eta: float | np.ndarray = coulomb_efficiency_lanes(current_a, eff)
        else:
            eta = coulomb_efficiency(current_a, eff)
        ot[0] = soc - eta * current_a * dt_s / (SECONDS_PER_HOUR * self.capacity_ah)
        if self.n_rc:
            rc = np.array([t.at_array(soc, temperature_c) for t in self._rc_tables])
            r, c = rc[: self.n_rc], rc[self.n_rc :]
            a = np.exp(-dt_s / (r * c))  # tau kept outside the range: C scales by 1/f
            if self._arrhenius:
                f = self.resistance_factor(temperature_c)
                if f != 1.0:
                    r = r * f
            if self._saturating:
                drive = np.empty_like(r)  # (n_rc, m): a linear branch's row is the current
                for i, b in enumerate(self.params.branches):
                    drive[i] = b.drive_array(soc, current_a, temperature_c)
                ot[1:] = a * xt[1:] + r * (1.0 - a) * drive
            else:
                ot[1:] = a * xt[1:] + r * (1.0 - a) * current_a
        return out

    def branch_steady_batch(
        self, soc: np.ndarray, current_a: np.ndarray, temperature_c: float | None = None
    ) -> np.ndarray:
        """Each branch's voltage after a constant current held long, ``R_i(s) I_i(s, I)``
        (:meth:`step`'s limit as ``dt`` grows), at each element's SoC and current: shape
        ``(n_rc, m)``."""
        f = self.resistance_factor(temperature_c) if self._arrhenius else 1.0
        out = np.empty((self.n_rc, soc.size))
        for k, b in enumerate(self.params.branches):
            r = b.r_ohm.at_array(soc, temperature_c)
            if f != 1.0:
                r = r * f
            out[k] = r * b.drive_array(soc, current_a, temperature_c)
        return out

    def terminal_voltage_batch(
        self,
        xs: np.ndarray,
        current_a: float | np.ndarray,
        temperature_c: float | None = None,
        z_soc: float | np.ndarray = 0.0,
    ) -> np.ndarray:
        """:meth:`terminal_voltage` for every row of ``xs``, at one current and lag or at each
        row's (``current_a``, ``z_soc`` of shape ``(m,)``)."""
        xt = xs.T
        soc = xt[0]
        shifted = isinstance(z_soc, np.ndarray) or z_soc
        ocv = self.ocv.ocv_array(soc - z_soc if shifted else soc)
        v = ocv - self.series_drop_array(soc, current_a, temperature_c)
        if self.ocv_offset is not None:
            v = v + self.ocv_offset.at_array(soc, temperature_c)
        if self.n_rc == 0:
            return v - 0.0
        # sum over the branch voltages, added left to right as ``xs[:, 1:].sum(axis=1)`` does
        v_rc = xt[1]
        for i in range(2, self.dim_x):
            v_rc = v_rc + xt[i]
        return v - v_rc

    def voltage_along(
        self,
        soc: np.ndarray,
        current_a: np.ndarray,
        dt_s: np.ndarray,
        temperature_c: np.ndarray,
    ) -> np.ndarray:
        """The terminal voltage (V) at every sample of a recording, from rest at sample 0, the
        model's SoC at each sample given (``soc``; the branches and the lag follow).

        Sample ``k`` (>= 1) is :meth:`surface_step` and :meth:`step` over ``dt_s[k]`` with
        ``current_a[k - 1]`` from ``soc[k - 1]`` at ``temperature_c[k]``, then
        :meth:`terminal_voltage` at ``soc[k]`` with ``current_a[k]``; NaN temperatures are
        ``None``. The same operations as those methods, element by element (tables by
        :meth:`ParamTable.at_each`, ``math.exp`` and ``math.asinh``): each value equals the
        per-sample loop's to the last bit, with only the two first-order recursions (branch
        voltages, lag modes) stepped sample by sample.
        """
        soc_from = np.concatenate([soc[:1], soc[:-1]])  # each step's start (sample 0: none)
        i_from = np.concatenate([current_a[:1], current_a[:-1]])
        dt = np.asarray(dt_s, dtype=float)
        temps = np.asarray(temperature_c, dtype=float)
        f = self._factor_each(temps)
        v = self.ocv.ocv_each(soc - self._lag_along(soc_from, i_from, dt))
        # series_drop_v at each sample
        drop = current_a * self.params.r0_ohm.at_each(soc, temps)
        if f is not None:
            drop = drop * f  # x 1.0 inside the range: the same value as no factor
        if self.r0_factor != 1.0:
            drop = drop * self.r0_factor
        kin = self.params.kinetic
        if kin is not None:
            i0 = kin.i0_a.at_each(soc, temps)
            if f is not None:
                i0 = i0 / f
            a_v = kin.a_v.at_each(soc, temps)
            eta = a_v * _each(math.asinh, current_a / i0)
            drop = np.where(current_a != 0.0, drop + eta, drop)
        v = v - drop
        if self.ocv_offset is not None:
            v = v + self.ocv_offset.at_each(soc, temps)
        for b in self.params.branches:
            r = b.r_ohm.at_each(soc_from, temps)
            tau = r * b.c_f.at_each(soc_from, temps)
            if f is not None:
                r = r * f
            a = _each(math.exp, -dt / tau)
            drive = i_from
            if b.i_sat_a is not None:
                sat = b.i_sat_a.at_each(soc_from, temps)
                drive = np.where(i_from != 0.0, sat * _each(math.asinh, i_from / sat), i_from)
            v = v - _first_order(a, r * (1.0 - a) * drive)
        return v

    def _factor_each(self, temperature_c: np.ndarray) -> np.ndarray | None:
        """:meth:`resistance_factor` per sample (NaN: 1.0); None without Ea (always 1)."""
        if not self._arrhenius:
            return None
        f = np.ones(temperature_c.size)
        for t in np.unique(temperature_c[~np.isnan(temperature_c)]).tolist():
            f[temperature_c == t] = self.resistance_factor(t)
        return f

    def _lag_along(self, soc_from: np.ndarray, i_from: np.ndarray, dt: np.ndarray) -> np.ndarray:
        """The lag's ``z`` (sum of the modes, as ``sum()`` adds them) at every sample
        (:meth:`SurfaceLag.step`); zeros without a lag."""
        lag = self.params.surface_lag
        z: np.ndarray = np.zeros(soc_from.size)
        if lag is None:
            return z
        for g, tau, soc_max in zip(lag.gain_soc_per_a, lag.tau_s, lag.soc_max, strict=True):
            a = _each(math.exp, -dt / tau)
            drive = np.where(soc_from <= soc_max, g * i_from, 0.0)
            z = z + _first_order(a, (1.0 - a) * drive)
        return z

    def transition_jacobian(
        self, x: np.ndarray, current_a: float, dt_s: float, temperature_c: float | None = None
    ) -> np.ndarray:
        """d step / d x, holding the parameters' SoC dependence fixed over the step."""
        soc = float(x[0])
        f = np.eye(self.dim_x)
        for i in range(self.n_rc):
            _, tau = self.branch_at(i, soc, temperature_c)
            f[1 + i, 1 + i] = math.exp(-dt_s / tau)
        return f

    def terminal_voltage(
        self,
        x: np.ndarray,
        current_a: float,
        temperature_c: float | None = None,
        z_soc: float = 0.0,
    ) -> float:
        """Terminal voltage in volts (eq. 14), the OCV read at ``SoC - z_soc`` (the surface
        lag, :meth:`surface_step`; 0 is the papers' model)."""
        soc = float(x[0])
        v = self.ocv.ocv(soc - z_soc) - self.series_drop_v(soc, current_a, temperature_c)
        if self.ocv_offset is not None:
            v += self.ocv_offset.at(soc, temperature_c)
        for i in range(self.n_rc):
            v -= float(x[1 + i])
        return v

    def output_jacobian(
        self,
        x: np.ndarray,
        current_a: float,
        temperature_c: float | None = None,
        z_soc: float = 0.0,
    ) -> np.ndarray:
        """d V_o / d x as a (1, dim_x) row: [dOCV/dSoC - d(I R0 + eta)/dSoC, -1, ..., -1]
        (the OCV's slope at ``SoC - z_soc``: z does not depend on the state)."""
        soc = float(x[0])
        h = np.full((1, self.dim_x), -1.0)
        eps = 1e-4
        d_drop = (
            self.series_drop_v(soc + eps, current_a, temperature_c)
            - self.series_drop_v(soc - eps, current_a, temperature_c)
        ) / (2.0 * eps)
        h[0, 0] = self.ocv.slope(soc - z_soc) - d_drop
        if self.ocv_offset is not None:
            off = self.ocv_offset
            h[0, 0] += (off.at(soc + eps, temperature_c) - off.at(soc - eps, temperature_c)) / (
                2.0 * eps
            )
        return h

    def pulse_resistance_ohm(
        self, soc: float = 0.5, duration_s: float = 5.0, temperature_c: float | None = None
    ) -> float:
        """The pack's resistance as a pulse test reads it: the voltage drop ``duration_s``
        into a 1 C discharge from rest at ``soc``, per ampere (the series drop, Butler-Volmer
        term included, the branches and the surface lag over the pulse; 0.1-s steps). The
        resistance a pack's spread is stated in (the corpus' +-15 %: ``tools/make_bags.py``
        measures its packs 5 s into 1 C at 50 %, 25 degC: SLA 0.139, LFP 0.0465 Ohm; this
        gives 0.140 and 0.049 for the bundled files)."""
        current_a = self.capacity_ah
        x = self.rested_state(soc)
        z = self.surface_rest()
        v_rest = self.terminal_voltage(x, 0.0, temperature_c)
        dt_s = 0.1
        for _ in range(max(1, round(duration_s / dt_s))):
            z = self.surface_step(z, current_a, dt_s, float(x[0]))
            x = self.step(x, current_a, dt_s, temperature_c)
        v = self.terminal_voltage(x, current_a, temperature_c, sum(z))
        return (v_rest - v) / current_a

    def soc_at_terminal_voltage(
        self,
        voltage_v: float,
        current_a: float,
        voltage_std_v: float,
        temperature_c: float | None = None,
    ) -> tuple[float, float]:
        """The SoC (clipped to [0, 1]) whose terminal voltage at ``current_a`` is
        ``voltage_v`` when the pack's history is unknown (a start, a reset), and its std.

        Eq. 14 with the branches unknown: the instantaneous drop ``I R_0 + eta(I)`` is there
        from the first sample, the branches lie anywhere from relaxed (a load just switched on)
        to their steady state ``R_i I_i`` (a load held for minutes), so they are taken at half
        of it, with the std of a uniform spread over that range (``sum R_i I_i / sqrt(12)``),
        added to ``voltage_std_v``. Outside the trusted temperatures (:meth:`extrapolation_c`)
        the drop is an extrapolation, not a measurement: its whole size joins the std. The
        surface lag (its steady offset a few thousandths of SoC at a robot's idle current) is
        left out. At rest this is the OCV curve (with its temperature offset) read backwards.

        The tables vary with the SoC, so the equation is solved on a grid of
        :data:`READING_GRID` SoC points, not by iterating the drop at the SoC read (which
        oscillates on LFP's plateau, where the OCV moves less than the drop's tables do): the
        root is interpolated between the grid points that bracket it; where several do, the
        SoC is the middle of the outer two and the std at least half their span. The std is
        the voltage's over the slope at the root, or, if larger, the distance to the farthest
        SoC whose voltage lies within one std of the reading; capped at
        ``UNINFORMATIVE_SOC_STD``.
        """
        grid = _READING_SOC
        v = self.ocv.ocv_array(grid)
        if self.ocv_offset is not None:
            v = v + self.ocv_offset.at_array(grid, temperature_c)
        unknown_v = np.zeros_like(grid)
        if current_a != 0.0:
            f = self.resistance_factor(temperature_c) if self._arrhenius else 1.0
            branches_v = np.zeros_like(grid)  # their steady state, sum R_i I_i
            for b in self.params.branches:
                r_ohm = f * b.r_ohm.at_array(grid, temperature_c)
                branches_v = branches_v + r_ohm * b.drive_array(grid, current_a, temperature_c)
            drop_v = self.series_drop_array(grid, current_a, temperature_c) + 0.5 * branches_v
            v = v - drop_v
            unknown_v = np.abs(branches_v) / math.sqrt(12.0)
            if self.extrapolation_c(temperature_c) != 0.0:
                unknown_v = np.hypot(unknown_v, drop_v)
        std_v = np.hypot(voltage_std_v, unknown_v)
        d = v - voltage_v
        above = d > 0.0
        if np.all(above):  # below the whole curve: empty
            return 0.0, float(min(std_v[0] / max(_slope(v, 0), 1e-12), UNINFORMATIVE_SOC_STD))
        if not np.any(above):  # above it: full
            k = len(grid) - 2
            return 1.0, float(min(std_v[-1] / max(_slope(v, k), 1e-12), UNINFORMATIVE_SOC_STD))
        cross = np.flatnonzero(above[:-1] != above[1:])
        roots = grid[cross] - d[cross] * (grid[cross + 1] - grid[cross]) / (d[cross + 1] - d[cross])
        lo, hi = float(roots[0]), float(roots[-1])
        soc = 0.5 * (lo + hi)
        k = int(cross[np.argmin(np.abs(roots - soc))])
        slope = abs(_slope(v, k))
        std = float(std_v[k]) / slope if slope > 0.0 else UNINFORMATIVE_SOC_STD
        # The SoCs the reading cannot tell from the root, within one std of the voltage: a curve
        # that bends within its own std (LFP's plateau) is read across them, not at the root's
        # slope alone (``OcvCurve.soc_at_with_interval_std``'s reason).
        near = np.flatnonzero(np.abs(d) <= std_v)
        if near.size:
            std = max(std, soc - float(grid[near[0]]), float(grid[near[-1]]) - soc)
        return soc, float(min(max(std, 0.5 * (hi - lo)), UNINFORMATIVE_SOC_STD))

    def rested_state(self, soc: float) -> np.ndarray:
        """State of a pack at rest (branch voltages relaxed to zero)."""
        x = np.zeros(self.dim_x)
        x[0] = soc
        return x


#: The SoC grid :meth:`TheveninModel.soc_at_terminal_voltage` solves on: 0.0025 apart, finer
#: than the bundled files' OCV tables (0.025) and resistance tables (about 0.1).
READING_GRID = 401
_READING_SOC = np.linspace(0.0, 1.0, READING_GRID)


def _slope(v: np.ndarray, k: int) -> float:
    """The grid's chord slope (V per unit SoC) between points ``k`` and ``k + 1``."""
    return float((v[k + 1] - v[k]) / (_READING_SOC[k + 1] - _READING_SOC[k]))


def _each(fn, x: np.ndarray) -> np.ndarray:
    """``fn`` (a ``math`` function) at every element: its rounding, not numpy's SIMD one."""
    return np.fromiter(map(fn, x.tolist()), dtype=float, count=x.size)


def _first_order(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``y[0] = 0``, ``y[k] = a[k] y[k - 1] + b[k]``: a branch's (or lag mode's) state from rest,
    in the order :meth:`TheveninModel.step` adds."""
    out = [0.0] * a.size
    y = 0.0
    for k, (ak, bk) in enumerate(zip(a.tolist(), b.tolist(), strict=True)):
        if k:
            y = ak * y + bk
            out[k] = y
    return np.array(out)


def one_rc_equivalent(params: TheveninParams) -> TheveninParams:
    """Reduce an n-RC model to the 1-RC model of seed 001's EKF, grid point by grid point.

    The single branch keeps the total polarization resistance ``R_p = sum R_i`` (same
    steady-state voltage under a constant current) and the resistance-weighted mean time
    constant ``tau_p = sum R_i tau_i / R_p`` (same area under the step response), so it
    matches the n-RC model at DC and in the charge it stores. A branch's saturation current
    (``i_sat_a``) is not carried: one branch cannot hold it for a part of its resistance, and
    seed 001's EKF is the linear 1-RC model (the reduction matches at low current).
    """
    if len(params.branches) == 1:
        return params
    first = params.branches[0].r_ohm
    r_rows, c_rows = [], []
    for temp in first.temperature_c:
        r_row, c_row = [], []
        for soc in first.soc:
            rs = [b.r_ohm.at(soc, temp) for b in params.branches]
            taus = [r * b.c_f.at(soc, temp) for r, b in zip(rs, params.branches, strict=True)]
            r_p = sum(rs)
            tau_p = sum(r * t for r, t in zip(rs, taus, strict=True)) / r_p
            r_row.append(r_p)
            c_row.append(tau_p / r_p)
        r_rows.append(r_row)
        c_rows.append(c_row)
    temps = first.temperature_c
    branch = RcBranch(
        ParamTable.from_arrays(first.soc, r_rows, temps),
        ParamTable.from_arrays(first.soc, c_rows, temps),
    )
    return TheveninParams(
        r0_ohm=params.r0_ohm,
        branches=(branch,),
        kinetic=params.kinetic,
        surface_lag=params.surface_lag,
    )
