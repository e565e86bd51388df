"""Run an estimator over a recorded series, and score it against a reference SoC.

One offline path: the replay CLI, the benchmarks, the accuracy tests and the node's
offline-equals-live test all call :func:`run_estimator` and :func:`accuracy`.

Metrics (as in seed 000 §4): mean absolute error, RMSE and maximum absolute error of the SoC,
in SoC fraction, over the samples after a convergence window (10 minutes by default, the
issue's window); convergence time is the time from the first sample until
``|error| < threshold`` (2 %) is first reached, and settle time until it holds for good.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from .estimators.base import Estimator
from .series import EstimateSeries, SampleSeries
from .units import SECONDS_PER_HOUR


def run_estimator(
    estimator: Estimator,
    series: SampleSeries,
    progress: Callable[[int, int], None] | None = None,
) -> EstimateSeries:
    """Feed every sample of ``series`` to ``estimator`` in order and collect the estimates.

    ``progress(done, total)`` is called every 2 % of the samples (a long replay's progress bar).
    """
    n = len(series.t_s)
    soc = np.empty(n)
    std = np.empty(n)
    v_pred = np.empty(n)
    nis = np.empty(n)
    innov = np.empty(n)
    xs: list[np.ndarray] = []
    ps: list[np.ndarray] = []
    names: tuple[str, ...] = ()
    status: list[str] = []
    every = max(1, n // 50)
    temps = series.temperature_c
    for k in range(n):
        t = float(temps[k]) if temps is not None else math.nan
        est = estimator.step(
            float(series.t_s[k]),
            float(series.current_a[k]),
            float(series.voltage_v[k]),
            None if math.isnan(t) else t,
        )
        soc[k] = est.soc
        std[k] = est.soc_std
        v_pred[k] = est.voltage_pred_v
        nis[k] = est.nis
        innov[k] = est.innovation_v
        xs.append(est.x)
        ps.append(est.p)
        names = est.state_names
        status.append(est.status.value)
        if progress is not None and (k + 1) % every == 0:
            progress(k + 1, n)
    return EstimateSeries.over(
        series,
        estimator=estimator.name,
        soc=soc,
        soc_std=std,
        voltage_pred_v=v_pred,
        nis=nis,
        status=tuple(status),
        innovation_v=innov,
        x=np.array(xs, dtype=float).reshape(n, -1),
        p=np.array(ps, dtype=float).reshape(n, len(names), len(names))
        if n
        else np.empty((0, 0, 0)),
        state_names=names,
    )


@dataclass(frozen=True)
class Accuracy:
    """SoC accuracy against a reference (fractions of SoC; times in seconds)."""

    mae: float
    rmse: float
    max_abs: float
    t_converge_s: float
    t_settle_s: float
    window_s: float
    n_samples: int

    def as_percent_row(self) -> dict[str, float]:
        """MAE, RMSE, max in percent points and times in seconds, for tables."""
        return {
            "mae_pct": 100.0 * self.mae,
            "rmse_pct": 100.0 * self.rmse,
            "max_pct": 100.0 * self.max_abs,
            "t_converge_s": self.t_converge_s,
            "t_settle_s": self.t_settle_s,
        }


def accuracy(
    t_s: np.ndarray,
    soc_est: np.ndarray,
    soc_ref: np.ndarray,
    window_s: float = 600.0,
    threshold: float = 0.02,
) -> Accuracy:
    """Score ``soc_est`` against ``soc_ref`` on the same samples.

    Samples whose reference is NaN are ignored. Errors are computed on samples with
    ``t - t[0] >= window_s``. ``t_converge_s`` / ``t_settle_s`` are ``inf`` when never reached.
    """
    t = np.asarray(t_s, dtype=float)
    err = np.asarray(soc_est, dtype=float) - np.asarray(soc_ref, dtype=float)
    valid = np.isfinite(err)
    if not np.any(valid):
        raise ValueError("no sample has both an estimate and a reference SoC")
    t_rel = t - t[0]
    after = valid & (t_rel >= window_s)
    if not np.any(after):
        raise ValueError(f"the run is shorter than the {window_s:g} s convergence window")
    e = np.abs(err[after])
    inside = np.abs(err) < threshold
    inside_valid = inside | ~valid
    hit = np.flatnonzero(inside & valid)
    t_conv = float(t_rel[hit[0]]) if hit.size else math.inf
    outside = np.flatnonzero(~inside_valid)
    if outside.size == 0:
        t_settle = 0.0
    elif outside[-1] + 1 < t.size:
        t_settle = float(t_rel[outside[-1] + 1])
    else:
        t_settle = math.inf
    return Accuracy(
        mae=float(np.mean(e)),
        rmse=float(np.sqrt(np.mean(e * e))),
        max_abs=float(np.max(e)),
        t_converge_s=t_conv,
        t_settle_s=t_settle,
        window_s=window_s,
        n_samples=int(after.sum()),
    )


@dataclass(frozen=True)
class ChargeEfficiency:
    """What a recording's reference SoC says the pack's coulomb efficiency on charge is."""

    efficiency: float  # eta = charge_scale / discharge_scale
    discharge_scale: float  # reference SoC lost per counted discharge charge (x capacity)
    charge_scale: float  # reference SoC gained per counted charge (x capacity)
    offset_a: float  # a constant current the reference SoC shows beside the counted one
    discharge_ah: float  # counted
    charge_ah: float  # counted


def charge_efficiency(
    t_s: np.ndarray, current_a: np.ndarray, soc_ref: np.ndarray, capacity_ah: float
) -> ChargeEfficiency:
    """The coulomb efficiency on charge that a reference SoC shows (positive current =
    discharge, each sample's current held until the next, as ``models.coulomb`` counts).

    Least squares over the samples of the counting equation with a scale for each direction
    and a constant offset:

        -(s_k+1 - s_k) Q 3600 = a I+_k dt_k - b I-_k dt_k + c dt_k

    (``I+`` the discharge part of the current, ``I-`` the charge part, both >= 0). ``a`` is
    what the sensor's gain and the capacity make of a discharged amp-hour, ``b`` the same
    times the efficiency on charge; so ``eta = b / a`` whatever the gain and the capacity,
    and ``c`` takes the sensor's offset. Needs charge in the recording: ``ValueError``
    without any.
    """
    t = np.asarray(t_s, dtype=float)
    i = np.asarray(current_a, dtype=float)[:-1]
    ref = np.asarray(soc_ref, dtype=float)
    dt = np.diff(t)
    lost_as = -np.diff(ref) * capacity_ah * SECONDS_PER_HOUR
    ok = np.isfinite(lost_as) & np.isfinite(i) & (dt > 0.0)
    dis_as = np.where(i > 0.0, i, 0.0)[ok] * dt[ok]
    chg_as = np.where(i < 0.0, -i, 0.0)[ok] * dt[ok]
    if not chg_as.sum() > 0.0 or not dis_as.sum() > 0.0:
        raise ValueError("the recording needs both discharge and charge to tell the efficiency")
    design = np.column_stack([dis_as, -chg_as, dt[ok]])
    (a, b, c), *_ = np.linalg.lstsq(design, lost_as[ok], rcond=None)
    return ChargeEfficiency(
        efficiency=float(b / a),
        discharge_scale=float(a),
        charge_scale=float(b),
        offset_a=float(c),
        discharge_ah=float(dis_as.sum() / SECONDS_PER_HOUR),
        charge_ah=float(chg_as.sum() / SECONDS_PER_HOUR),
    )


#: The reference "reaches" a SoC within this much (fraction): the bundled field runs stop when
#: the simulator's SoC reaches ``limits.soc_min``, one 10 Hz sample short of it at most
#: (SLA run 1 ends at 0.400015 for 0.40).
REACH_TOL_SOC = 1e-3


def time_reaching(
    t_s: np.ndarray, soc_ref: np.ndarray, soc_target: float, tol: float = REACH_TOL_SOC
) -> float | None:
    """The first time (s) the reference SoC is at or below ``soc_target + tol``; None if it
    never is."""
    hit = np.flatnonzero(np.asarray(soc_ref) <= soc_target + tol)
    return float(t_s[hit[0]]) if hit.size else None


def remaining_time_s(
    t_s: np.ndarray, soc_ref: np.ndarray, soc_target: float, tol: float = REACH_TOL_SOC
) -> np.ndarray:
    """The actual time to empty: for each sample before the reference reaches ``soc_target``
    (:func:`time_reaching`), the time until it does; NaN after, and everywhere when it never
    does."""
    t_s = np.asarray(t_s, dtype=float)
    t_end = time_reaching(t_s, soc_ref, soc_target, tol)
    if t_end is None:
        return np.full(t_s.shape, math.nan)
    return np.where(t_s <= t_end, t_end - t_s, math.nan)


@dataclass(frozen=True)
class TimeToEmptyScore:
    """Predicted against actual time to empty over a run.

    Attributes:
        marks: per reference SoC mark (e.g. 0.8, 0.5, 0.3): (mark, predicted s, its std s,
            actual s) at the first sample where the reference is at or below the mark; marks
            the reference never reaches or that are at or below the target are left out.
        n: predictions scored (finite prediction and std, the reference reaching the target
            later).
        within_1sigma, within_2sigma: the fraction of them with |error| <= 1 and 2 std.
        median_abs_rel_error: the median of |predicted - actual| / actual.
        infinite: predictions that were ``inf`` (no discharge load) while the reference still
            had to reach the target.
    """

    marks: tuple[tuple[float, float, float, float], ...]
    n: int
    within_1sigma: float
    within_2sigma: float
    median_abs_rel_error: float
    infinite: int


def score_time_to_empty(
    t_s: np.ndarray,
    predicted_s: np.ndarray,
    predicted_std_s: np.ndarray,
    soc_ref: np.ndarray,
    soc_target: float,
    marks: tuple[float, ...] = (0.8, 0.5, 0.3),
    every_s: float = 60.0,
) -> TimeToEmptyScore | None:
    """Score a run's time-to-empty predictions against the reference (None when the
    reference never reaches ``soc_target``). The coverage counts one prediction per
    ``every_s`` of time (the predictions of one minute are not independent)."""
    t_s = np.asarray(t_s, dtype=float)
    actual = remaining_time_s(t_s, soc_ref, soc_target)
    if not np.any(np.isfinite(actual)):
        return None
    pred = np.asarray(predicted_s, dtype=float)
    std = np.asarray(predicted_std_s, dtype=float)
    got = []
    for mark in marks:
        if mark <= soc_target + REACH_TOL_SOC:
            continue
        hit = np.flatnonzero(np.asarray(soc_ref) <= mark)
        if not hit.size or not math.isfinite(actual[hit[0]]):
            continue
        k = int(hit[0])
        got.append((mark, float(pred[k]), float(std[k]), float(actual[k])))
    picks: list[int] = []
    next_t = -math.inf
    for j in np.flatnonzero(np.isfinite(actual) & (actual > 0.0)):
        if t_s[j] >= next_t:
            picks.append(int(j))
            next_t = t_s[j] + every_s
    idx = np.array(picks, dtype=int)
    infinite = int(np.sum(np.isinf(pred[idx])))
    ok = idx[np.isfinite(pred[idx]) & np.isfinite(std[idx])]
    if not ok.size:
        return TimeToEmptyScore(tuple(got), 0, math.nan, math.nan, math.nan, infinite)
    err = np.abs(pred[ok] - actual[ok])
    return TimeToEmptyScore(
        marks=tuple(got),
        n=int(ok.size),
        within_1sigma=float(np.mean(err <= std[ok])),
        within_2sigma=float(np.mean(err <= 2.0 * std[ok])),
        median_abs_rel_error=float(np.median(err / actual[ok])),
        infinite=infinite,
    )
