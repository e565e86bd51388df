"""t2rc_ukf replays of many recordings through the batch engine (``batch/``), with the
results of :func:`~soc_estimator_ros.replay.run.replay_estimator`.

Everything around the filter stays the tracker's: each recording first goes through a
:class:`~soc_estimator_ros.tracking.Tracker` whose estimator only logs what it is asked
(:class:`_CallLog`: the samples it steps, the SoC resets of the start and of a FULL
recalibration), so the input gate, the start, the counts, the charge monitor's FULL and the
statuses are the tracker's own. The batch engine then runs every recording's logged calls as
one lane (lock-step by call; the resets applied where the tracker made them) and the filter's
outputs fill the tracker's rows. The filter equals the per-sample t2rc_ukf to 1e-9 in SoC
(``test/unit/replay/test_batch.py``); the tracker's pass costs about a fifth of the per-sample
replay. Not for ``--live``, ``--state``/``--learn-health`` (the health feeds back into the
filter) or runtime predictions (they read the filter at every second): those replay sample
by sample.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from ..batch import BatchError, BatchT2rcUkf, LaneStatus
from ..estimators import Estimator, StepStatus
from ..estimators.t2rc_ukf import T2rcUkf
from ..params import BatteryParams
from ..recordings import read_recording
from ..series import BatterySeries, EstimateSeries
from ..tracking import GateConfig, Tracker, Verdict
from .run import (
    ReplayJob,
    ReplayResult,
    check_finite,
    job_battery,
    score,
    track_series_runtime,
    tracker_config,
)

#: ``--batch auto`` runs t2rc_ukf through the engine from this many recordings of one battery
#: (docs/benchmarks.md: below it the engine's per-step floor costs more than it saves).
BATCH_MIN_LANES = 32

#: The statuses of rows whose estimate a step made (the others repeat the last one).
_STEPPED = {s.value for s in (StepStatus.INITIALIZED, StepStatus.OK, StepStatus.GAP)}


@dataclass
class _Calls:
    """One recording's estimator calls: per step, its sample, and the SoC reset applied
    before it (NaN: none) and after it (a FULL recalibration, reported in the estimate)."""

    t_s: list[float] = field(default_factory=list)
    current_a: list[float] = field(default_factory=list)
    voltage_v: list[float] = field(default_factory=list)
    temperature_c: list[float] = field(default_factory=list)
    fresh: list[bool] = field(default_factory=list)  # no time base before it: a first sample
    before: list[tuple[float, float]] = field(default_factory=list)
    after: list[tuple[float, float]] = field(default_factory=list)
    # The published variance's count (``Estimator.count_floor``) after the call: SoC, variance.
    count: list[tuple[float, float]] = field(default_factory=list)


class _CallLog(T2rcUkf):
    """t2rc_ukf's interface and time rules (``Estimator.step``) with no filter: it logs the
    calls for the batch engine. Its SoC is the last reset's (the tracker reads it only for
    the low-battery level, which no replay output holds without predictions)."""

    def _init_state(self, soc: float, soc_var: float) -> None:
        n_rc = len(self.battery.thevenin.branches)
        self.x = np.array([soc] + [0.0] * n_rc)
        self.p = np.diag([soc_var] + [self.tuning["p0_v"]] * n_rc)
        calls: _Calls | None = getattr(self, "calls", None)
        if calls is not None:
            self._pending = (soc, soc_var)

    # FilterpyState's properties over a filterpy filter are replaced by plain attributes.
    x: np.ndarray = np.zeros(0)
    p: np.ndarray = np.zeros(0)
    calls: _Calls
    _pending: tuple[float, float]

    def step(self, t_s, current_a, voltage_v, temperature_c=None, held_current_a=None):
        assert held_current_a is None, "the batch engine steps on every sample"
        calls = self.calls
        calls.t_s.append(t_s)
        calls.current_a.append(current_a)
        calls.voltage_v.append(voltage_v)
        calls.temperature_c.append(math.nan if temperature_c is None else temperature_c)
        calls.fresh.append(self.t_last_s is None)
        calls.before.append(self._take_pending())
        calls.after.append((math.nan, math.nan))
        out = Estimator.step(self, t_s, current_a, voltage_v, temperature_c)
        calls.count.append(self._count_now())
        return out

    def after_step_reset(self) -> None:
        """The reset just made belongs after the last step (a FULL recalibration)."""
        self.calls.after[-1] = self._take_pending()
        self.calls.count[-1] = self._count_now()

    def _count_now(self) -> tuple[float, float]:
        """The floor's count (base.py ``_published``): the filter's calls move it alike."""
        count = self.floor_count
        assert count is not None
        return count.soc, count.var

    def _take_pending(self) -> tuple[float, float]:
        pending = getattr(self, "_pending", (math.nan, math.nan))
        self._pending = (math.nan, math.nan)
        return pending

    def _predict(self, dt_s, current_a, next_current_a, temp_c) -> None:
        return None

    def _update(self, current_a, voltage_v, temp_c) -> tuple[float, float, float]:
        return math.nan, math.nan, math.nan


class _LoggingTracker(Tracker):
    """The tracker with :class:`_CallLog` as its estimator; a FULL recalibration's reset is
    marked as following the step it came after."""

    def __init__(self, battery: BatteryParams, gate: GateConfig, config) -> None:
        super().__init__(battery, gate, config)
        log = _CallLog(battery, 0.5, config.initial_soc_std, self.estimator.tuning)
        log.calls = _Calls()
        log._pending = (math.nan, math.nan)
        self.estimator = log
        if not isinstance(config.initial_soc, str):  # the tracker set it at construction
            log.reset_soc(float(config.initial_soc), config.initial_soc_std)

    def _recalibrate(self, soc: float, soc_std: float):
        est = super()._recalibrate(soc, soc_std)
        assert isinstance(self.estimator, _CallLog)
        self.estimator.after_step_reset()
        return est


def replay_t2rc_batch(
    recordings: Sequence[tuple[str, BatterySeries]],
    battery: BatteryParams,
    initial_soc: str,
) -> list[ReplayResult]:
    """t2rc_ukf over every recording (one battery), as ``replay_estimator`` would replay each
    without runtime predictions or health; one :class:`ReplayResult` per recording."""
    logged = []
    for name, series in recordings:
        config = replace(tracker_config(series, T2rcUkf.name, initial_soc), health=False)
        tracker = _LoggingTracker(battery, GateConfig.from_limits(battery.limits), config)
        estimates, start, runtime = track_series_runtime(series, tracker)
        counts = {
            v.value: c for v, c in tracker.gate.counts.items() if c and v is not Verdict.ACCEPTED
        }
        if tracker.gate.temperature_ignored:
            counts["temperature_ignored"] = tracker.gate.temperature_ignored
        assert isinstance(tracker.estimator, _CallLog)
        logged.append((name, series, estimates, start, runtime, counts, tracker.estimator))
    outputs = _run_calls(battery, [log.calls for *_, log in logged], logged[0][-1])
    results = []
    for (name, series, estimates, start, runtime, counts, _), out in zip(
        logged, outputs, strict=True
    ):
        filled = _fill(estimates, *out)
        results.append(ReplayResult(name, filled, score(series, filled), start, counts, runtime))
    return results


def _run_calls(battery: BatteryParams, lanes: list[_Calls], proto: _CallLog):
    """Every lane's calls through one engine; per lane the outputs of its non-rejected calls:
    (soc, var, v_pred, innovation, nis, x, p), in call order."""
    k = len(lanes)
    n = max(len(c.t_s) for c in lanes)
    tuning = dict(proto.tuning)
    engine = BatchT2rcUkf(battery, np.full(k, 0.5), 0.05, tuning, proto.time_policy)
    dim = engine.n
    cols = {}
    for attr in ("t_s", "current_a", "voltage_v", "temperature_c"):
        a = np.zeros((k, n))
        for lane, c in enumerate(lanes):
            a[lane, : len(c.t_s)] = getattr(c, attr)
        cols[attr] = a
    present = np.zeros((k, n), dtype=bool)
    fresh = np.zeros((k, n), dtype=bool)
    before = np.full((k, n, 2), math.nan)
    after = np.full((k, n, 2), math.nan)
    count = np.full((n, k, 2), math.nan)
    for lane, c in enumerate(lanes):
        m = len(c.t_s)
        present[lane, :m] = True
        fresh[lane, :m] = c.fresh
        before[lane, :m] = c.before
        after[lane, :m] = c.after
        count[:m, lane] = c.count
    soc, var, v_pred, innov, nis = (np.full((n, k), math.nan) for _ in range(5))
    x = np.full((n, k, dim), math.nan)
    p = np.full((n, k, dim, dim), math.nan)
    stepped = np.zeros((n, k), dtype=bool)
    for step in range(n):
        reset = ~np.isnan(before[:, step, 0])
        if reset.any():
            engine.reset_soc(reset, before[reset, step, 0], before[reset, step, 1])
        new_base = fresh[:, step] & present[:, step]
        engine.t_last_s[new_base] = math.nan
        r = engine.step(
            cols["t_s"][:, step],
            cols["current_a"][:, step],
            cols["voltage_v"][:, step],
            cols["temperature_c"][:, step],
            present[:, step],
        )
        reset = ~np.isnan(after[:, step, 0])
        if reset.any():
            engine.reset_soc(reset, after[reset, step, 0], after[reset, step, 1])
        stepped[step] = present[:, step] & (r.status != LaneStatus.REJECTED_DT)
        soc[step] = engine.x[0]
        # The published variance: the filter's, floored by the count (base.py ``_published``).
        c_soc, c_var = count[step, :, 0], count[step, :, 1]
        var[step] = np.maximum(engine.p[0, 0], (engine.x[0] - c_soc) ** 2 + c_var)
        v_pred[step], innov[step], nis[step] = r.voltage_pred_v, r.innovation_v, r.nis
        x[step] = engine.x.T
        p[step] = engine.p.transpose(2, 0, 1)
    out = []
    for lane in range(k):
        rows = stepped[:, lane]
        out.append(
            (
                soc[rows, lane],
                var[rows, lane],
                v_pred[rows, lane],
                innov[rows, lane],
                nis[rows, lane],
                x[rows, lane],
                p[rows, lane],
            )
        )
    return out


def _fill(e: EstimateSeries, soc, var, v_pred, innov, nis, x, p) -> EstimateSeries:
    """The tracker's rows with the filter's outputs: a stepped row gets its call's, another
    repeats the last estimate (NaN before the first; no voltage, innovation or NIS), as
    ``track_series_runtime`` fills them."""
    rows = np.array([s in _STEPPED for s in e.status], dtype=bool)
    if int(rows.sum()) != soc.size:
        raise AssertionError(f"{int(rows.sum())} stepped rows for {soc.size} filter steps")
    call = np.cumsum(rows) - 1  # the last stepped row's call, per row (-1: none yet)
    have = call >= 0
    idx = np.where(have, call, 0)
    n = len(e.status)
    out_soc = np.where(have, soc[idx] if soc.size else math.nan, math.nan)
    out_var = np.where(have, var[idx] if var.size else math.nan, math.nan)
    dim = e.x.shape[1]
    out_x = np.full((n, dim), math.nan)
    out_p = np.full((n, dim, dim), math.nan)
    if soc.size:
        out_x[have], out_p[have] = x[idx[have]], p[idx[have]]
    pred, inn, ni = (np.full(n, math.nan) for _ in range(3))
    pred[rows], inn[rows], ni[rows] = v_pred, innov, nis
    return replace(
        e,
        soc=out_soc,
        soc_std=np.sqrt(np.maximum(out_var, 0.0)),
        voltage_pred_v=pred,
        innovation_v=inn,
        nis=ni,
        x=out_x,
        p=out_p,
    )


def batch_eligible(job: ReplayJob) -> bool:
    """A job whose t2rc_ukf the batch engine can replay: offline, no health, no runtime
    predictions (CSV, plots), no output bag, a filter step on every sample, and a local input
    (a URL is fetched by its job, ``fleet.py``)."""
    return (
        T2rcUkf.name in job.estimators
        and not job.url
        and not job.live
        and not job.health
        and job.state is None
        and not job.runtime
        and not job.extras.get("output_bag")
        and job.filter_rate_hz == 0.0
    )


def replay_jobs_batched(jobs: Sequence[ReplayJob]) -> dict[int, ReplayResult]:
    """t2rc_ukf of ``jobs`` (all :func:`batch_eligible`) through the engine, one engine per
    battery: the results by job index. A battery whose engine fails (a lane's covariance) is
    left out, for the per-sample path (and its tracker's recovery) to replay."""
    groups: dict[tuple, list[tuple[int, str, BatterySeries, BatteryParams]]] = {}
    for i, job in enumerate(jobs):
        series = read_recording(job.path, job.topic, job.sign)
        battery_file, battery = job_battery(job, series)
        key = (battery_file.resolve(), job.cells_in_series, job.capacity_ah, job.initial_soc)
        groups.setdefault(key, []).append((i, job.name, series, battery))
    out: dict[int, ReplayResult] = {}
    for key, members in groups.items():
        battery = members[0][3]
        if battery.hysteresis is not None:
            # The tracker hands the filter the hysteresis' offset variance on every step
            # (``Estimator.voltage_offset_var_v2``), which the engine's lanes do not carry.
            continue
        try:
            results = replay_t2rc_batch([(m[1], m[2]) for m in members], battery, key[3])
        except BatchError:
            continue
        for (i, name, _, _), result in zip(members, results, strict=True):
            check_finite(result, name, T2rcUkf.name)
            out[i] = result
    return out
