"""The objective ``soc_tune`` minimizes: one tuning of one estimator on one recording.

Two runs of the estimator alone (``evaluation.run_estimator``, as the accuracy tests run it)
against the recording's reference SoC, and one of coulomb counting from the same true start
(issue 24's baseline):

* from the **true start** (std ``START_STD``): MAE and max error after the 10-minute window,
  and the share of those samples whose error lies within the reported ±2 sigma (the coverage);
* from a **wrong start** (``wrong_start`` away from the truth, towards the middle, with that
  std; 0 skips it): the time until the error is first below 2 points.

``J = MAE + max / 2 + COVERAGE_WEIGHT * d(coverage, [0.90, 0.98]) + min(t_conv / 600 s, 3)
+ HARM_WEIGHT * max(0, max - coulomb max - 1)``, in points of SoC (MAE, max in %), ``d`` the
distance of the coverage from the band (a fraction). So a point of MAE weighs as two of max, as
5 % of coverage outside the band (``0.05 * 20``), as 10 minutes of convergence (up to three
points for a filter that never converges), and as half a point by which the estimator's max
exceeds coulomb counting's by more than issue 24's one point (the do-no-harm rule, which the
tuning must not trade for accuracy). It acts only where the tuning recordings show harm: on the
SLA corpus' tuning half no candidate ``extrapolation_scale_c`` breaks the rule, and the choice
(7.9 degC) lowered the validation half's MAE and broke the rule on one more mission there
(docs/accuracy.md). The weights are a choice (stated here, printed by ``soc_tune``), not
fitted.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..estimators import make_estimator
from ..evaluation import run_estimator
from ..params import BatteryParams
from ..series import BatterySeries

WINDOW_S = 600.0
START_STD = 0.1
COVERAGE_BAND = (0.90, 0.98)
COVERAGE_WEIGHT = 20.0
CONVERGED_SOC = 0.02
CONVERGENCE_SCALE_S = 600.0
CONVERGENCE_CAP = 3.0
HARM_ALLOWANCE_PCT = 1.0  # issue 24: max at most 1 point above coulomb counting's
HARM_WEIGHT = 2.0


@dataclass(frozen=True)
class Score:
    """One tuning on one recording (percent points of SoC, a fraction, seconds)."""

    mae_pct: float
    max_pct: float
    coverage: float
    t_converge_s: float
    coulomb_max_pct: float = math.nan  # NaN: no baseline, no harm term

    @property
    def harm_pct(self) -> float:
        """Points by which the max exceeds coulomb counting's by more than the rule allows."""
        if math.isnan(self.coulomb_max_pct):
            return 0.0
        return max(0.0, self.max_pct - self.coulomb_max_pct - HARM_ALLOWANCE_PCT)

    @property
    def total(self) -> float:
        """``J`` of the module docstring."""
        lo, hi = COVERAGE_BAND
        off_band = max(0.0, lo - self.coverage, self.coverage - hi)
        conv = 0.0 if math.isnan(self.t_converge_s) else self.t_converge_s / CONVERGENCE_SCALE_S
        return (
            self.mae_pct
            + 0.5 * self.max_pct
            + COVERAGE_WEIGHT * off_band
            + min(conv, CONVERGENCE_CAP)
            + HARM_WEIGHT * self.harm_pct
        )


def _wrong_soc(true_soc: float, offset: float) -> float:
    """``offset`` away from the truth towards the middle (so it stays a SoC)."""
    return true_soc - offset if true_soc >= 0.5 else true_soc + offset


def _true_start(series: BatterySeries) -> tuple[np.ndarray, float, np.ndarray]:
    """The reference, its first finite SoC (clipped) and the samples after the window."""
    if series.soc_ref is None:
        raise ValueError("a recording without a reference SoC cannot be scored")
    ref = series.soc_ref
    soc0 = float(np.clip(ref[np.flatnonzero(np.isfinite(ref))[0]], 0.0, 1.0))
    after = (series.t_s - series.t_s[0] >= WINDOW_S) & np.isfinite(ref)
    if not after.any():
        raise ValueError(f"the recording is shorter than the {WINDOW_S:g} s window")
    return ref, soc0, after


def coulomb_max_pct(series: BatterySeries, battery: BatteryParams) -> float:
    """Coulomb counting's max error after the window from the true start (%): the baseline of
    the harm term. It does not depend on the tuning scored: ``soc_tune`` computes it once per
    recording."""
    ref, soc0, after = _true_start(series)
    count = run_estimator(make_estimator("coulomb", battery, soc0, START_STD), series)
    return float(100.0 * np.max(np.abs(count.soc[after] - ref[after])))


def score_recording(
    series: BatterySeries,
    battery: BatteryParams,
    estimator: str,
    tuning: Mapping[str, Any],
    wrong_start: float = 0.3,
    baseline_max_pct: float | None = None,
) -> Score:
    """:class:`Score` of ``estimator`` with ``tuning`` (over the file's own block) on
    ``series``; ``wrong_start`` 0: no wrong-start run (``t_converge_s`` NaN);
    ``baseline_max_pct``: :func:`coulomb_max_pct` of ``series``, computed here when None."""
    ref, soc0, after = _true_start(series)
    t_rel = series.t_s - series.t_s[0]
    merged = {**battery.filters.get(estimator, {}), **tuning}
    est = run_estimator(make_estimator(estimator, battery, soc0, START_STD, merged), series)
    err = est.soc[after] - ref[after]
    coverage = float(np.mean(np.abs(err) <= 2.0 * est.soc_std[after]))
    if baseline_max_pct is None:
        baseline_max_pct = coulomb_max_pct(series, battery)
    t_conv = math.nan
    if wrong_start > 0.0:
        wrong = make_estimator(
            estimator, battery, _wrong_soc(soc0, wrong_start), wrong_start, merged
        )
        w = run_estimator(wrong, series)
        inside = np.flatnonzero(np.abs(w.soc - ref) < CONVERGED_SOC)
        t_conv = float(t_rel[inside[0]]) if inside.size else math.inf
    return Score(
        float(100.0 * np.mean(np.abs(err))),
        float(100.0 * np.max(np.abs(err))),
        coverage,
        t_conv,
        baseline_max_pct,
    )
