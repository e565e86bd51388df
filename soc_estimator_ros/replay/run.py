"""One replay job: a recording through one or more estimators, each behind a ``Tracker``.

The samples go through the same :class:`~soc_estimator_ros.tracking.Tracker` the node uses: the
input gate rejects and counts what the node rejects (NaN/inf, out of range, duplicate, out of
order, stale, not present), and the start is the node's (``initial_soc``: the OCV of the first
accepted sample by default, a given SoC, or the recording's reference with ``"ref"``).

An :class:`EstimateSeries` keeps one row per input sample: a rejected sample repeats the last
estimate (status = the rejection reason); rows before the first accepted sample are NaN. A
:class:`RuntimeSeries` keeps the tracker's runtime monitor per row: FULL, and with
``runtime=True`` its latest prediction, made as the node makes them (every second of sample
time, its default settings); without, no prediction is made (NaN: they are only needed for
the CSV and the plots).

With a state file (``state``, ``soc_replay --state FILE``) the tracker learns the battery's
health (``health/``), starts from the health saved in the file (whatever its age; the SoC is
not resumed: the replay's start is ``initial_soc``) and writes it back at the end, as the
node's persistence does, so missions replayed in order with one file are one battery's life.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..cells import cell_field_names
from ..errors import SocEstimatorError
from ..estimators import ESTIMATORS
from ..evaluation import Accuracy, accuracy
from ..health import CapacityPair
from ..messages import chemistry_of_technology
from ..params import BatteryParams, load_battery_params
from ..recordings import read_recording
from ..resources import BUNDLED_FILES, bundled_file
from ..runtime import RuntimeConfig
from ..scaling import scale_to_pack
from ..series import HEALTH_COLUMNS, RUNTIME_COLUMNS, BatterySeries, EstimateSeries, RuntimeSeries
from ..tracking import GateConfig, Sample, Tracker, TrackerConfig, Verdict
from ..tracking.decimation import filter_period_s
from ..tracking.persistence import resume_health, save_state
from ..units import CurrentSign

#: Std of a given (numeric or reference) initial SoC.
INITIAL_SOC_STD = 0.1
#: The accuracy window (s): errors are scored after it (evaluation.accuracy's default).
ACCURACY_WINDOW_S = 600.0

Progress = Callable[[int, int], None]


class ReplayError(SocEstimatorError, ValueError):
    """A replay that cannot run or whose result is unusable (one line, the input named)."""


@dataclass(frozen=True)
class ReplayResult:
    """One estimator on one input: its estimates, accuracy, start and input counts."""

    input_name: str
    estimates: EstimateSeries
    accuracy: Accuracy | None
    start: str
    counts: dict[str, int]
    runtime: RuntimeSeries | None = None
    #: The capacity's pairs of well-known SoC points this run made (``health/``; empty when
    #: the health is not learned).
    health_pairs: tuple[CapacityPair, ...] = ()

    @property
    def finite(self) -> bool:
        """True when the run ends with a finite SoC and std."""
        e = self.estimates
        return bool(len(e.soc)) and math.isfinite(e.soc[-1]) and math.isfinite(e.soc_std[-1])


@dataclass(frozen=True)
class ReplayJob:
    """What to replay: an input, how to read it, with which file, estimators and start."""

    path: Path
    estimators: tuple[str, ...]
    params: Path | None = None
    initial_soc: str = "ocv"
    topic: str = "/battery/state"
    sign: CurrentSign = CurrentSign.DISCHARGE_POSITIVE
    progress: bool = False
    live_rate: float | None = None
    live: bool = False
    extras: dict[str, str] = field(default_factory=dict)
    runtime: bool = False
    health: bool = False
    state: Path | None = None
    cells_in_series: int = 0
    capacity_ah: float = 0.0
    #: Filter steps per second (``TrackerConfig.filter_period_s``); 0 = on every sample.
    filter_rate_hz: float = 0.0
    #: An fsspec URL the input is fetched from where the job runs (``fleet.py``); "" = path.
    url: str = ""

    @property
    def name(self) -> str:
        """The input's name in tables and plots."""
        return self.url.rstrip("/").rsplit("/", 1)[-1] if self.url else self.path.name


def battery_file_for(series: BatterySeries) -> Path:
    """The bundled battery file matching a recording's ``power_supply_technology``."""
    chemistry = chemistry_of_technology(series.technology)
    if chemistry is None:
        known = ", ".join(f"{c} -> {f}" for c, f in BUNDLED_FILES.items())
        raise ReplayError(
            f"power_supply_technology {series.technology} matches no bundled battery file "
            f"({known}): pass --params"
        )
    return bundled_file(chemistry)


def tracker_config(
    series: BatterySeries,
    estimator: str,
    initial_soc: str,
    runtime: bool = False,
    health: bool = False,
    filter_rate_hz: float = 0.0,
    initial_soc_std: float = INITIAL_SOC_STD,
) -> TrackerConfig:
    """The tracker's start for ``initial_soc``: ``"ocv"``, ``"ref"`` or a fraction (text), the
    last two with std ``initial_soc_std``; ``runtime``: predictions every second as the node
    makes them (else none); ``health``: learn the battery's health; ``filter_rate_hz``: filter
    steps per second (0: every sample)."""
    rt = RuntimeConfig() if runtime else RuntimeConfig(predict_period_s=0.0)
    period_s = filter_period_s(filter_rate_hz)
    if initial_soc == "ocv":
        return TrackerConfig(
            estimator=estimator,
            initial_soc="ocv",
            runtime=rt,
            health=health,
            filter_period_s=period_s,
        )
    if initial_soc == "ref":
        if series.soc_ref is None or not math.isfinite(series.soc_ref[0]):
            raise ReplayError("--initial-soc ref: the recording has no reference SoC at its start")
        value = float(series.soc_ref[0])
    else:
        try:
            value = float(initial_soc)
        except ValueError:
            raise ReplayError(
                f"--initial-soc {initial_soc}: expected ocv, ref or a fraction in [0, 1]"
            ) from None
        if not 0.0 <= value <= 1.0:
            raise ReplayError(f"--initial-soc {initial_soc}: expected a fraction in [0, 1]")
    return TrackerConfig(
        estimator=estimator,
        initial_soc=value,
        initial_soc_std=initial_soc_std,
        runtime=rt,
        health=health,
        filter_period_s=period_s,
    )


def track_series(
    series: BatterySeries, tracker: Tracker, progress: Progress | None = None
) -> tuple[EstimateSeries, str]:
    """Every sample of ``series`` through ``tracker``; the estimates and the start used."""
    estimates, start, _ = track_series_runtime(series, tracker, progress)
    return estimates, start


def track_series_runtime(
    series: BatterySeries, tracker: Tracker, progress: Progress | None = None
) -> tuple[EstimateSeries, str, RuntimeSeries]:
    """:func:`track_series` and the runtime monitor over the run (its predictions NaN when the
    tracker makes none; FULL either way)."""
    n = len(series)
    rt = {k: np.full(n, math.nan) for k in (*RUNTIME_COLUMNS, *HEALTH_COLUMNS)}
    health = tracker.health
    full = np.zeros(n, dtype=bool)
    report: dict[str, float] | None = None
    soc = np.full(n, math.nan)
    std = np.full(n, math.nan)
    v_pred = np.full(n, math.nan)
    nis = np.full(n, math.nan)
    innov = np.full(n, math.nan)
    dim = len(tracker.estimator.state_names)
    x = np.full((n, dim), math.nan)
    p = np.full((n, dim, dim), math.nan)
    status: list[str] = []
    start = ""
    pack = tracker.pack_serial(series.serial_number)
    every = max(1, n // 50)
    last = None
    cell_v = series.cell_voltage_v
    n_cells = 0 if cell_v is None else cell_v.shape[1]
    cell_soc = np.full((n, n_cells), math.nan)
    cell_std = np.full((n, n_cells), math.nan)
    cell_fields = np.full((n, len(cell_field_names(n_cells)) if n_cells else 0), math.nan)
    lumped = np.full(n, math.nan)
    lumped_std = np.full(n, math.nan)
    cells = None
    for k in range(n):
        sample = Sample(
            int(series.stamp_ns[k]),
            float(series.current_a[k]),
            float(series.voltage_v[k]),
            float(series.temperature_c[k]),
            cell_voltage_v=() if cell_v is None else tuple(float(v) for v in cell_v[k]),
        )
        result = tracker.process(sample)
        if result.estimate is not None:
            cells = result.cells
            last = result.estimate
            status.append(last.status.value)
            v_pred[k], innov[k], nis[k] = last.voltage_pred_v, last.innovation_v, last.nis
            if not start and result.events:
                start = result.events[0].message
        else:
            status.append(result.verdict.value)
        if last is not None:
            soc[k], std[k] = last.soc, last.soc_std
            x[k], p[k] = last.x, last.p
        if cells is not None and last is not None:  # the usable SoC is the published one
            lumped[k], lumped_std[k] = soc[k], std[k]
            soc[k], std[k] = cells.usable_soc, cells.usable_soc_std
            cell_soc[k], cell_std[k] = cells.soc, cells.soc_std
            cell_fields[k] = list(cells.fields().values())
        if result.runtime is not None:
            report = result.runtime.fields()
        if report is not None:
            for name in RUNTIME_COLUMNS:
                rt[name][k] = report[name]
        full[k] = tracker.runtime.full
        if health is not None:
            rt["capacity_ah"][k], rt["r0_factor"][k] = health.capacity_ah, health.r0_factor
        if progress is not None and (k + 1) % every == 0:
            progress(k + 1, n)
    tracker.finish()
    if health is not None and n:  # the end of the run may have read a last rest
        rt["capacity_ah"][n - 1], rt["r0_factor"][n - 1] = health.capacity_ah, health.r0_factor
    estimates = EstimateSeries.over(
        series,
        estimator=tracker.estimator.name,
        soc=soc,
        soc_std=std,
        voltage_pred_v=v_pred,
        nis=nis,
        status=tuple(status),
        innovation_v=innov,
        x=x,
        p=p,
        state_names=tracker.estimator.state_names,
        cell_soc=cell_soc if n_cells else None,
        cell_soc_std=cell_std if n_cells else None,
        cell_fields=cell_fields if n_cells else None,
        soc_lumped=lumped if n_cells else None,
        soc_lumped_std=lumped_std if n_cells else None,
    )
    runtime = RuntimeSeries(rt, full, tracker.battery.limits.soc_min)
    start = start or "no sample accepted"
    return estimates, f"{pack.message}; {start}" if pack is not None else start, runtime


def replay_estimator(
    series: BatterySeries,
    battery: BatteryParams,
    estimator: str,
    initial_soc: str,
    name: str,
    progress: Progress | None = None,
    runtime: bool = False,
    health: bool = False,
    state: Path | None = None,
    filter_rate_hz: float = 0.0,
    initial_soc_std: float = INITIAL_SOC_STD,
) -> ReplayResult:
    """One estimator over a recording, offline, behind a tracker (with the runtime
    monitor's predictions when ``runtime``; learning the health when ``health`` or with a
    ``state`` file, from whose health it starts and to which it writes it back; a given
    start's std ``initial_soc_std``)."""
    saved, health_start = None, ""
    if state is not None:
        saved, health_start = resume_health(state, battery.name, battery.capacity_ah)
    tracker = Tracker(
        battery,
        GateConfig.from_limits(battery.limits),
        tracker_config(
            series,
            estimator,
            initial_soc,
            runtime,
            health or state is not None,
            filter_rate_hz,
            initial_soc_std,
        ),
        health=saved,
    )
    estimates, start, rt = track_series_runtime(series, tracker, progress)
    if state is not None:
        save_health(state, tracker)
        start = f"{health_start}; {start}"
    counts = {v.value: c for v, c in tracker.gate.counts.items() if c and v is not Verdict.ACCEPTED}
    if tracker.gate.temperature_ignored:
        counts["temperature_ignored"] = tracker.gate.temperature_ignored
    pairs = tuple(tracker.health.capacity.pairs) if tracker.health is not None else ()
    return ReplayResult(name, estimates, score(series, estimates), start, counts, rt, pairs)


def save_health(path: Path, tracker: Tracker) -> None:
    """Write ``tracker``'s state, its health with it, to ``path`` (``ReplayError`` if not)."""
    state = tracker.saved_state()
    if state is None:
        return
    try:
        save_state(path, state)
    except OSError as exc:
        raise ReplayError(f"--state {path}: cannot be written ({exc})") from exc


def score(series: BatterySeries, estimates: EstimateSeries) -> Accuracy | None:
    """Accuracy against the recording's reference (None without one or a short run)."""
    if series.soc_ref is None or series.t_s[-1] <= ACCURACY_WINDOW_S:
        return None
    try:
        return accuracy(estimates.t_s, estimates.soc, series.soc_ref, ACCURACY_WINDOW_S)
    except ValueError:
        return None  # no sample with both an estimate and a reference after the window


def job_battery(job: ReplayJob, series: BatterySeries) -> tuple[Path, BatteryParams]:
    """The job's battery file (``--params``, else by the recording's technology) and its
    parameters, scaled to the job's pack."""
    battery_file = job.params or battery_file_for(series)
    battery = load_battery_params(battery_file)
    try:
        battery = scale_to_pack(battery, job.cells_in_series, job.capacity_ah)
    except ValueError as exc:  # the node's rule (node/ros_node.py), one line
        raise ReplayError(f"--cells-in-series / --capacity-ah: {exc}") from exc
    return Path(battery_file), battery


def check_finite(result: ReplayResult, job_name: str, estimator: str) -> None:
    """A run that ends with a SoC that is not finite is an error (one line)."""
    if not result.finite:
        raise ReplayError(
            f"{job_name}: {estimator} ends with a SoC that is not finite "
            f"(rejected: {result.counts or 'none'})"
        )


def run_job(job: ReplayJob) -> tuple[BatterySeries, BatteryParams, list[ReplayResult]]:
    """Read the job's input and replay it through each of its estimators."""
    from .outputs import ProgressBar  # noqa: PLC0415 (outputs imports matplotlib lazily)

    series = read_recording(job.path, job.topic, job.sign)
    battery_file, battery = job_battery(job, series)
    results = []
    for estimator in job.estimators:
        if estimator not in ESTIMATORS:
            raise ReplayError(f"unknown estimator {estimator!r}")
        bar = ProgressBar(f"{job.name} {estimator}{' (live)' if job.live else ''}")
        progress = bar if job.progress else None
        if job.live:
            from .live import replay_live  # noqa: PLC0415 (rclpy only for --live)

            config = tracker_config(series, estimator, job.initial_soc)
            estimates, start, rt = replay_live(
                series,
                Path(battery_file).resolve(),
                config,
                job.live_rate,
                progress,
                {"cells_in_series": job.cells_in_series, "capacity_ah": float(job.capacity_ah)},
            )
            result = ReplayResult(job.name, estimates, score(series, estimates), start, {}, rt)
        else:
            result = replay_estimator(
                series,
                battery,
                estimator,
                job.initial_soc,
                job.name,
                progress,
                job.runtime,
                job.health,
                job.state,
                job.filter_rate_hz,
            )
        check_finite(result, job.name, estimator)
        results.append(result)
    return series, battery, results
