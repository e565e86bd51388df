"""The identified model's own voltage error: the size of the hybrid filter's bias state.

The hybrid (``estimators/hybrid.py``, item 5) carries the model's voltage error as a
Gauss-Markov state whose stationary std, ``bias_std_v``, is the size of that error where the
bias applies: from a load until the rest the filter trusts (``rest_min_s`` of the current
low-passed over ``rest_filter_tau_s`` at or below ``rest_current_a``). That size belongs to the
model, so it is measured where the model is made: on the identification tests, with the model
just identified, and written to ``filters.hybrid.bias_std_v``.

For each test the model runs open loop with the test's counted SoC imposed at every sample
(``identify.simulate_open_loop`` with ``gap_s`` 0: the SoC is the filter's other state; what is
left is the error of the voltage given the SoC) and the residual, measured minus model, is
taken on the 1-s grid of the surface-lag fit (``surface.LagWindow``: every second weighs alike
whatever the logging rate), over the seconds the bias applies at SoC >= ``limits.soc_min``
(below it the tables are held). ``bias_std_v`` is its RMS, not centred: a mean error is one the
bias must carry as much as a swing.

Only the tests at the reference temperature (the one nearest 25 degC) count. A cold cell's
error is larger but not a bias: the NCR18650PF's 2RC misses its 0.6 degC HPPC by 29.5 mV RMS
(its 25.8 degC one by 7.3 mV), an error that changes sign within 5 minutes of each pulse
(autocovariance negative from 300 s on); a bias state that size at 0 degC (per temperature,
with its fitted 2-min correlation time) let the hybrid take 20-75 minutes instead of 4 to come
within 2 % from a wrong start on the 0 degC drive cycles (docs/identification.md).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace

import numpy as np
from scipy.signal import lfilter

from ..params import BatteryParams
from ..series import BatterySeries
from .segment import IdentificationError
from .surface import GRID_S, LagWindow

#: Fewer seconds in use than this (summed over the tests) and the size is not measured.
MIN_SECONDS = 600


@dataclass(frozen=True)
class ModelError:
    """The model's voltage error over the seconds the hybrid's bias applies (V RMS)."""

    rms_v: float
    seconds: int


def residual_on_grid(
    battery: BatteryParams,
    test: BatterySeries,
    soc: np.ndarray,
    v_model: np.ndarray,
    tuning: Mapping[str, float],
) -> tuple[np.ndarray, np.ndarray]:
    """The residual (V, measured minus model) on the 1-s grid and the mask of seconds in use.

    ``soc``: the test's counted SoC at each sample; ``v_model``: the model's voltage with that
    SoC imposed (module docstring); ``tuning``: the hybrid's (``rest_min_s``,
    ``rest_current_a``, ``rest_filter_tau_s``).
    """
    if test.t_s.size < 2:
        raise IdentificationError("a test for the model error needs two samples or more")
    grid = LagWindow.on_grid(test.window(0), v_model, soc)  # on_grid takes time from 0
    # The hybrid's rest test: the current low-passed (exactly, per 1-s step), then held light.
    a = math.exp(-GRID_S / float(tuning["rest_filter_tau_s"]))
    current_lp_a = lfilter([1.0 - a], [1.0, -a], grid.current_a)
    t_s = np.arange(grid.soc.size) * GRID_S
    loaded = np.abs(current_lp_a) > float(tuning["rest_current_a"])
    last_load_s = np.maximum.accumulate(np.where(loaded, t_s, -np.inf))
    in_use = (t_s - last_load_s <= float(tuning["rest_min_s"])) & (
        grid.soc >= battery.limits.soc_min
    )
    return grid.measured_v - grid.v0, in_use


def pooled_rms(residuals: Sequence[tuple[np.ndarray, np.ndarray]]) -> ModelError:
    """The RMS of :func:`residual_on_grid`'s residuals over their masks, pooled."""
    seconds = int(sum(np.count_nonzero(m) for _, m in residuals))
    if seconds < MIN_SECONDS:
        raise IdentificationError(
            f"model error: {seconds} s of the tests from a load to its rest, fewer than "
            f"{MIN_SECONDS}"
        )
    square = sum(float(np.sum(r[m] ** 2)) for r, m in residuals)
    return ModelError(rms_v=math.sqrt(square / seconds), seconds=seconds)


def with_bias_std(battery: BatteryParams, error: ModelError | None) -> BatteryParams:
    """``battery`` with ``filters.hybrid.bias_std_v`` set to ``error``'s RMS; without the
    entry (the hybrid's code default) when ``error`` is None."""
    filters = {name: dict(block) for name, block in battery.filters.items()}
    if error is not None:
        filters.setdefault("hybrid", {})["bias_std_v"] = error.rms_v
    elif "hybrid" in filters:
        filters["hybrid"].pop("bias_std_v", None)
    return replace(battery, filters=filters)
