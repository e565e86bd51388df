"""The surface-SoC lag (``models/thevenin.py``, :class:`SurfaceLag`) from a pulse that crosses a
bend of the OCV.

Where the OCV is straight the lag is invisible (OCV(SoC - z) differs from OCV(SoC) by a slope
times z, which the branches absorb); where a pulse crosses a bend (LFP leaving full: the OCV
falls 600 mV over the first 3 % of SoC) the voltage leaves the knee within minutes while the
mean SoC is still in it, and that is what g and tau are fitted to. The rest of the model is
fixed first (``fit_pulse`` with ``anchor_end`` fits such a pulse on its end, away from the bend),
so the lag only explains the onset and the early recovery.

The fit: the model's voltage over the window (the rest before the pulse to the end of the rest
after it), simulated once without the lag from a pack at rest at the window's SoC
(``identify.simulate_open_loop``), is given with its SoC; the lag changes only the OCV term,
``v(g, tau) = v_0 - OCV(SoC) + OCV(SoC - z(g, tau))``, so each evaluation is one pass of the
lag's recursion. A coarse grid over (g, tau) then scipy's ``least_squares`` on (ln g, ln tau),
bounded.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from ..bag_io import BatterySeries
from ..models.ocv import OcvCurve
from ..models.thevenin import SurfaceLag

GAIN_BOUNDS_SOC_PER_A = (1.0e-5, 0.1)
TAU_BOUNDS_S = (1.0, 3600.0)


@dataclass(frozen=True)
class SurfaceLagFit:
    """The fitted lag and the window's voltage RMSE (V) without and with it."""

    lag: SurfaceLag
    rmse_without_v: float
    rmse_with_v: float


def lag_path(current_a: np.ndarray, dt_s: np.ndarray, gain: float, tau_s: float) -> np.ndarray:
    """``z`` at every sample (0 at the first): the recursion of :meth:`SurfaceLag.step` with
    sample k's current held until sample k + 1."""
    a = np.exp(-dt_s / tau_s)
    drive = (1.0 - a) * gain * current_a[:-1]
    z = np.zeros(current_a.size)
    zk = 0.0
    for k in range(a.size):
        zk = a[k] * zk + drive[k]
        z[k + 1] = zk
    return z


def fit_surface_lag(
    ocv: OcvCurve, window: BatterySeries, v0: np.ndarray, soc: np.ndarray
) -> SurfaceLagFit:
    """Fit g and tau on ``window`` (a pulse and the rests around it), given the model's voltage
    ``v0`` and SoC ``soc`` over it without the lag (module docstring)."""
    current = window.current_a
    measured = window.voltage_v
    dt = np.diff(window.t_s)
    base = v0 - ocv.ocv_array(soc)

    def residual(p: np.ndarray) -> np.ndarray:
        z = lag_path(current, dt, math.exp(p[0]), math.exp(p[1]))
        return base + ocv.ocv_array(soc - z) - measured

    grid = [
        (math.log(g), math.log(tau))
        for g in np.geomspace(1.0e-4, 3.0e-2, 8)
        for tau in (10.0, 30.0, 100.0, 300.0, 1000.0)
    ]
    start = min(grid, key=lambda p: float(np.sum(residual(np.array(p)) ** 2)))
    lower = [math.log(GAIN_BOUNDS_SOC_PER_A[0]), math.log(TAU_BOUNDS_S[0])]
    upper = [math.log(GAIN_BOUNDS_SOC_PER_A[1]), math.log(TAU_BOUNDS_S[1])]
    sol = least_squares(residual, np.array(start), bounds=(lower, upper), x_scale=1.0)
    lag = SurfaceLag(gain_soc_per_a=math.exp(sol.x[0]), tau_s=math.exp(sol.x[1]))
    without = float(np.sqrt(np.mean((v0 - measured) ** 2)))
    return SurfaceLagFit(lag, without, float(np.sqrt(np.mean(sol.fun**2))))
