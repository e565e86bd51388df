"""The runtime monitor: the tracker's companion that answers what the robot asks next.

The :class:`~soc_estimator_ros.tracking.Tracker` feeds it every accepted sample with its
estimate (so the node, ``soc_replay`` and ``soc_replay --live`` see the same), and it keeps:

* the load window (``prediction.PowerWindow``) and the model's own RC branch voltages and
  surface lag, run open-loop on the current (used when the estimator has none of its own);
* the charge phase and FULL (``charging.py``); on FULL it asks the tracker to recalibrate the
  SoC to 1;
* the low-battery level (``levels.py``);
* every ``predict_period_s`` of sample time (0: never; ``soc_replay`` without CSV or plot),
  a :class:`RuntimeReport`: time to empty and its std, time to full, state of power. Its
  inputs are taken on the sample it is due (:class:`PredictionInput`); it is computed there,
  or, ``deferred`` (the node), by :meth:`RuntimeMonitor.flush` where no SoC output waits for
  it (after that sample's output, or on a later sample without one: node/output_rate.py):
  the same numbers, and no SoC message a second waits 0.5-1 ms for it (docs/benchmarks.md,
  "Where the time goes in the node").

It never changes the estimate except on FULL.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..estimators.base import Estimate
from ..messages import CHARGING_CURRENT_A, IDLE_CURRENT_A
from ..params import BatteryParams, LevelSettings
from .charging import FULL_SOC_STD, ChargeMonitor, ChargePhase, ChargeSpec
from .levels import BatteryLevel, LevelMonitor, LevelThresholds
from .prediction import (
    LoadForecast,
    PackState,
    PowerWindow,
    TimeToEmpty,
    state_of_power,
    time_to_empty,
    time_to_full,
)

#: Blocks of the load window (its spread is the std of their means).
WINDOW_BLOCKS = 5


@dataclass(frozen=True)
class RuntimeConfig:
    """How the monitor runs (the node's parameters; ``soc_replay`` uses the defaults).

    Attributes:
        window_s: the load window (s).
        mission_power_w: a load power the robot sets (W); 0 = the window's mean.
        predict_period_s: sample time between predictions (s); 0 = no predictions.
        idle_current_a: |current| at or below which the pack is idle (A).
        charging_current_a: charge current above which it is charging (A).
        levels: level overrides (None entries: the battery file's, else the rule).
        deferred: a due prediction waits for :meth:`RuntimeMonitor.flush` (module docstring).
    """

    window_s: float = 300.0
    mission_power_w: float = 0.0
    predict_period_s: float = 1.0
    idle_current_a: float = IDLE_CURRENT_A
    charging_current_a: float = CHARGING_CURRENT_A
    levels: LevelSettings = field(default_factory=LevelSettings)
    deferred: bool = False


@dataclass(frozen=True)
class PredictionInput:
    """What a prediction reads, taken on the sample it is due (floats and frozen values: the
    estimator and the monitor may move on before it is computed)."""

    stamp_ns: int
    t_s: float
    state: PackState
    forecast: LoadForecast
    min_power_w: float
    level: BatteryLevel
    phase: ChargePhase
    charge_current_a: float
    charge_voltage_v: float
    taper_current_a: float
    in_cv: bool
    hold_left_s: float


@dataclass(frozen=True)
class RuntimeReport:
    """One prediction (``messages.RUNTIME_FIELDS`` in order, plus what explains it)."""

    stamp_ns: int
    t_s: float
    soc: float
    soc_std: float
    time_to_empty_s: float
    time_to_empty_std_s: float
    time_to_full_s: float
    max_discharge_current_10s_a: float
    max_discharge_current_60s_a: float
    max_charge_current_10s_a: float
    max_charge_current_60s_a: float
    level: BatteryLevel
    load_power_w: float
    load_power_std_w: float
    load_source: str
    phase: ChargePhase
    note: str = ""

    def fields(self) -> dict[str, float]:
        """{label: value} for ``messages.runtime_vector``."""
        return {
            "stamp_s": self.stamp_ns * 1e-9,
            "time_to_empty_s": self.time_to_empty_s,
            "time_to_empty_std_s": self.time_to_empty_std_s,
            "time_to_full_s": self.time_to_full_s,
            "max_discharge_current_10s_a": self.max_discharge_current_10s_a,
            "max_discharge_current_60s_a": self.max_discharge_current_60s_a,
            "max_charge_current_10s_a": self.max_charge_current_10s_a,
            "max_charge_current_60s_a": self.max_charge_current_60s_a,
            "level": float(int(self.level)),
            "load_power_w": self.load_power_w,
            "load_power_std_w": self.load_power_std_w,
        }


@dataclass(frozen=True)
class Notice:
    """Something to log: ``severity`` "info", "warning" or "error" (the tracker's Level)."""

    severity: str
    message: str


Recalibrate = Callable[[float, float], Estimate]


class RuntimeMonitor:
    """Levels, charge state and predictions for one tracker (module docstring)."""

    def __init__(self, battery: BatteryParams, config: RuntimeConfig | None = None) -> None:
        self.battery = battery
        self.config = config or RuntimeConfig()
        self.model = battery.thevenin_model()
        self.thresholds = LevelThresholds.resolve(
            battery.limits, battery.levels, self.config.levels
        )
        self.levels = LevelMonitor(self.thresholds)
        self.charge = ChargeMonitor(
            ChargeSpec.resolve(battery, self.config.charging_current_a, self.config.idle_current_a)
        )
        self.window = PowerWindow(self.config.window_s, WINDOW_BLOCKS)
        self.mission_power_w = self.config.mission_power_w
        self.report: RuntimeReport | None = None
        self._next_predict_s: float | None = None
        self._due: PredictionInput | None = None
        self._branch_v = np.zeros(self.model.n_rc)
        self._surface_z = self.model.surface_rest()
        self._last: tuple[float, float, float, float | None] | None = None  # t, I, SoC, T

    # -- run-time settings --------------------------------------------------------------------
    @property
    def predicting(self) -> bool:
        """True when predictions are made (``predict_period_s`` > 0)."""
        return self.config.predict_period_s > 0.0

    @property
    def level(self) -> BatteryLevel:
        """The level now (OK before the first estimate)."""
        return self.levels.level if self.levels.level is not None else BatteryLevel.OK

    @property
    def full(self) -> bool:
        """FULL holds (``power_supply_status``)."""
        return self.charge.full

    def set_levels(self, overrides: LevelSettings) -> LevelThresholds:
        """New level overrides (``ValueError`` if they break the order); applied at once."""
        th = LevelThresholds.resolve(self.battery.limits, self.battery.levels, overrides)
        self.thresholds = th
        self.levels.reset(th)
        return th

    def set_mission_power(self, power_w: float) -> None:
        """The robot's mission power (W); 0 = the window's mean."""
        self.mission_power_w = float(power_w)

    def set_idle_current(self, idle_current_a: float) -> None:
        """A new idle dead band (A)."""
        spec = self.charge.spec
        self.charge.spec = ChargeSpec(
            spec.voltage_v,
            spec.voltage_source,
            spec.voltage_tolerance_v,
            spec.taper_current_a,
            spec.hold_s,
            spec.charging_current_a,
            float(idle_current_a),
        )

    # -- per sample ---------------------------------------------------------------------------
    def update(
        self,
        t_s: float,
        stamp_ns: int,
        current_a: float,
        voltage_v: float,
        temperature_c: float,
        est: Estimate,
        estimator: Any,
        recalibrate: Recalibrate,
    ) -> tuple[Estimate, list[Notice], RuntimeReport | None]:
        """One accepted sample and its estimate (core sign; ``t_s`` the tracker's time).

        Returns the estimate (a new one after a FULL recalibration), what to log, and a new
        report when one was due (``deferred``: None, the report comes from :meth:`flush`).
        """
        notices: list[Notice] = []
        temp = temperature_c if math.isfinite(temperature_c) else None
        if self.predicting:
            self._track_branches(t_s, est, estimator)
        change = self.charge.update(t_s, current_a, voltage_v)
        if change is not None:
            if change.kind == "full":
                old = est.soc
                est = recalibrate(1.0, FULL_SOC_STD)
                notices.append(
                    Notice(
                        "info",
                        f"{change.message}: SoC recalibrated {old:.4f} -> {est.soc:.4f} "
                        f"(std {FULL_SOC_STD:g}); status FULL until the pack discharges",
                    )
                )
            else:
                notices.append(Notice("info", change.message))
        self.window.add(t_s, current_a * voltage_v)
        level_change = self.levels.update(t_s, est.soc)
        if level_change is not None and not (
            level_change.old is None and level_change.new is BatteryLevel.OK
        ):
            sev = {
                BatteryLevel.OK: "info",
                BatteryLevel.WARN: "warning",
                BatteryLevel.CRITICAL: "warning",
                BatteryLevel.EMERGENCY: "error",
            }[level_change.new]
            if level_change.old is not None and level_change.new < level_change.old:
                sev = "info"
            notices.append(Notice(sev, level_change.describe(self.thresholds)))
        self._last = (t_s, current_a, est.soc, temp)
        report = None
        if self.predicting and (self._next_predict_s is None or t_s >= self._next_predict_s):
            self._next_predict_s = t_s + self.config.predict_period_s
            self._due = self.prediction_input(stamp_ns, t_s, est, estimator, voltage_v, temp)
            if not self.config.deferred:
                report = self.flush()
        return est, notices, report

    def flush(self) -> RuntimeReport | None:
        """The prediction due and not yet computed, from the inputs taken on its sample (kept
        as :attr:`report`); None when none is due."""
        due, self._due = self._due, None
        if due is None:
            return None
        self.report = self.report_from(due)
        return self.report

    def _estimator_branches(self, est: Estimate) -> np.ndarray | None:
        """The estimator's RC branch voltages ``v1_v..vn_v`` by name, None without them."""
        names = est.state_names
        wanted = [f"v{k + 1}_v" for k in range(self.model.n_rc)]
        if not all(w in names for w in wanted):
            return None
        return np.array([est.x[names.index(w)] for w in wanted], dtype=float)

    def _estimator_surface(self, estimator: Any) -> tuple[float, ...] | None:
        """The estimator's surface-lag modes (``z_modes``), None without them."""
        z = getattr(estimator, "z_modes", None)
        if isinstance(z, tuple) and len(z) == len(self._surface_z):
            return tuple(float(v) for v in z)
        return None

    def _track_branches(self, t_s: float, est: Estimate, estimator: Any) -> None:
        """The monitor's own branch voltages and surface lag: the estimator's where it has
        them, else the model run open-loop over the last interval with the previous sample's
        current held (the estimators' zero-order hold). Kept either way, so a switch to an
        estimator without them continues from where the last one left off."""
        own = self._estimator_branches(est)
        z = self._estimator_surface(estimator)
        if (own is None or z is None) and self._last is not None:
            t_prev, i_prev, soc_prev, temp = self._last
            dt = t_s - t_prev
            if dt > 0.0:
                if own is None:
                    x = np.concatenate([[soc_prev], self._branch_v])
                    own = self.model.step(x, i_prev, dt, temp)[1:]
                if z is None:
                    z = self.model.surface_step(self._surface_z, i_prev, dt, soc_prev)
        if own is not None:
            self._branch_v = own
        if z is not None:
            self._surface_z = z

    def pack_state(self, est: Estimate, estimator: Any, temperature_c: float | None) -> PackState:
        """The state the predictions read: the estimator's branch voltages, surface lag,
        model-error voltage and resistance error where it has them (by name), else the
        monitor's own (no model error); the stds of those the estimator has, from its
        covariance (the state of power's margin)."""
        names = est.state_names
        p = np.atleast_2d(np.asarray(est.p, dtype=float))

        def std(name: str) -> float:
            k = names.index(name) if name in names else -1
            return math.sqrt(max(float(p[k, k]), 0.0)) if 0 <= k < p.shape[0] else 0.0

        branch = self._estimator_branches(est)
        branch_std: tuple[float, ...] = ()
        if branch is None:
            branch = self._branch_v
        else:
            branch_std = tuple(std(f"v{k + 1}_v") for k in range(self.model.n_rc))
        z = self._estimator_surface(estimator)
        if z is None:
            z = self._surface_z
        bias = float(est.x[names.index("bias_v")]) if "bias_v" in names else 0.0
        r_delta = float(est.x[names.index("r_delta_ohm")]) if "r_delta_ohm" in names else 0.0
        return PackState(
            soc=est.soc,
            soc_std=est.soc_std,
            branch_v=tuple(float(v) for v in branch),
            surface_z=tuple(float(v) for v in z),
            bias_v=bias,
            r_delta_ohm=r_delta,
            temperature_c=temperature_c,
            branch_std_v=branch_std,
            bias_std_v=std("bias_v"),
            r_delta_std_ohm=std("r_delta_ohm"),
        )

    def forecast(self) -> LoadForecast:
        """The load the time to empty assumes: the mission power if set, else the window."""
        if self.mission_power_w > 0.0:
            return LoadForecast(self.mission_power_w, source="mission")
        return self.window.forecast()

    def prediction_input(
        self,
        stamp_ns: int,
        t_s: float,
        est: Estimate,
        estimator: Any,
        voltage_v: float,
        temperature_c: float | None,
    ) -> PredictionInput:
        """What a prediction for the present state reads (:class:`PredictionInput`)."""
        state = self.pack_state(est, estimator, temperature_c)
        charge = self.charge
        return PredictionInput(
            stamp_ns=stamp_ns,
            t_s=t_s,
            state=state,
            forecast=self.forecast(),
            min_power_w=charge.spec.idle_current_a * self.model.ocv.ocv(state.soc),
            level=self.level,
            phase=charge.phase,
            charge_current_a=max(-charge.current_lp_a, charge.spec.taper_current_a),
            charge_voltage_v=charge.spec.voltage_v,
            taper_current_a=charge.spec.taper_current_a,
            in_cv=charge.in_cv_band(voltage_v),
            hold_left_s=charge.hold_left_s,
        )

    def report_from(self, due: PredictionInput) -> RuntimeReport:
        """The :class:`RuntimeReport` of ``due``: time to empty, state of power, time to full."""
        state, forecast = due.state, due.forecast
        lim = self.battery.limits
        tte: TimeToEmpty = time_to_empty(self.model, state, lim.soc_min, forecast, due.min_power_w)
        sop = state_of_power(self.model, lim, state)
        ttf = math.nan
        if due.phase.full:
            ttf = 0.0
        elif due.phase.charging:
            ttf = time_to_full(
                self.model,
                state,
                due.charge_current_a,
                due.charge_voltage_v,
                due.taper_current_a,
                in_cv=due.in_cv,
                hold_left_s=due.hold_left_s,
            )
        return RuntimeReport(
            stamp_ns=due.stamp_ns,
            t_s=due.t_s,
            soc=state.soc,
            soc_std=state.soc_std,
            time_to_empty_s=tte.time_s,
            time_to_empty_std_s=tte.std_s,
            time_to_full_s=ttf,
            max_discharge_current_10s_a=sop.max_discharge_current_10s_a,
            max_discharge_current_60s_a=sop.max_discharge_current_60s_a,
            max_charge_current_10s_a=sop.max_charge_current_10s_a,
            max_charge_current_60s_a=sop.max_charge_current_60s_a,
            level=due.level,
            load_power_w=forecast.power_w,
            load_power_std_w=forecast.power_std_w(tte.time_s),
            load_source=forecast.source,
            phase=due.phase,
            note=tte.note,
        )
