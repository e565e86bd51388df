"""The current dependence of the instantaneous drop, from a rate test (not in the papers).

Seed 000 identifies R0 from one pulse current (eq. 17: the voltage step over the current step).
A pack's instantaneous drop is not linear in the current (charge-transfer kinetics): PyBaMM's
SLA pack at SoC 0.5 drops 217 mV at 1 A and 1.64 V at 30 A (55 mohm, not 217). A rate test
(steps from rest to several currents at each SoC level, like an HPPC) measures the drop per
current; each level is fitted with

    dV(I) = R I + a asinh(I / i0)                       (models/thevenin.py: R0 and eta)

by ``least_squares`` (bounded: R, a >= 0, i0 in [1e-3, 1e3] C). The drop is the voltage at
the step's first sample below the mean over the last second of rest before it: the RC
branches' voltages are continuous, so they cancel, and at 10 Hz the sample at the step stamp
is the instantaneous answer (a bridge that lags a sample would add 0.1 s of the fastest
branch: see the report's RMSE).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
from scipy.optimize import least_squares

from ..models.ocv import OcvCurve
from ..models.tables import ParamTable
from ..models.thevenin import KineticParams, TheveninModel, TheveninParams
from ..series import BatterySeries
from ..units import SECONDS_PER_HOUR
from .segment import IdentificationError

#: Shortest RC time constant when a rate test is given (its pulses' length, tools/make_bags.py).
RATE_PULSE_S = 5.0


@dataclass(frozen=True)
class RateStep:
    """One step from rest to a load: the current step (A) and the voltage drop (V) at its
    first sample; at the load's last sample ``end_s`` later, the drop ``end_drop_v`` below the
    same rest and the charge ``end_charge_ah`` the pulse had removed by then."""

    t_s: float
    soc: float
    current_a: float
    drop_v: float
    end_s: float = 0.0
    end_drop_v: float = math.nan
    end_charge_ah: float = 0.0


@dataclass(frozen=True)
class KineticFit:
    """``dV(I) = R I + a asinh(I / i0)`` at one SoC level (volts, ohms, amperes)."""

    soc: float
    r_ohm: float
    a_v: float
    i0_a: float
    rmse_v: float
    steps: tuple[RateStep, ...]
    i_sat_a: float | None = None  # the fastest branch's saturation current (fit_saturation)
    end_rmse_v: float = math.nan  # the pulses' last samples, with that saturation

    def drop_v(self, current_a: np.ndarray | float) -> np.ndarray:
        """The fitted drop at ``current_a``."""
        i = np.asarray(current_a, dtype=float)
        return self.r_ohm * i + self.a_v * np.arcsinh(i / self.i0_a)


def rate_steps(
    test: BatterySeries,
    soc: np.ndarray,
    rest_a: float,
    min_step_a: float,
    min_rest_s: float = 10.0,
) -> list[RateStep]:
    """Steps from a rest of at least ``min_rest_s`` (|I| < ``rest_a``) to |I| >= ``min_step_a``.

    ``soc`` is the SoC at every sample (the identification's charge count).
    """
    i, v, t = test.current_a, test.voltage_v, test.t_s
    resting = np.abs(i) < rest_a
    steps: list[RateStep] = []
    rest_since = t[0] if resting[0] else math.nan
    for k in range(1, t.size):
        if resting[k]:
            if not resting[k - 1]:
                rest_since = t[k]
            continue
        if resting[k - 1] and t[k - 1] - rest_since >= min_rest_s and abs(i[k]) >= min_step_a:
            if t[k] - t[k - 1] <= 1.0:  # a logging gap at the step would hide the drop
                # Before the step: the mean over its last second of rest (the rested voltage
                # moves by microvolts in a second; the noise of one sample does not average).
                j = k - 1
                while j > 0 and resting[j - 1] and t[k - 1] - t[j - 1] <= 1.0:
                    j -= 1
                i_rest, v_rest = float(np.mean(i[j:k])), float(np.mean(v[j:k]))
                # The load lasts while the current stays within 10 % of the step's.
                e = k
                while e + 1 < t.size and abs(i[e + 1] - i[k]) <= 0.1 * abs(i[k]):
                    e += 1
                charge_ah = float(np.sum(i[k:e] * np.diff(t[k : e + 1]))) / SECONDS_PER_HOUR
                steps.append(
                    RateStep(
                        float(t[k]),
                        float(soc[k]),
                        float(i[k]) - i_rest,
                        v_rest - float(v[k]),
                        float(t[e] - t[k]),
                        v_rest - float(v[e]),
                        charge_ah,
                    )
                )
        rest_since = math.nan
    return steps


def fit_level(steps: list[RateStep], capacity_ah: float) -> KineticFit:
    """Fit ``R, a, i0`` to the steps of one SoC level (needs four distinct currents)."""
    i = np.array([s.current_a for s in steps])
    dv = np.array([s.drop_v for s in steps])
    if np.unique(np.round(np.abs(i), 1)).size < 4:
        raise IdentificationError(f"{i.size} steps at {np.unique(np.round(i, 1))} A: need 4 rates")
    r_lin = float(np.sum(i * dv) / np.sum(i * i))  # the papers' constant R0, to start from

    def residual(p: np.ndarray) -> np.ndarray:
        r, a, log_i0 = p
        return r * i + a * np.arcsinh(i / math.exp(log_i0)) - dv

    lo_i0, hi_i0 = math.log(1e-3 * capacity_ah), math.log(1e3 * capacity_ah)
    best = None
    for i0 in (0.2 * capacity_ah, capacity_ah, 5.0 * capacity_ah):  # starts over the decades
        x0 = np.array([0.3 * r_lin, 0.7 * r_lin * i0, math.log(i0)])
        sol = least_squares(
            residual,
            x0,
            bounds=([0.0, 0.0, lo_i0], [np.inf, np.inf, hi_i0]),
            x_scale=[r_lin, r_lin * i0, 1.0],
        )
        if best is None or sol.cost < best.cost:
            best = sol
    assert best is not None  # the loop runs three times
    r, a, log_i0 = best.x
    rmse = float(np.sqrt(np.mean(best.fun**2)))
    soc = float(np.median([s.soc for s in steps]))
    return KineticFit(soc, float(r), float(a), float(math.exp(log_i0)), rmse, tuple(steps))


def fit_rate_test(
    test: BatterySeries,
    soc: np.ndarray,
    capacity_ah: float,
    notes: list[str],
    level_gap_s: float = 600.0,
) -> list[KineticFit]:
    """One :class:`KineticFit` per SoC level of a rate test (steps closer than
    ``level_gap_s`` belong to one level), in increasing SoC."""
    # Rest below 0.05 C (a Hall sensor's 40 mA of noise never reaches it); steps from 0.08 C,
    # so that a 0.1 C pulse counts: the light load a robot idles at (0.07 C on the seeder).
    steps = rate_steps(test, soc, rest_a=0.05 * capacity_ah, min_step_a=0.08 * capacity_ah)
    if not steps:
        raise IdentificationError("rate test: no step from a rest to a load found")
    levels: list[list[RateStep]] = [[steps[0]]]
    for s in steps[1:]:
        if s.t_s - levels[-1][-1].t_s > level_gap_s:
            levels.append([])
        levels[-1].append(s)
    fits = []
    for lv in levels:
        try:
            fits.append(fit_level(lv, capacity_ah))
        except IdentificationError as exc:
            notes.append(f"rate test: level at t = {lv[0].t_s:.0f} s skipped: {exc}")
    if not fits:
        raise IdentificationError("rate test: no SoC level with steps at four or more currents")
    notes.append(
        f"rate test: {len(steps)} steps at {len(fits)} SoC levels; drop fit RMSE "
        f"{1000 * max(f.rmse_v for f in fits):.1f} mV at worst"
    )
    return sorted(fits, key=lambda f: f.soc)


def fit_saturation(
    fit: KineticFit,
    thevenin: TheveninParams,
    ocv: OcvCurve,
    capacity_ah: float,
    temperature_c: float | None = None,
) -> KineticFit:
    """``fit`` with the fastest branch's saturation current ``s`` (models/thevenin.py).

    Each pulse of the level ends ``T`` <= 5 s after its step, the drop below the rest then::

        dV(T) = R I + a asinh(I / i0)                    (this level's kinetic fit)
              + R_1 s asinh(I / s) (1 - exp(-T / tau_1))  (the fastest branch, saturating)
              + sum_{i>1} R_i I (1 - exp(-T / tau_i))     (the slower ones, linear)
              + OCV(SoC) - OCV(SoC - q / Q)               (the charge q the pulse removed)

    with R_i, tau_i from the pulse test at the level's SoC; ``s`` (one per level) by
    ``least_squares`` on its logarithm within [0.01, 100] C (at 100 C the branch is linear
    up to 6 C within 0.1 %).
    """
    steps = [st for st in fit.steps if st.end_s >= 1.0 and math.isfinite(st.end_drop_v)]
    if not steps:
        return fit
    model = TheveninModel(ocv, thevenin, capacity_ah)
    branches = [model.branch_at(k, fit.soc, temperature_c) for k in range(model.n_rc)]
    i = np.array([st.current_a for st in steps])
    end = np.array([st.end_s for st in steps])
    fixed = np.array(
        [
            float(fit.drop_v(st.current_a))
            + sum(r * st.current_a * (1.0 - math.exp(-st.end_s / tau)) for r, tau in branches[1:])
            + ocv.ocv(st.soc)
            - ocv.ocv(st.soc - st.end_charge_ah / capacity_ah)
            for st in steps
        ]
    )
    measured = np.array([st.end_drop_v for st in steps])
    r1, tau1 = branches[0]
    grow = r1 * (1.0 - np.exp(-end / tau1))

    def residual(p: np.ndarray) -> np.ndarray:
        sat = math.exp(p[0])
        return fixed + grow * sat * np.arcsinh(i / sat) - measured

    lo, hi = math.log(0.01 * capacity_ah), math.log(100.0 * capacity_ah)
    sol = least_squares(residual, np.array([math.log(capacity_ah)]), bounds=([lo], [hi]))
    rmse = float(np.sqrt(np.mean(sol.fun**2)))
    return replace(fit, i_sat_a=float(math.exp(sol.x[0])), end_rmse_v=rmse)


def with_kinetics(
    thevenin: TheveninParams, fits_by_temperature: list[list[KineticFit]]
) -> TheveninParams:
    """``thevenin`` with R0 (the ohmic part) and the overpotential from the rate test(s).

    One list of fits per row of the tables' temperature axis, in its order. Each level's fit is
    interpolated onto the tables' SoC grid (held beyond the levels the test covered; i0 and the
    saturation current in their logarithms, as they span decades). The RC branches are kept:
    they were fitted to the pulse test with the drop its own pulses showed, which the kinetic
    fit reproduces at that current; when every level has a saturation current
    (:func:`fit_saturation`), the fastest branch gets it.
    """
    grid = np.asarray(thevenin.r0_ohm.soc)
    temps = thevenin.r0_ohm.temperature_c
    if len(fits_by_temperature) != len(temps):
        raise IdentificationError(
            f"{len(fits_by_temperature)} rate test(s) for {len(temps)} temperature(s) of the tables"
        )

    def rows(get) -> np.ndarray:
        return np.array(
            [
                np.interp(grid, [f.soc for f in fits], [get(f) for f in fits])
                for fits in fits_by_temperature
            ]
        )

    floor = 1e-6  # the schema's tables are > 0: an R or a fitted at its bound of 0
    r0 = np.maximum(rows(lambda f: f.r_ohm), floor)
    a = np.maximum(rows(lambda f: f.a_v), floor)
    i0 = np.exp(rows(lambda f: math.log(f.i0_a)))
    branches = thevenin.branches
    if all(f.i_sat_a is not None for fits in fits_by_temperature for f in fits):
        i_sat = np.exp(rows(lambda f: math.log(f.i_sat_a)))
        first = replace(branches[0], i_sat_a=ParamTable.from_arrays(grid, i_sat, temps))
        branches = (first, *branches[1:])
    return TheveninParams(
        r0_ohm=ParamTable.from_arrays(grid, r0, temps),
        branches=branches,
        kinetic=KineticParams(
            ParamTable.from_arrays(grid, a, temps), ParamTable.from_arrays(grid, i0, temps)
        ),
        surface_lag=thevenin.surface_lag,
    )
