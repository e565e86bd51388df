"""The tracker: one battery's SoC over a stream of samples, without ROS.

``Sample`` in -> input gate -> estimator -> :class:`StepResult` (the verdict, the estimate, and
events to log). The node (``node/ros_node.py``), ``soc_replay`` offline and the benchmarks feed
samples through this one path, so they reject, count, initialize, resume and re-base alike.

What it owns, besides the estimator and the gate:

* **Time base.** The estimator's time is seconds since the first accepted stamp (``t0_ns``).
  A source whose stamps jump is never integrated across the jump:

  - backwards beyond the stale window (a bridge restarted its clock): its samples are rejected
    as ``STALE`` until they have stayed there for ``rebase_after_s`` of steady time and at least
    ``REBASE_MIN_SAMPLES`` samples; then the time base is re-anchored on them;
  - forwards beyond what the receiver's clock has advanced plus ``GateConfig.time_jump_s`` (one
    stamp a day ahead, a source switching from zero-based stamps to real time): rejected as
    ``TIME_JUMP``; ``REBASE_MIN_SAMPLES`` consecutive samples that agree with each other on
    the new time line re-anchor the time base, otherwise the lone sample was an outlier.

  A re-anchored time line continues after the last accepted sample by the steady time elapsed
  since (the best knowledge of the real interval): the estimator bridges it as a step or a gap
  (``TimePolicy``), so the SoC moves only by the charge the current can explain over it.
* **Initialization** on the first accepted sample: a given SoC, the OCV of that sample's
  voltage (``"ocv"``: read through the file's model at the sample's current and temperature,
  :meth:`Tracker.soc_from_ocv`), or a saved state (``"resume"``, through the ``resume``
  callback) with an OCV fallback.
* **Run-time control**: reset to a SoC, reset from the OCV, switch estimator (keeping SoC,
  variance, time base and current), recover from an estimator exception.
* **Counts**: the gate's verdicts, ignored temperatures, and samples missing from the stamps
  (gaps of whole sample periods, estimated from the median period), so lost input shows.
* **Runtime** (``runtime/``): every accepted sample and its estimate go on to a
  :class:`~soc_estimator_ros.runtime.RuntimeMonitor` (low-battery level, charge state, load
  window, and a time to empty, time to full and state of power every ``predict_period_s``).
  A CC-CV charge detected at its end recalibrates the SoC to 1 through :meth:`reset_soc`.
* **Stale input**: :meth:`carried_forward` is the last SoC with its std grown over the silence.
* **Health** (``health/``): every accepted sample also goes to a
  :class:`~soc_estimator_ros.health.HealthMonitor` (``TrackerConfig.health``), which learns
  the full capacity and a factor on ``R_0``; what it learns is handed to the estimator
  (``Estimator.set_health``), and to every estimator that takes over (a switch, a recovery).
  A CC-CV end is one of its anchors. :meth:`finish` ends a run (a rest still going is an
  anchor).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from enum import Enum

import numpy as np

from ..cells import CellBank, CellEstimate
from ..estimators import DEFAULT_ESTIMATOR, PRESETS, StepStatus, make_estimator
from ..estimators.base import Estimate, Estimator
from ..health import HealthMonitor, HealthState
from ..models.coulomb import coulomb_efficiency
from ..models.hysteresis import HysteresisState
from ..models.thevenin import TheveninModel
from ..params import BatteryParams
from ..runtime.monitor import RuntimeConfig, RuntimeMonitor, RuntimeReport
from ..units import MAX_SOC_VAR, NS_PER_S, SECONDS_PER_HOUR
from .decimation import Decimator
from .gate import GateConfig, InputGate, Verdict
from .persistence import CellsState, ResumeDecision, SavedState

#: Minimum SoC std used for (re-)initializations (an OCV on a steep curve is not exact).
MIN_INIT_SOC_STD = 1e-3
#: Jumped samples needed (besides ``rebase_after_s`` for backward jumps) to re-anchor time.
REBASE_MIN_SAMPLES = 3
#: Samples in a row that must carry another serial number than the health's, once running,
#: before it is another pack: a garbled or flapping serial field (two BMS on one topic, a
#: noisy UART) reset the learned health on every glitch.
SERIAL_CONFIRM_SAMPLES = 3
#: Accepted intervals used to estimate the source's sample period (median).
PERIOD_WINDOW = 50


class Level(str, Enum):
    """How loud an :class:`Event` is (the node logs at this level)."""

    INFO = "info"
    WARNING = "warning"
    ERROR = "error"


@dataclass(frozen=True)
class Event:
    """Something the caller should log. ``key`` groups events for throttling ("" = never)."""

    level: Level
    message: str
    key: str = ""


@dataclass(frozen=True)
class Sample:
    """One reading of the pack (the core's conventions, ``units.py``).

    Attributes:
        stamp_ns: the sample's stamp (ns, the source's clock).
        current_a: current (A, positive while discharging).
        voltage_v: pack voltage (V).
        temperature_c: temperature (degC; NaN if not measured).
        present: the source says a battery is present.
        cell_voltage_v: the cells' voltages (V, series order; ``BatteryState.cell_voltage``),
            empty when the source sends none.
    """

    stamp_ns: int
    current_a: float
    voltage_v: float
    temperature_c: float = math.nan
    present: bool = True
    cell_voltage_v: tuple[float, ...] = ()


@dataclass(frozen=True)
class StepResult:
    """What became of one sample: the verdict, the estimate if accepted, events to log, and
    the runtime monitor's report when this sample made one."""

    verdict: Verdict
    estimate: Estimate | None = None
    events: tuple[Event, ...] = ()
    runtime: RuntimeReport | None = None
    cells: CellEstimate | None = None
    #: False for a sample between filter steps (``TrackerConfig.filter_period_s``): its
    #: estimate is the last step's, moved by the charge counted since.
    filtered: bool = True

    @property
    def accepted(self) -> bool:
        """True when the estimator ran on the sample."""
        return self.estimate is not None


InitialSoc = float | str  # a fraction, "ocv" or "resume"
ResumeFn = Callable[[float], ResumeDecision]


@dataclass(frozen=True)
class TrackerConfig:
    """How a tracker starts and re-anchors.

    Attributes:
        estimator: estimator (or preset) name.
        initial_soc: a fraction in [0, 1], ``"ocv"`` or ``"resume"``.
        initial_soc_std: std of a numeric ``initial_soc``.
        ocv_voltage_std_v: voltage uncertainty when a voltage is read as an OCV (V).
        rebase_after_s: steady time a backward jump must persist before re-anchoring (s).
        runtime: the runtime monitor's settings (``runtime/monitor.py``).
        health: learn the battery's health (``health/``) and hand it to the estimator. Off by
            default until its rest readings are validated (docs/architecture.md): every
            estimator then runs on the file's capacity and resistances, as before.
        filter_period_s: step the estimator (and the runtime and health monitors) at most
            once per this many seconds, on the interval's counted charge and mean voltage
            (``decimation.py``); 0 = on every sample.
        initial_branch: for a battery with OCV hysteresis, where the pack starts between its
            branches (0 discharge, 1 charge: ``models/hysteresis.py``); None = unknown (midway,
            uncertain). A resumed state carries its own.
    """

    estimator: str = DEFAULT_ESTIMATOR
    initial_soc: InitialSoc = "ocv"
    initial_soc_std: float = 0.1
    ocv_voltage_std_v: float = 0.05
    rebase_after_s: float = 2.0
    runtime: RuntimeConfig = field(default_factory=RuntimeConfig)
    health: bool = False
    filter_period_s: float = 0.0
    initial_branch: float | None = None

    def __post_init__(self) -> None:
        b = self.initial_branch
        if b is not None and not 0.0 <= b <= 1.0:
            raise ValueError(f"initial_branch = {b!r}: expected None or a fraction in [0, 1]")
        if not (self.filter_period_s >= 0.0 and math.isfinite(self.filter_period_s)):
            raise ValueError(f"filter_period_s = {self.filter_period_s!r}: expected >= 0 s")
        init = self.initial_soc
        if isinstance(init, str):
            if init not in ("ocv", "resume"):
                raise ValueError(f"initial_soc = {init!r}: expected a fraction, 'ocv' or 'resume'")
        elif not 0.0 <= float(init) <= 1.0:
            raise ValueError(f"initial_soc = {init!r}: expected a fraction in [0, 1]")


class Tracker:
    """One battery's SoC estimation over a sample stream (see the module docstring).

    Not thread-safe: the node serializes calls with its lock.
    """

    def __init__(
        self,
        battery: BatteryParams,
        gate: GateConfig,
        config: TrackerConfig | None = None,
        *,
        resume: ResumeFn | None = None,
        steady_clock: Callable[[], float] = time.monotonic,
        health: HealthState | None = None,
    ) -> None:
        self.battery = battery
        self.config = config or TrackerConfig()
        self.gate = InputGate(gate)
        self._resume = resume
        self._steady = steady_clock
        init = self.config.initial_soc
        self._initial: InitialSoc = init
        soc0 = float(init) if not isinstance(init, str) else 0.5
        self.estimator: Estimator = make_estimator(
            self.config.estimator, battery, soc0, self.config.initial_soc_std
        )
        self.estimator_name = self.config.estimator
        #: Stamp of the first accepted sample: the estimator's time origin (None before).
        self.t0_ns: int | None = None
        self.last_sample: Sample | None = None
        self.last_estimate: Estimate | None = None
        self.last_accept_steady_s: float | None = None
        #: Time (s, estimator time base) of the last accepted sample (None before).
        self._t_sample_s: float | None = None
        self.samples_used = 0
        period = self.config.filter_period_s
        self._decimator = Decimator(period) if period > 0.0 else None
        #: The last filter step's estimate (samples between steps move from it).
        self._step_estimate: Estimate | None = None
        self._step_cells_estimate: CellEstimate | None = None
        #: Grows on every change of the estimate (a save is due when it moved since the last).
        self.revision = 0
        self.missing_samples = 0
        #: Samples whose serial number differed from the health's without (yet) persisting.
        self.serial_unconfirmed = 0
        self._serial_run: tuple[str, int] = ("", 0)
        self._stale_since_s: float | None = None
        self._stale_run = 0
        self._jump_run: list[int] = []
        self._intervals: list[float] = []
        self._period_s: float | None = None
        self.runtime = RuntimeMonitor(battery, self.config.runtime)
        #: The health monitor (None with ``TrackerConfig.health`` off); ``health`` resumes it.
        self.health: HealthMonitor | None = (
            HealthMonitor(battery, health) if self.config.health else None
        )
        self._apply_health()
        #: The cells' filters (``cells/``), made on the first sample with a voltage for every
        #: one of the file's ``cells_in_series`` cells; None before (and for a pack without).
        self.cells: CellBank | None = None
        #: Samples whose ``cell_voltage`` held another number of cells (not estimated).
        self.cells_miscounted = 0
        #: The cells of a resumed state and its age (s), for the bank made on the first
        #: sample with cell voltages.
        self._resumed_cells: tuple[CellsState, float] | None = None
        #: The cells after the last accepted sample (None when it carried no cell voltages).
        self.last_cells: CellEstimate | None = None
        #: Where the pack is between its OCV branches (``models/hysteresis.py``), advanced on
        #: every accepted sample; None for a battery without hysteresis.
        self.hysteresis: HysteresisState | None = (
            None if battery.hysteresis is None else self._start_branch()
        )

    # -- the estimation step ------------------------------------------------------------------
    def process(
        self, sample: Sample, now_ns: int | None = None, clock_ns: int | None = None
    ) -> StepResult:
        """Gate one sample and, if accepted, run the estimator on it.

        Args:
            sample: the reading.
            now_ns: the receiver's clock (ns) for the gate's age check (``stale_vs_clock``),
                or None to skip it.
            clock_ns: the receiver's clock (ns) at arrival, for the time-jump check, or None
                (offline: the stamps are the only time).
        """
        s = sample
        events: list[Event] = []
        verdict = self.gate.evaluate(
            s.stamp_ns, s.current_a, s.voltage_v, s.present, now_ns, clock_ns
        )
        if verdict is Verdict.STALE and self._stale_long_enough():
            events.append(self._rebase(s.stamp_ns, "jumped back"))
            verdict = self.gate.evaluate(s.stamp_ns, s.current_a, s.voltage_v, s.present, now_ns)
        elif verdict is Verdict.TIME_JUMP and self._jump_confirmed(s.stamp_ns):
            events.append(self._rebase(s.stamp_ns, "jumped ahead"))
            verdict = self.gate.evaluate(s.stamp_ns, s.current_a, s.voltage_v, s.present, now_ns)
        if verdict is not Verdict.TIME_JUMP:
            self._jump_run.clear()
        self.gate.commit(verdict, s.stamp_ns, clock_ns)
        if not verdict.accepted:
            return StepResult(verdict, None, (*events, self._rejection_event(verdict, s)))
        self._stale_since_s = None
        if self.t0_ns is None:
            events.append(self._initialize(s))
            self.t0_ns = s.stamp_ns
        t_s = (s.stamp_ns - self.t0_ns) * 1e-9  # as BatterySeries.t_s: the same float
        temperature_c = self.gate.temperature(s.temperature_c)
        temp = temperature_c if math.isfinite(temperature_c) else None
        t_prev = self._t_sample_s
        if self.hysteresis is not None and t_prev is not None and self.last_sample is not None:
            self._advance_hysteresis(self.last_sample.current_a, s.current_a, t_s - t_prev)
        current_a, voltage_v, cell_voltage_v = s.current_a, s.voltage_v, s.cell_voltage_v
        held_a: float | None = None
        if self._decimator is not None:
            interval = self._decimator.add(t_s, current_a, voltage_v, cell_voltage_v)
            if interval is None and self._step_estimate is not None:
                return self._between_steps(t_s, t_prev, s, temperature_c, verdict, events)
            if interval is not None:
                current_a, voltage_v = interval.mean_current_a, interval.mean_voltage_v
                cell_voltage_v, held_a = interval.mean_cell_voltage_v, interval.held_current_a
        terminal_v = voltage_v  # the charge monitor and the power read the terminal's
        if self.battery.hysteresis is not None and self.hysteresis is not None:
            voltage_v, cell_voltage_v = self._on_discharge_branch(voltage_v, cell_voltage_v)
            self.estimator.voltage_offset_var_v2 = (
                self.battery.hysteresis.std_v(self.hysteresis) ** 2
            )
        try:
            est = self.estimator.step(t_s, current_a, voltage_v, temp, held_current_a=held_a)
        except Exception as exc:  # a numerical failure must not end the run
            self.gate.record(Verdict.ESTIMATOR_ERROR)
            return StepResult(Verdict.ESTIMATOR_ERROR, None, (*events, self._recover(exc)))
        if est.status is StepStatus.REJECTED_DT:
            self.gate.record(Verdict.ESTIMATOR_DT)
            return StepResult(
                Verdict.ESTIMATOR_DT,
                None,
                (*events, self._rejection_event(Verdict.ESTIMATOR_DT, s)),
            )
        self._accepted(t_s, t_prev, s, temperature_c)
        if self.health is not None and self.health.update(
            t_s, s.stamp_ns / NS_PER_S, current_a, voltage_v, temp, est.soc
        ):
            self._apply_health()
        est, notices, report = self.runtime.update(
            t_s,
            s.stamp_ns,
            current_a,
            terminal_v,
            temperature_c,
            est,
            self.estimator,
            self._recalibrate,
        )
        events += [Event(Level(n.severity), n.message) for n in notices]
        cells = (
            self._cells_step(t_s, current_a, held_a, cell_voltage_v, est)
            if cell_voltage_v
            else None
        )
        self.last_cells = self._step_cells_estimate = cells
        self.last_estimate = self._step_estimate = est
        return StepResult(verdict, est, tuple(events), report, cells)

    def _accepted(self, t_s: float, t_prev: float | None, s: Sample, temperature_c: float) -> None:
        """Book-keeping for every accepted sample, filter step or not."""
        if t_prev is not None:
            self._count_missing(t_s - t_prev)
        self._t_sample_s = t_s
        self.samples_used += 1
        self.last_sample = (
            s  # the same values: no copy on most samples
            if temperature_c is s.temperature_c
            else Sample(
                s.stamp_ns, s.current_a, s.voltage_v, temperature_c, s.present, s.cell_voltage_v
            )
        )
        self.last_accept_steady_s = self._steady()
        self.revision += 1

    def _between_steps(
        self,
        t_s: float,
        t_prev: float | None,
        s: Sample,
        temperature_c: float,
        verdict: Verdict,
        events: list[Event],
    ) -> StepResult:
        """A sample between filter steps: the last step's SoC (and cells) moved by the charge
        counted since (its net charge at the charge efficiency, as the next step counts it),
        with the step's variance (``decimation.py``)."""
        assert self._decimator is not None and self._step_estimate is not None
        self._accepted(t_s, t_prev, s, temperature_c)
        q_as = self._decimator.charge_since_step_as
        eta = coulomb_efficiency(q_as, self.battery.coulomb_efficiency_charge)  # as the step will
        dq = eta * q_as / (SECONDS_PER_HOUR * self.estimator.capacity_ah)
        step = self._step_estimate
        est = Estimate(  # not dataclasses.replace: this runs on most samples at a high rate
            t_s,
            min(max(step.soc - dq, 0.0), 1.0),
            step.soc_var,
            step.x,
            step.p,
            step.state_names,
            math.nan,
            math.nan,
            math.nan,
            StepStatus.OK,  # not the step's: an INITIALIZED or GAP belongs to that sample
            False,
        )
        cells = self._step_cells_estimate
        if cells is not None and s.cell_voltage_v:
            cells = replace(
                cells,
                soc=np.clip(cells.soc - dq, 0.0, 1.0),
                usable_soc=min(max(cells.usable_soc - dq, 0.0), 1.0),
                usable_charge_soc=min(max(cells.usable_charge_soc - dq, 0.0), 1.0),
            )
        else:
            cells = None
        self.last_cells = cells
        self.last_estimate = est
        return StepResult(verdict, est, tuple(events), None, cells, filtered=False)

    # -- the OCV's hysteresis (models/hysteresis.py) -------------------------------------------
    def _start_branch(self) -> HysteresisState:
        """The hysteresis state a start without a saved one takes (``initial_branch``)."""
        b = self.config.initial_branch
        return HysteresisState.unknown() if b is None else HysteresisState(b, 0.0)

    def _advance_hysteresis(self, last_a: float, current_a: float, dt_s: float) -> None:
        """Move the hysteresis state over ``dt_s`` by the charge the estimators count over it
        (``TimePolicy.held_current_a``), at the file's capacity."""
        hyst, state = self.battery.hysteresis, self.hysteresis
        assert hyst is not None and state is not None
        held_a = self.estimator.time_policy.held_current_a(last_a, current_a, dt_s)
        self.hysteresis = hyst.step(
            state, held_a, dt_s, self.battery.capacity_ah, self.battery.coulomb_efficiency_charge
        )

    def _on_discharge_branch(
        self, voltage_v: float, cell_voltage_v: tuple[float, ...]
    ) -> tuple[float, tuple[float, ...]]:
        """The pack's (and each cell's) voltage referred to the discharge branch, on which
        the battery file's OCV and model were identified: the hysteresis' offset taken out
        (each cell's share of it, for the cells)."""
        hyst, state = self.battery.hysteresis, self.hysteresis
        assert hyst is not None and state is not None
        offset_v = hyst.offset_v(state)
        if cell_voltage_v:
            per_cell_v = offset_v / len(cell_voltage_v)
            cell_voltage_v = tuple(v - per_cell_v for v in cell_voltage_v)
        return voltage_v - offset_v, cell_voltage_v

    def _cells_step(
        self,
        t_s: float,
        current_a: float,
        held_a: float | None,
        cell_voltage_v: tuple[float, ...],
        est: Estimate,
    ) -> CellEstimate | None:
        """The cells on a filter step, about the pack's estimate of it (``cells/``)."""
        n = self.battery.cells_in_series
        if len(cell_voltage_v) != n or n < 2:
            self.cells_miscounted += 1
            return None
        if self.cells is None:
            self.cells = CellBank(self.battery, n)
            if self._resumed_cells is not None and self._resumed_cells[0].cells == n:
                saved, age_s = self._resumed_cells
                self.cells.filter.start_from(saved.x, saved.p, age_s)
            self._resumed_cells = None
        v = np.asarray(cell_voltage_v, dtype=float)
        return self.cells.step(t_s, current_a, v, est.soc, est.soc_var, held_a)

    def _recalibrate(self, soc: float, soc_std: float) -> Estimate:
        """Reset the SoC (the runtime monitor's FULL) and return the estimate it leaves."""
        if self.health is not None and self.health.full():
            self._apply_health()
        if self.hysteresis is not None:  # charged to full: on the charge branch
            self.hysteresis = HysteresisState(1.0, 0.0)
        self.reset_soc(soc, soc_std)
        last = self.estimator.last
        assert last is not None
        e = self.estimator
        return replace(
            last,
            soc=e.soc,
            soc_var=e.soc_var,
            x=np.array(e.x, dtype=float),
            p=np.array(e.p, dtype=float),
        )

    def _rejection_event(self, verdict: Verdict, s: Sample) -> Event:
        return Event(
            Level.WARNING,
            f"rejected sample ({verdict.value}): stamp {s.stamp_ns / NS_PER_S:.3f} s, "
            f"current {s.current_a:g} A (discharge +), voltage {s.voltage_v:g} V; "
            f"{self.gate.counts[verdict]} rejected for this reason so far",
            key=verdict.value,
        )

    # -- time base ----------------------------------------------------------------------------
    def _stale_long_enough(self) -> bool:
        """True once stale stamps persisted ``rebase_after_s`` (steady) and enough samples."""
        now = self._steady()
        if self._stale_since_s is None:
            self._stale_since_s, self._stale_run = now, 0
        self._stale_run += 1
        waited = now - self._stale_since_s
        return waited >= self.config.rebase_after_s and self._stale_run >= REBASE_MIN_SAMPLES

    def _jump_confirmed(self, stamp_ns: int) -> bool:
        """True once ``REBASE_MIN_SAMPLES`` jumped samples agree on one new time line."""
        run = self._jump_run
        tol_ns = round(self.gate.config.time_jump_s * NS_PER_S)
        if run and not 0 < stamp_ns - run[-1] <= tol_ns:
            run.clear()  # not the same time line as the previous jumped sample
        run.append(stamp_ns)
        return len(run) >= REBASE_MIN_SAMPLES

    def _rebase(self, stamp_ns: int, how: str) -> Event:
        """Continue the time line from a source whose stamps jumped (see the module docstring)."""
        newest = self.gate.newest_stamp_ns or stamp_ns
        last_t = self._t_sample_s
        now = self._steady()
        elapsed = now - (self.last_accept_steady_s if self.last_accept_steady_s else now)
        if last_t is not None and self.t0_ns is not None:
            self.t0_ns = stamp_ns - round((last_t + max(elapsed, 1e-3)) * NS_PER_S)
        self.gate.rebase()
        self._stale_since_s = None
        self._jump_run.clear()
        return Event(
            Level.ERROR,
            f"input stamps {how} by {abs(newest - stamp_ns) / NS_PER_S:.3f} s and stayed "
            f"there (source restarted or its clock changed?); continuing with the new stamps "
            f"({elapsed:.1f} s after the last accepted sample)",
        )

    def _count_missing(self, dt_s: float) -> None:
        """Add the whole sample periods missing in an accepted interval to ``missing_samples``."""
        if self._period_s is None:
            self._intervals.append(dt_s)
            if len(self._intervals) >= PERIOD_WINDOW:
                self._period_s = float(np.median(self._intervals))
                self._intervals.clear()
            return
        lost = round(dt_s / self._period_s) - 1
        if lost > 0:
            self.missing_samples += lost

    @property
    def sample_period_s(self) -> float | None:
        """The source's sample period (median of the first intervals), None until known."""
        return self._period_s

    # -- initialization and control -----------------------------------------------------------
    def soc_from_ocv(
        self, voltage_v: float, current_a: float = 0.0, temperature_c: float = math.nan
    ) -> tuple[float, float]:
        """The SoC (clipped to [0, 1]) and its std read from ``voltage_v``, measured at
        ``current_a`` and ``temperature_c``, as an OCV, through the battery's model
        (``TheveninModel.soc_at_terminal_voltage``: the drop the current causes and the
        temperature's offset taken out, the relaxation no one knows at a start added to the
        std)."""
        std_v = self.config.ocv_voltage_std_v
        hyst, state = self.battery.hysteresis, self.hysteresis
        if hyst is not None and state is not None:  # read on the discharge branch
            voltage_v, _ = self._on_discharge_branch(voltage_v, ())
            std_v = math.hypot(std_v, hyst.std_v(state))
        # The estimator's own model where it has one: it carries the learned health (health/).
        # Else the file's, built here: a start or a reset reads it, the samples never do.
        model = getattr(self.estimator, "model", None)
        if not isinstance(model, TheveninModel):
            model = self.battery.thevenin_model()
        temp = None if math.isnan(temperature_c) else temperature_c
        soc, std = model.soc_at_terminal_voltage(voltage_v, current_a, std_v, temp)
        return min(max(soc, 0.0), 1.0), max(std, MIN_INIT_SOC_STD)

    def _initialize(self, s: Sample) -> Event:
        """Apply ``initial_soc`` on the first accepted sample."""
        init = self._initial
        if not isinstance(init, str):
            return Event(Level.INFO, f"initial SoC {float(init):.4f} (given)")
        reason = ""
        if init == "resume":
            if self._resume is None:
                reason = "no state file"
            else:
                decision = self._resume(s.stamp_ns / NS_PER_S)
                if decision.state is not None:
                    st = decision.state
                    self.estimator.reset_soc(st.soc, max(math.sqrt(st.soc_var), 1e-6))
                    if self.hysteresis is not None and st.hysteresis is not None:
                        self.hysteresis = st.hysteresis
                    if st.cells is not None:
                        self._resumed_cells = (st.cells, s.stamp_ns / NS_PER_S - st.stamp_s)
                    return Event(Level.INFO, decision.reason)
                reason = decision.reason
        soc, std = self.soc_from_ocv(s.voltage_v, s.current_a, s.temperature_c)
        self.estimator.reset_soc(soc, std)
        start = f"SoC {soc:.4f} (std {std:.4f}) from the OCV at {s.voltage_v:.3f} V"
        if init == "resume":
            return Event(Level.WARNING, f"initial_soc=resume: {reason}; initialized {start}")
        return Event(Level.INFO, f"initial_soc=ocv: {start}")

    @property
    def started(self) -> bool:
        """True once a sample was accepted (the time base and the initial SoC are set)."""
        return self.t0_ns is not None

    def reset_soc(self, soc: float, soc_std: float) -> None:
        """Reset the SoC (keeps the time base); before the first sample it replaces
        ``initial_soc``."""
        self.estimator.reset_soc(soc, soc_std)
        if not self.started:
            self._initial = soc
        self.revision += 1

    def reset_from_ocv(self) -> tuple[float, float, Sample]:
        """Reset the SoC from the last accepted voltage read as an OCV; (soc, std, sample).

        Raises ``LookupError`` before any sample was accepted.
        """
        last = self.last_sample
        if last is None:
            raise LookupError("no accepted sample yet: no voltage to read as an OCV")
        soc, std = self.soc_from_ocv(last.voltage_v, last.current_a, last.temperature_c)
        self.estimator.reset_soc(soc, std)
        self.revision += 1
        return soc, std, last

    def prepare_estimator(self, name: str) -> Estimator:
        """A new estimator ``name`` for this battery (``ValueError`` for an unknown name)."""
        return make_estimator(name, self.battery, 0.5, 0.1)

    def switch_estimator(self, name: str, prepared: Estimator | None = None) -> Event:
        """Continue with estimator ``name`` from the current SoC, variance, time and current."""
        new = prepared
        if new is None or new.name != PRESETS.get(name, name):
            new = self.prepare_estimator(name)
        old = self.estimator
        soc, var = old.soc, old.published_soc_var
        new.start_from(old.t_last_s, soc, var, old.current_last_a)
        self.estimator = new
        self._apply_health()
        old_name, self.estimator_name = self.estimator_name, name
        self.revision += 1
        return Event(
            Level.INFO,
            f"switched estimator {old_name} -> {name} at SoC {soc:.4f} (std {math.sqrt(var):.4f})",
        )

    # -- health -------------------------------------------------------------------------------
    def _apply_health(self) -> None:
        """Hand what the health monitor learned to the estimator (a no-op on the file's values:
        an estimator on the file's capacity and factor 1 computes exactly as without)."""
        if self.health is None:
            return
        learned = self.health.learned()
        factor = getattr(getattr(self.estimator, "model", None), "r0_factor", 1.0)
        if learned != (self.estimator.capacity_ah, factor):
            self.estimator.set_health(*learned)

    def finish(self) -> None:
        """The run ends (a replay's last sample, a shutdown): a rest still going is read."""
        if self.health is not None and self.health.finish():
            self._apply_health()
            self.revision += 1

    def new_pack(self, serial_number: str = "") -> None:
        """Another pack (a new serial number, the reset service): health from the file again,
        and the cells' priors."""
        if self.cells is not None:
            self.cells.reset()
        self._resumed_cells = None
        if self.hysteresis is not None:
            self.hysteresis = HysteresisState.unknown()
        if self.health is None:
            return
        self.health.reset(serial_number)
        self.estimator.set_health(self.battery.capacity_ah, 1.0)
        self.revision += 1

    def pack_serial(self, serial_number: str) -> Event | None:
        """The input's ``serial_number``: the health's pack takes a first one; another one
        than the health's is another pack (:meth:`new_pack`, and the event says so), at once
        before the first accepted sample (the pack the robot booted with), else once it has
        come on :data:`SERIAL_CONFIRM_SAMPLES` samples in a row (until then each is counted in
        :attr:`serial_unconfirmed`)."""
        h = self.health
        if h is None or not serial_number or serial_number == h.serial_number:
            self._serial_run = ("", 0)
            return None
        if not h.serial_number:
            h.serial_number = serial_number
            self.revision += 1
            return None
        if self.started:
            seen, run = self._serial_run
            run = run + 1 if seen == serial_number else 1
            self._serial_run = (serial_number, run)
            if run < SERIAL_CONFIRM_SAMPLES:
                self.serial_unconfirmed += 1
                return None
        self._serial_run = ("", 0)
        old = h.serial_number
        self.new_pack(serial_number)
        return Event(
            Level.WARNING,
            f"pack serial number {old!r} -> {serial_number!r}: another pack, its health "
            "starts from the battery file's values",
        )

    def _recover(self, exc: Exception) -> Event:
        """Rebuild the estimator from its last good estimate after an exception in step()."""
        old = self.estimator
        last = self.last_estimate
        soc = last.soc if last else 0.5
        var = last.soc_var if last else 0.25
        new = make_estimator(self.estimator_name, self.battery, soc, max(math.sqrt(var), 1e-3))
        new.start_from(old.t_last_s, soc, var, old.current_last_a)
        self.estimator = new
        self._apply_health()
        return Event(
            Level.ERROR,
            f"{self.estimator_name} failed on a sample ({type(exc).__name__}: {exc}); "
            "restarting it from its last good SoC",
            key="estimator_error",
        )

    # -- state --------------------------------------------------------------------------------
    @property
    def soc(self) -> float:
        """The SoC now."""
        return self.estimator.soc

    @property
    def soc_var(self) -> float:
        """The SoC variance now, at most ``MAX_SOC_VAR`` (what a state file may hold)."""
        return min(self.estimator.published_soc_var, MAX_SOC_VAR)

    @property
    def usable_soc(self) -> float:
        """The SoC ``BatteryState.percentage`` publishes: the cells' usable discharge SoC when
        the last accepted sample carried every cell's voltage, else the pack's last estimate."""
        if self.last_cells is not None:
            return self.last_cells.usable_soc
        if self.last_estimate is not None:
            return self.last_estimate.soc
        return self.soc

    def saved_state(self) -> SavedState | None:
        """What a state file keeps now (``persistence.py``), the learned health with it; None
        before the first accepted sample."""
        last = self.last_sample
        if last is None:
            return None
        return SavedState(
            soc=self.soc,
            soc_var=self.soc_var,
            stamp_s=last.stamp_ns / NS_PER_S,
            estimator=self.estimator_name,
            battery=self.battery.name,
            health=None if self.health is None else self.health.state(),
            cells=None
            if self.cells is None
            else CellsState.of_arrays(self.cells.filter.x, self.cells.filter.p),
            hysteresis=self.hysteresis,
        )

    def carried_forward(self, now_steady_s: float) -> tuple[float, float, float]:
        """The last SoC carried over a silence of the input: (SoC, std, silent seconds).

        The SoC stays; its variance grows as over an estimator's gap (``estimators/base.py``):
        ``(gap_current_std_a * silent_s / (3600 Q))^2`` is added, up to ``MAX_SOC_VAR``, so
        the std keeps growing and is never NaN. (SoC, std) of the estimator, silent 0, before
        any accepted sample.
        """
        soc, var = self.soc, self.soc_var
        if self.last_accept_steady_s is None:
            return soc, math.sqrt(var), 0.0
        silent = max(now_steady_s - self.last_accept_steady_s, 0.0)
        gap_std = self.estimator.time_policy.gap_current_std_a
        grown = gap_std * silent / (SECONDS_PER_HOUR * self.estimator.capacity_ah)
        return soc, math.sqrt(min(var + grown * grown, MAX_SOC_VAR)), silent
