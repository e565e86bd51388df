"""The OCV's charge/discharge hysteresis from a test that rests after both directions.

``soc_identify --hysteresis-test`` (``models/hysteresis.py`` has the model): a test that starts
full and rests (30 minutes or more) after discharges and after charges, at SoCs the other
direction also visits: for instance 10 % discharge pulses down to 30 %, small charge pulses
(a few % each, tracing the move from one branch to the other), 10 % charge pulses back up,
and small discharge pulses again (``tools/make_bags.py --hysteresis``: ``lfp_hysteresis_test``).

The identified model (its OCV and branches fitted on discharge pulses: the discharge branch)
is run open loop along the test with the SoC counted from full; what it misses at the end of
each long rest is the hysteresis' offset plus the model's own error::

    r_k = v_k - v_model_k = c + gap_v b_k(gamma) + e_k

``c`` is what the model's OCV misses on both branches alike (its own error at those SoCs, or
a template's OCV that is not this pack's discharge branch: on the PyBaMM pack the bundled LFP
file, identified on the same cell without hysteresis, reads the middle of the branches, and
``c`` comes out near minus half the gap). It is fitted so that the gap is read from the
difference between the branches alone, and reported, not applied: the file's OCV is what its
own discharge tests gave.

``b`` follows Plett's state along the measured current from ``b = 1`` at the full start (a
pack charged to full sits on the charge branch; the first 10 % discharge takes it within
``exp(-0.1 gamma)`` of the discharge branch whatever it was). For each ``gamma`` of a
logarithmic grid ``c`` and ``gap_v`` are the least squares of the rests' residuals on
``[1, b]``; the grid point of least squared error wins. The hysteresis is kept only where
the test holds what identifies it: rests after at least two charges and two discharges, and a
gap at least three of its standard errors (else the file has none and the report says why).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..models.hysteresis import Hysteresis, HysteresisState
from ..params import BatteryParams
from ..series import BatterySeries
from .fit import charge_removed_ah
from .identify import offset_corrected, simulate_open_loop
from .segment import load_threshold_a, long_rests

#: A rest long enough to read the branch at its end (s): the pulse tests' rests are 1 h.
MIN_REST_S = 1800.0
#: Rests after each direction needed to identify the gap (and the rate between them).
MIN_RESTS_EACH = 2
#: The rate grid (per unit SoC): a branch change within 0.5 % (1000) to 100 % (1) of SoC.
RATE_GRID = np.geomspace(1.0, 1000.0, 61)
#: A gap below this many of its standard errors is not told from the model's error.
MIN_GAP_SE = 3.0


@dataclass(frozen=True)
class HysteresisFit:
    """What the test gave: the hysteresis (None: not identified, ``why`` says why) and the
    rests' residuals behind it."""

    hysteresis: Hysteresis | None
    why: str
    rests_after_charge: int
    rests_after_discharge: int
    rms_before_v: float = math.nan  # at the rests' ends, without the hysteresis
    rms_after_v: float = math.nan  # with it (and c)
    gap_se_v: float = math.nan
    offset_v: float = math.nan  # c: the model's OCV against both branches alike


def branch_along(
    hysteresis: Hysteresis, series: BatterySeries, capacity_ah: float, eta_charge: float
) -> np.ndarray:
    """``b`` at every sample from 1 at the first (``Hysteresis.step``, sample by sample), the
    current held between samples as :func:`~.identify.simulate_open_loop` counts the SoC."""
    state = HysteresisState(1.0, 0.0)
    out = np.empty(series.t_s.size)
    out[0] = 1.0
    amps, times = series.current_a.tolist(), series.t_s.tolist()
    for k in range(1, len(times)):
        state = hysteresis.step(
            state, amps[k - 1], times[k] - times[k - 1], capacity_ah, eta_charge
        )
        out[k] = state.branch
    return out


def rest_ends(series: BatterySeries) -> tuple[list[int], list[int]]:
    """The last samples of the long rests after a charge and after a discharge: the
    direction of the net charge since the previous long rest (:func:`~.fit.charge_removed_ah`)."""
    t, i = series.t_s, series.current_a
    removed_ah = charge_removed_ah(series)
    quiet = np.abs(i) <= load_threshold_a(i)
    after_charge: list[int] = []
    after_discharge: list[int] = []
    prev_end = 0
    for first, last, _ in long_rests(t, quiet, MIN_REST_S):
        net_ah = float(removed_ah[first] - removed_ah[prev_end])
        if first > prev_end and net_ah != 0.0:
            (after_charge if net_ah < 0.0 else after_discharge).append(last)
        prev_end = last
    return after_charge, after_discharge


def fit_hysteresis(battery: BatteryParams, test: BatterySeries, notes: list[str]) -> HysteresisFit:
    """Identify ``battery``'s hysteresis on ``test`` (module docstring); ``battery`` is the
    identified model (its own hysteresis, if any, is not used)."""
    test = offset_corrected(test, notes, "hysteresis test")
    after_charge, after_discharge = rest_ends(test)
    n_c, n_d = len(after_charge), len(after_discharge)
    if n_c < MIN_RESTS_EACH or n_d < MIN_RESTS_EACH:
        return HysteresisFit(
            None,
            f"{n_c} long rests after a charge and {n_d} after a discharge: at least "
            f"{MIN_RESTS_EACH} of each are needed",
            n_c,
            n_d,
        )
    q, eta = battery.capacity_ah, battery.coulomb_efficiency_charge
    v_model, _ = simulate_open_loop(battery, test, 1.0)  # the SoC counted from full
    ends = np.array(sorted(after_charge + after_discharge))
    r = test.voltage_v[ends] - v_model[ends]
    best: tuple[float, float, float, float, np.ndarray] | None = None  # sse, c, gap, rate, X
    for rate in RATE_GRID:
        b = branch_along(Hysteresis(1.0, float(rate)), test, q, eta)[ends]
        design = np.column_stack([np.ones_like(b), b])
        (c, gap), *_ = np.linalg.lstsq(design, r, rcond=None)
        sse = float(np.sum((r - c - gap * b) ** 2))
        if best is None or sse < best[0]:
            best = (sse, float(c), float(gap), float(rate), design)
    assert best is not None
    sse, c, gap, rate, design = best
    dof = max(len(ends) - 3, 1)  # c, the gap and the rate
    se = math.sqrt(sse / dof * float(np.linalg.inv(design.T @ design)[1, 1]))
    rms_before = float(np.sqrt(np.mean(r**2)))
    rms_after = math.sqrt(sse / len(ends))
    if not gap > MIN_GAP_SE * se:
        return HysteresisFit(
            None,
            f"gap {1000 * gap:.1f} mV within {MIN_GAP_SE:g} standard errors "
            f"({1000 * se:.1f} mV) of none",
            n_c,
            n_d,
            rms_before,
            rms_after,
            se,
            c,
        )
    return HysteresisFit(
        Hysteresis(gap_v=gap, rate_per_soc=rate), "", n_c, n_d, rms_before, rms_after, se, c
    )
