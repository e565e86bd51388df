"""The node's ``/diagnostics`` status, computed from a tracker without ROS.

One status per report (1 Hz): level OK / WARN / ERROR, a message joining every problem, and
key-value pairs (the estimate, the counts per rejection reason, ...). Problems:

* WARN: no sample accepted yet;
* ERROR: none accepted for ``stale_timeout_s`` (stale input: the bridge went silent, as
  Husarion's battery node reports a silent source); the SoC is then the last one carried
  forward and its std grows over the silence (``Tracker.carried_forward``);
* WARN: samples rejected since the last report; temperatures ignored since the last report
  (implausible readings, ``tracking/gate.py``); samples missing from the stamps since the last
  report (input lost before the callback: queue overflow, a link dropping messages);
* WARN / ERROR: the low-battery level (``runtime/levels.py``) WARN / CRITICAL or EMERGENCY;
* ERROR: pack voltage above or below the battery's voltage limits;
* WARN: extrapolating: the temperature lies outside the range the battery file's model was
  identified at (plus its margin; the model's resistances then follow Arrhenius, and the hybrid
  weighs the voltage less);
* WARN / ERROR: with health learned (``learn_health``), the state of health below the battery
  file's ``health.soh_warn`` / ``health.soh_dead`` (seed 001's end of life, 0.6), read on the
  applied SOH (``HealthMonitor.applied_soh``: the learned capacity once it differs from the
  file's by its ``APPLY_SIGMA`` std, the value the estimator and ``BatteryState`` use);
* with cell voltages (``cells/``): WARN / ERROR for the cell imbalance (max - min cell SoC)
  and the cell voltage spread beyond the battery file's ``cells:`` thresholds, ERROR for a
  cell over or under its voltage limits, WARN for cell readings rejected since the last report;
* WARN: the hybrid's guard (``estimators/guard.py``) weighs its voltage model below
  :data:`MODEL_WEIGHT_WARN`: the filter and the charge count disagree beyond the count's error
  budget, and the published SoC follows the count;
* WARN: the hybrid's voltage model is off by a persistent error under load (item 11: the
  innovation averaged over a minute beyond what the filter's uncertainty and the noise
  explain): the voltage counts as one reading a minute and the count does not follow it.

The values hold the estimate, the counts, the level and its thresholds, the charge phase, and
the runtime monitor's latest prediction under ``battery/runtime``'s labels.

:class:`Diagnostics` keeps the counts of the previous report (what "since the last report"
compares with); ``node/ros_node.py`` turns a :class:`Report` into a ``DiagnosticStatus``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from enum import IntEnum
from typing import Any

from ..estimators.guard import Guarded
from ..estimators.hybrid import Hybrid
from ..messages import RUNTIME_FIELDS
from ..runtime import BatteryLevel
from ..tracking import REJECTIONS, Tracker
from ..units import NS_PER_S, ros_current_from_core

#: The SoC std below which diagnostics report ``converged: true``.
CONVERGED_SOC_STD = 0.02
#: The guard's model weight below which diagnostics warn (the count outweighs the model).
MODEL_WEIGHT_WARN = 0.5


class Level(IntEnum):
    """``diagnostic_msgs/DiagnosticStatus`` levels."""

    OK = 0
    WARN = 1
    ERROR = 2


@dataclass(frozen=True)
class Report:
    """One diagnostic status: level, message and key-value pairs (values as text)."""

    level: Level
    message: str
    values: list[tuple[str, str]]


def _text(value: Any) -> str:
    return f"{value:.6g}" if isinstance(value, float) else str(value)


@dataclass
class Diagnostics:
    """Builds reports for one tracker; remembers what the previous report counted."""

    tracker: Tracker
    battery_file: str
    start_steady_s: float
    _seen: dict[str, int] = field(default_factory=dict)

    def _new_since_last(self, key: str, count: int) -> int:
        new = count - self._seen.get(key, 0)
        self._seen[key] = count
        return new

    def report(
        self,
        now_steady_s: float,
        stale_timeout_s: float,
        extra: list[tuple[str, Any]] | None = None,
    ) -> Report:
        """The status now; ``extra`` key-values."""
        tr = self.tracker
        hybrid = tr.estimator if isinstance(tr.estimator, Hybrid) else None
        guarded = hybrid.guarded() if hybrid is not None and tr.last_estimate is not None else None
        outside_c = self._outside_c()
        stale, problems = self._input_problems(now_steady_s, stale_timeout_s)
        problems += self._battery_problems()
        problems += self._model_problems(outside_c, hybrid, guarded)
        cell_problems, cell_values = self._cells()
        problems += cell_problems
        problems += self._health_problems()
        level = max((lvl for lvl, _ in problems), default=Level.OK)
        message = "; ".join(m for _, m in problems) or "OK"
        values = self._estimate_values(now_steady_s, stale, outside_c)
        values += self._runtime_values()
        values += self._estimator_values(hybrid, guarded)
        values += self._health_values()
        values += cell_values
        values += extra or []
        return Report(level, message, [(k, _text(v)) for k, v in values])

    def _outside_c(self) -> float:
        """How far (degC) the last sample's temperature lies outside the model's identified
        range (0 inside, or for a model without one)."""
        tr = self.tracker
        extrapolation_c = getattr(getattr(tr.estimator, "model", None), "extrapolation_c", None)
        if tr.last_sample is None or extrapolation_c is None:
            return 0.0
        return float(extrapolation_c(tr.last_sample.temperature_c))

    def _input_problems(
        self, now_steady_s: float, stale_timeout_s: float
    ) -> tuple[bool, list[tuple[Level, str]]]:
        """Whether the input is stale, and the input's problems: none accepted yet or for too
        long, rejections, ignored temperatures and missing samples since the last report."""
        tr = self.tracker
        problems: list[tuple[Level, str]] = []
        stale = False
        if tr.last_accept_steady_s is None:
            if now_steady_s - self.start_steady_s > stale_timeout_s:
                problems.append((Level.WARN, "no input sample accepted yet"))
        elif now_steady_s - tr.last_accept_steady_s > stale_timeout_s:
            stale = True
            silent = now_steady_s - tr.last_accept_steady_s
            problems.append((Level.ERROR, f"stale input: no sample for {silent:.1f} s"))
        gate = tr.gate
        for key, count, what in (
            ("rejected", gate.rejected_count, "samples rejected recently"),
            ("temperature", gate.temperature_ignored, "implausible temperatures ignored recently"),
            ("missing", tr.missing_samples, "samples missing from the input stamps recently"),
        ):
            new = self._new_since_last(key, count)
            if new > 0:
                problems.append((Level.WARN, f"{new} {what}"))
        return stale, problems

    def _battery_problems(self) -> list[tuple[Level, str]]:
        """The low-battery level and the pack voltage against the limits."""
        tr = self.tracker
        est, last, rt = tr.last_estimate, tr.last_sample, tr.runtime
        if est is None or last is None:
            return []
        problems: list[tuple[Level, str]] = []
        battery_level = rt.level
        if battery_level is not BatteryLevel.OK:
            severity = Level.WARN if battery_level is BatteryLevel.WARN else Level.ERROR
            problems.append(
                (
                    severity,
                    f"low SoC {est.soc:.3f}: level {battery_level.label} "
                    f"(below {rt.thresholds.threshold(battery_level):.3f})",
                )
            )
        v, lim = last.voltage_v, tr.battery.limits
        if v > lim.voltage_max_v:
            problems.append((Level.ERROR, f"overvoltage {v:.3f} V > {lim.voltage_max_v:g} V"))
        elif v < lim.voltage_min_v:
            problems.append((Level.ERROR, f"undervoltage {v:.3f} V < {lim.voltage_min_v:g} V"))
        return problems

    @staticmethod
    def _model_problems(
        outside_c: float, hybrid: Hybrid | None, guarded: Guarded | None
    ) -> list[tuple[Level, str]]:
        """The voltage model: outside its temperatures, weighed out by the guard, off by a
        persistent error under load."""
        problems: list[tuple[Level, str]] = []
        if outside_c != 0.0:
            where = "below" if outside_c < 0 else "above"
            problems.append(
                (
                    Level.WARN,
                    f"extrapolating: {abs(outside_c):.1f} degC {where} the identified "
                    "temperature range",
                )
            )
        if guarded is not None and guarded.model_weight < MODEL_WEIGHT_WARN:
            problems.append(
                (
                    Level.WARN,
                    f"voltage model weighed out: weight {guarded.model_weight:.2f}, the SoC "
                    "follows the charge count",
                )
            )
        if hybrid is not None and hybrid.persistent_error:
            problems.append(
                (
                    Level.WARN,
                    f"voltage model off by {1000.0 * hybrid.innovation_avg_v:+.0f} mV under "
                    "load for a minute: read as one reading a minute",
                )
            )
        return problems

    def _health_problems(self) -> list[tuple[Level, str]]:
        """The applied state of health against the battery file's thresholds."""
        health = self.tracker.health
        if health is None:
            return []
        soh, hs = health.applied_soh, self.tracker.battery.health
        if soh >= hs.soh_warn:
            return []
        severity = Level.ERROR if soh < hs.soh_dead else Level.WARN
        limit = hs.soh_dead if soh < hs.soh_dead else hs.soh_warn
        return [(severity, f"state of health {soh:.2f} below {limit:g}")]

    def _estimate_values(
        self, now_steady_s: float, stale: bool, outside_c: float
    ) -> list[tuple[str, Any]]:
        """The estimate (carried forward while stale), the last sample and the counts."""
        tr = self.tracker
        est, last, gate = tr.last_estimate, tr.last_sample, tr.gate
        nan = math.nan
        period = tr.sample_period_s
        soc, soc_std, silent_s = tr.carried_forward(now_steady_s)
        if est is None:
            soc = soc_std = nan
        elif not stale:
            soc, soc_std = est.soc, est.soc_std
        return [
            ("estimator", tr.estimator_name),
            ("battery", tr.battery.name),
            ("battery_file", self.battery_file),
            ("soc", soc),
            ("soc_std", soc_std),
            ("stale", str(stale).lower()),
            ("silent_s", silent_s),
            ("nis", est.nis if est else nan),
            ("innovation_v", est.innovation_v if est else nan),
            ("voltage_v", last.voltage_v if last else nan),
            ("current_a", ros_current_from_core(last.current_a) if last else nan),
            ("temperature_c", last.temperature_c if last else nan),
            ("samples_accepted", tr.samples_used),
            *((f"rejected_{v.value}", gate.counts[v]) for v in REJECTIONS),
            ("temperature_ignored", gate.temperature_ignored),
            ("samples_missing", tr.missing_samples),
            ("extrapolating_c", outside_c),
            ("sample_period_s", period if period is not None else nan),
            ("converged", str(bool(est and est.soc_std < CONVERGED_SOC_STD)).lower()),
            ("clip_count", tr.estimator.clip_count),
            (
                "last_stamp_s",
                f"{last.stamp_ns / NS_PER_S:.3f}" if last is not None else "none",
            ),
        ]

    def _runtime_values(self) -> list[tuple[str, Any]]:
        """The runtime monitor's latest prediction, the level now and the charge phase."""
        rt = self.tracker.runtime
        th = rt.thresholds
        predicted = rt.report.fields() if rt.report is not None else {}
        predicted["level"] = int(rt.level)  # the level now, not at the last prediction
        values: list[tuple[str, Any]] = [
            (k, predicted.get(k, math.nan)) for k in RUNTIME_FIELDS if k != "stamp_s"
        ]
        return values + [
            ("level_name", rt.level.label),
            ("level_warn_soc", th.warn_soc),
            ("level_critical_soc", th.critical_soc),
            ("level_emergency_soc", th.emergency_soc),
            ("charge_phase", rt.charge.phase.value),
            ("charge_voltage_v", rt.charge.spec.voltage_v),
        ]

    def _estimator_values(
        self, hybrid: Hybrid | None, guarded: Guarded | None
    ) -> list[tuple[str, Any]]:
        """The estimator's own: NIS average, OCV corrections, the hybrid's guard and grid."""
        estimator = self.tracker.estimator
        values: list[tuple[str, Any]] = []
        if hasattr(estimator, "nis_avg"):
            values.append(("nis_avg", float(estimator.nis_avg)))
        if hasattr(estimator, "ocv_corrections"):
            values.append(("ocv_corrections", int(estimator.ocv_corrections)))
        if hybrid is not None and guarded is not None:
            charge_count = hybrid.count
            values += [
                ("model_weight", guarded.model_weight),
                ("soc_model", float(hybrid.x[hybrid.soc_index])),
                ("soc_count", charge_count.soc),
                ("soc_count_std", math.sqrt(charge_count.var)),
                ("innovation_avg_v", hybrid.innovation_avg_v),
                ("model_error_persistent", str(hybrid.persistent_error).lower()),
                # item 12: the SoC's grid posterior, nan once the SoC is no longer wide
                (
                    "soc_grid_std",
                    math.nan if hybrid.grid is None else math.sqrt(hybrid.grid.moments()[1]),
                ),
            ]
        return values

    def _health_values(self) -> list[tuple[str, Any]]:
        """The learned health (with ``learn_health``) and the OCV's hysteresis branch."""
        tr = self.tracker
        health = tr.health
        values: list[tuple[str, Any]] = []
        if health is not None:
            values += [(f"health_{k}", v) for k, v in health.fields().items()]
            values += [
                ("health_applied_capacity_ah", health.applied_capacity_ah),
                ("health_applied_soh", health.applied_soh),
                ("health_pairs_used", health.pairs_used),
                ("health_pairs_rejected", health.pairs_rejected),
                ("health_serial_number", health.serial_number or "none"),
                ("health_serial_unconfirmed", tr.serial_unconfirmed),
            ]
        if tr.hysteresis is not None:  # the OCV's hysteresis (models/hysteresis.py)
            values += [
                ("hysteresis_branch", tr.hysteresis.branch),
                ("hysteresis_branch_std", math.sqrt(tr.hysteresis.var)),
            ]
        return values

    def _cells(self) -> tuple[list[tuple[Level, str]], list[tuple[str, Any]]]:
        """The cells' problems and values (``cells/``), none before a sample with cells:
        imbalance (max - min cell SoC) and voltage spread against the file's ``cells:``
        WARN / ERROR thresholds, ERROR for a cell over or under its voltage limits, WARN for
        cell readings rejected since the last report."""
        tr = self.tracker
        bank, ce = tr.cells, tr.last_cells
        problems: list[tuple[Level, str]] = []
        if bank is None:
            return problems, []
        cs = tr.battery.cells
        rejected = int(bank.rejected.sum())
        new = self._new_since_last("cells_rejected", rejected)
        if new > 0:
            problems.append((Level.WARN, f"{new} cell readings rejected recently"))
        values: list[tuple[str, Any]] = [
            ("cells", bank.cells),
            ("cells_miscounted", tr.cells_miscounted),
            *((f"cell_rejected_{k + 1}", int(n)) for k, n in enumerate(bank.rejected)),
            ("cell_voltage_min_v", bank.v_min),
            ("cell_voltage_max_v", bank.v_max),
        ]
        if ce is None:
            return problems, values
        for what, value, warn, err, unit in (
            ("cell imbalance", ce.imbalance_soc, cs.imbalance_soc_warn, cs.imbalance_soc_error, ""),
            ("cell voltage spread", ce.spread_v, cs.spread_v_warn, cs.spread_v_error, " V"),
        ):
            if value >= err:
                problems.append((Level.ERROR, f"{what} {value:.3f}{unit} >= {err:g}{unit}"))
            elif value >= warn:
                problems.append((Level.WARN, f"{what} {value:.3f}{unit} >= {warn:g}{unit}"))
        for k in range(ce.cells):
            v = ce.voltage_v[k]
            if ce.over_voltage[k]:
                problems.append((Level.ERROR, f"cell {k + 1} overvoltage {v:.3f} V"))
            elif ce.under_voltage[k]:
                problems.append((Level.ERROR, f"cell {k + 1} undervoltage {v:.3f} V"))
        values += [
            ("usable_soc", ce.usable_soc),
            ("usable_soc_std", ce.usable_soc_std),
            ("usable_charge_soc", ce.usable_charge_soc),
            ("weakest_cell", ce.weakest + 1),
            ("strongest_cell", ce.strongest + 1),
            ("imbalance_soc", ce.imbalance_soc),
            ("cell_spread_v", ce.spread_v),
            *((f"cell_soc_{k + 1}", float(ce.soc[k])) for k in range(ce.cells)),
            *((f"cell_soc_std_{k + 1}", float(ce.soc_std[k])) for k in range(ce.cells)),
            *((f"cell_voltage_{k + 1}_v", float(ce.voltage_v[k])) for k in range(ce.cells)),
        ]
        return problems, values
