"""The surface-SoC lag (``models/thevenin.py``, :class:`SurfaceLag`) from the pulse, rate and
load tests' windows: one diffusion mode per bend of the OCV that the data show.

Where the OCV is straight a lag is nearly invisible (OCV(SoC - z) differs from OCV(SoC) by a
slope times z, which the branches absorb); where a window crosses a bend of the OCV the voltage
follows the surface while the mean SoC lags, and that is what a mode is fitted to. The rest of
the model is fixed first (``fit_pulse`` with ``anchor_end`` fits a pulse whose onset crosses a
bend on its end), so the lag only explains what the branches, fitted pulse by pulse, cannot.

The modes are fitted in stages (``identify.with_surface_lag`` makes them): first on the pulses
whose onset crosses a bend (LFP leaving full: the OCV falls 600 mV over the first 3 % of SoC,
the cathode's knee), then on every window below that knee that crosses a bend (the graphite's
stage bends near 0.8 and 0.4 and the knee near empty), that mode driven only below the knee
(``soc_max``): with one mode for both, the slow graphite lag the windows below ask for would
read the cathode's knee too, where the graphite is flat. Each stage's mode is fitted with the
earlier ones held, and kept only if it cuts its windows' RMSE by ``MODE_GAIN`` and its gain
and time constant are inside their bounds.

Each fit: for each window (a pulse or a rate-test level and the rests around it) the model's
voltage and SoC without the lag, simulated once from a pack at rest at the window's SoC
(``identify.simulate_open_loop``), are given; the lag changes only the OCV term,
``v = v_0 - OCV(SoC) + OCV(SoC - z)``, so each evaluation is the lag's recursion and one OCV
lookup. Both run on a 1-s grid (the current averaged over each second, so the charge is kept;
the bags log at 1-10 Hz), which also weighs every second alike: the recursion is then one
``scipy.signal.lfilter`` per mode. A coarse grid over (g, tau), then scipy's
``least_squares`` on (ln g, ln tau), bounded.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import cast

import numpy as np
from scipy.optimize import least_squares
from scipy.signal import lfilter

from ..models.ocv import OcvCurve
from ..models.thevenin import SurfaceLag
from ..series import BatterySeries

GAIN_BOUNDS_SOC_PER_A = (1.0e-5, 0.1)
#: Up to a third of the 1-h rests of the seed-000 protocol (and of the rate and load tests): a
#: slower mode does not settle within a window, and its fit cannot tell it from an OCV or a
#: capacity error (the SLA pack's last pulse window asks for tau 1700 s, g 0.056 SoC/A).
TAU_BOUNDS_S = (1.0, 1200.0)
GRID_S = 1.0
#: a mode is kept when it lowers the windows' voltage RMSE by at least this fraction
MODE_GAIN = 0.10


@dataclass(frozen=True)
class LagWindow:
    """One window on the fit's 1-s grid: the current averaged over each second (A, point k
    held until k + 1), the measured voltage, and the model's voltage and SoC without the lag."""

    current_a: np.ndarray
    measured_v: np.ndarray
    v0: np.ndarray
    soc: np.ndarray

    @classmethod
    def on_grid(cls, window: BatterySeries, v0: np.ndarray, soc: np.ndarray) -> LagWindow:
        """Resample ``window`` (time from 0) and the model's ``v0``, ``soc`` over it."""
        t = window.t_s
        grid = np.arange(0.0, t[-1] + 1e-9, GRID_S)
        # Charge moved up to each grid time, with each sample's current held until the next.
        charge = np.concatenate([[0.0], np.cumsum(window.current_a[:-1] * np.diff(t))])
        mean_a = np.diff(np.interp(grid, t, charge)) / GRID_S
        return cls(
            current_a=np.append(mean_a, 0.0),
            measured_v=np.interp(grid, t, window.voltage_v),
            v0=np.interp(grid, t, v0),
            soc=np.interp(grid, t, soc),
        )


@dataclass(frozen=True)
class LagStage:
    """The windows one mode is fitted on, and the SoC above which that mode is not driven."""

    windows: Sequence[LagWindow]
    soc_max: float = 1.0


@dataclass(frozen=True)
class SurfaceLagFit:
    """The kept modes (``None``: none) and, per stage, its windows' voltage RMSE (V) without
    and with its mode (NaN for a stage without windows), and whether the mode was kept."""

    lag: SurfaceLag | None
    rmse_v: tuple[tuple[float, float], ...]
    kept: tuple[bool, ...]


def mode_path(
    current_a: np.ndarray, soc: np.ndarray, gain: float, tau_s: float, soc_max: float = 1.0
) -> np.ndarray:
    """One mode's ``z`` on the 1-s grid (0 at the first point): :meth:`SurfaceLag.step`'s
    recursion, ``z[k+1] = a z[k] + (1 - a) g I[k]``, not driven where ``soc[k] > soc_max``."""
    a = math.exp(-GRID_S / tau_s)
    drive = np.where(soc[:-1] <= soc_max, current_a[:-1], 0.0)
    z = np.zeros(current_a.size)
    z[1:] = lfilter([(1.0 - a) * gain], [1.0, -a], drive)
    return z


def fit_surface_lag(ocv: OcvCurve, stages: Sequence[LagStage]) -> SurfaceLagFit:
    """One mode per stage, fitted with the kept ones held (module docstring)."""
    kept: list[tuple[float, float, float]] = []  # (g, tau, soc_max)
    rmses: list[tuple[float, float]] = []
    flags: list[bool] = []
    lower = [math.log(GAIN_BOUNDS_SOC_PER_A[0]), math.log(TAU_BOUNDS_S[0])]
    upper = [math.log(GAIN_BOUNDS_SOC_PER_A[1]), math.log(TAU_BOUNDS_S[1])]
    for stage in stages:
        if not stage.windows:
            rmses.append((math.nan, math.nan))
            flags.append(False)
            continue
        # Per window: the model's voltage less its OCV term, and the kept modes' z (held).
        base = [w.v0 - ocv.ocv_array(w.soc) for w in stage.windows]
        z_held = [
            sum((mode_path(w.current_a, w.soc, *m) for m in kept), np.zeros(w.soc.size))
            for w in stage.windows
        ]

        def residual(p: np.ndarray, stage: LagStage = stage, base=base, z_held=z_held):
            out = []
            for w, b, z0 in zip(stage.windows, base, z_held, strict=True):
                z = z0
                if p.size:
                    z = z0 + mode_path(
                        w.current_a, w.soc, *cast("tuple[float, float]", np.exp(p)), stage.soc_max
                    )
                out.append(b + ocv.ocv_array(w.soc - z) - w.measured_v)
            return np.concatenate(out)

        without = float(np.sqrt(np.mean(residual(np.empty(0)) ** 2)))
        grid = [
            np.array([math.log(g), math.log(tau)])
            for g in np.geomspace(1.0e-4, 3.0e-2, 8)
            for tau in (3.0, 10.0, 30.0, 100.0, 300.0, 1000.0)
        ]
        start = min(grid, key=lambda p: float(np.sum(residual(p) ** 2)))
        sol = least_squares(residual, start, bounds=(lower, upper), x_scale=1.0)
        with_mode = float(np.sqrt(np.mean(sol.fun**2)))
        rmses.append((without, with_mode))
        # A mode at a bound is not one the windows resolve (TAU_BOUNDS_S).
        inside = bool(np.all((sol.x > np.array(lower) + 1e-3) & (sol.x < np.array(upper) - 1e-3)))
        flags.append(inside and with_mode <= (1.0 - MODE_GAIN) * without)
        if flags[-1]:
            g, tau = np.exp(sol.x)
            kept.append((float(g), float(tau), float(stage.soc_max)))
    if not kept:
        return SurfaceLagFit(None, tuple(rmses), tuple(flags))
    lag = SurfaceLag(
        gain_soc_per_a=tuple(m[0] for m in kept),
        tau_s=tuple(m[1] for m in kept),
        soc_max=tuple(m[2] for m in kept),
    )
    return SurfaceLagFit(lag, tuple(rmses), tuple(flags))
