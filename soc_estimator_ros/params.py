"""Battery parameter files: schema, dataclasses, and a loader that validates everything.

One YAML file describes one battery (pack level): chemistry, capacity, limits, the OCV table,
the Saft RC model, the n-RC Thevenin model as tables over SoC (temperature optional), the
default filter tunings, and optionally the low-battery levels (``levels:``), the charger's
CC-CV end (``charge:``) and how health is learned (``health:``). ``config/*.yaml`` are
examples; docs/battery_files.md documents every key.

Every problem in a file raises :class:`ParamFileError` with one message that names the file,
the key (dotted path), the value found and what was expected, e.g.::

    config/bad.yaml: thevenin.branches[1].r_ohm[3] = -0.01: expected a number > 0
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import yaml

from .errors import SocEstimatorError
from .models.hysteresis import Hysteresis
from .models.ocv import OcvCurve
from .models.rc_saft import RcModelParams
from .models.tables import ParamTable
from .models.thevenin import (
    KineticParams,
    RcBranch,
    SurfaceLag,
    TemperatureExtrapolation,
    TheveninModel,
    TheveninParams,
)

SCHEMA_VERSION = 1
CHEMISTRIES = ("sla", "lfp", "li_ion")
#: Values no battery has, (lowest, highest); 0 as the lowest: any value > 0. A file holding
#: one is refused with its key instead of running into NaN estimates or overflows (each bound
#: was found so, by a fuzz of the bundled files). "Per cell": times ``cells_in_series``. The
#: bundled files stay orders of magnitude inside: 2.8-5.8 Ah; 2.5-4.2 V per cell; at most
#: 0.27 ohm per cell (the NCR18650PF's cold low-SoC branch); 0.08-5.4e6 F; saturation and
#: exchange currents 0.4-575 A, current limits to 30 A; a kinetic scale to 0.06 V per cell.
ABSURD = {
    "capacity_ah": (1.0e-3, 1.0e5),
    "voltage_v_per_cell": (0.0, 10.0),
    "resistance_ohm_per_cell": (0.0, 100.0),
    "capacitance_f": (1.0e-6, 1.0e10),
    "current_a": (1.0e-6, 1.0e5),
    "kinetic_scale_v_per_cell": (0.0, 1.0),
    "temperature_c": (-100.0, 200.0),
}
#: The closest two SoC points of a table may be: closer, a curve's slope between them is
#: infinite for the EKF's Jacobian (a fuzz found 0 and 1e-300).
SOC_STEP_MIN = 1.0e-6
#: Filter tunings (``filters.<estimator>.<entry>``) at most this large in magnitude: 1e9
#: switches a gate off in the tests; 1e300 overflowed a variance (a squared std) in the
#: hybrid.
ABSURD_TUNING = 1.0e12


class ParamFileError(SocEstimatorError, ValueError):
    """A battery parameter file that cannot be used, with the file, key, value and expectation."""

    def __init__(self, source: str, key: str, value: Any, expected: str) -> None:
        self.source, self.key, self.value, self.expected = source, key, value, expected
        shown = repr(value)
        if len(shown) > 80:
            shown = shown[:77] + "..."
        super().__init__(f"{source}: {key} = {shown}: expected {expected}")


@dataclass(frozen=True)
class Limits:
    """Operating limits of the pack (from the manufacturer's data sheet).

    ``soc_min`` is the lowest SoC the manufacturer recommends (40 % for SLA, about 20 % for
    LFP, seed 000 §2.1); the node warns below it.
    """

    voltage_min_v: float
    voltage_max_v: float
    soc_min: float
    soc_max: float
    current_max_discharge_a: float
    current_max_charge_a: float
    temperature_min_c: float
    temperature_max_c: float


@dataclass(frozen=True)
class LevelSettings:
    """The optional ``levels:`` section: low-battery levels and how they are filtered.

    Every entry is optional (None: the node parameter, else the rule of
    ``runtime/levels.py``: warn ``critical + 0.10``, critical ``limits.soc_min``, emergency
    ``critical - 0.05`` clipped at 0, hysteresis 0.02, debounce 30 s).

    Attributes:
        warn_soc, critical_soc, emergency_soc: the levels' SoC thresholds (fractions).
        hysteresis_soc: how far above a threshold the SoC must rise to clear its level.
        debounce_s: how long a level's condition must hold before the level changes (s).
    """

    warn_soc: float | None = None
    critical_soc: float | None = None
    emergency_soc: float | None = None
    hysteresis_soc: float | None = None
    debounce_s: float | None = None


@dataclass(frozen=True)
class ChargeSettings:
    """The optional ``charge:`` section: the charger's CC-CV end, for FULL detection.

    Every entry is optional (None: the rule of ``runtime/charging.py``: voltage
    ``limits.voltage_max_v - 0.05 V x cells_in_series``, tolerance ``0.025 V x
    cells_in_series``, taper 0.05 C, hold 60 s).

    Attributes:
        voltage_v: the charger's constant (CV) voltage, pack level (V).
        voltage_tolerance_v: how far from it the terminal voltage may be at the CV end (V).
        taper_c_rate: the charge current (in C of ``nominal_capacity_ah``) below which a CV
            charge has ended.
        hold_s: how long both must hold before FULL (s).
    """

    voltage_v: float | None = None
    voltage_tolerance_v: float | None = None
    taper_c_rate: float | None = None
    hold_s: float | None = None


@dataclass(frozen=True)
class HealthSettings:
    """The optional ``health:`` section: how the battery's health is learned (``health/``).

    Every entry has a default (an entry the file leaves out takes it).

    Attributes:
        capacity_std_frac: the file's capacity's std for a pack of unknown age (fraction):
            0.2, the widest whose 2 std stay above the end of life (0.6 of the file's); at
            0.1 the file's fresh capacity pulled three missions of an aged pack's evidence
            by about 2 % (docs/architecture.md#health).
        capacity_drift_per_cycle: the capacity's std growth per equivalent full cycle
            (fraction): how fast what was learned goes out of date as the pack ages.
        rest_min_s: a rest this long is read as an OCV (s).
        rest_current_c_rate: |current| (C, low-passed) at or below which the pack rests.
        ocv_std_v: the voltage std of such a reading (V, pack): the table's error and the
            relaxation the model leaves.
        pair_min_soc_drop: charge (fraction of the capacity) two readings must be apart to
            make a pair.
        full_soc_std: the SoC std at a CC-CV charge's end.
        current_offset_std_a, current_gain_std: the current sensor's offset (A) and gain
            (fraction) std (the guard's, ``estimators/guard.py``).
        r0_factor_std: the ``R_0`` factor's std for a pack of unknown age.
        r0_drift_per_hour: the factor's random walk (per sqrt(hour)).
        step_min_c_rate: a current step (C) at least this big between two samples is read.
        step_max_dt_s: ... only when the samples are at most this far apart (s).
        voltage_noise_std_v, current_noise_std_a: one sample's sensor noise (V, A).
        step_model_frac: the model's relative error on a step's answer.
        soh_warn, soh_dead: state of health below which diagnostics warn and
            ``power_supply_health`` is DEAD (seed 001: 0.6 is the end of life).
        ocv_ageing_exponent: how the OCV ages with the capacity: a rest reading ``s`` below
            ``ocv_ageing_below_soc`` is taken as ``p + (s - p) (Q_file / Q)^k`` on a pack of
            capacity ``Q`` (``health.capacity.OcvAgeing``; 0: the OCV does not age).
        ocv_ageing_pivot_soc: ``p``, where the aged and the fresh pack's OCV agree.
        ocv_ageing_below_soc: readings at or above this SoC are taken as read.
    """

    capacity_std_frac: float = 0.20
    capacity_drift_per_cycle: float = 0.002
    rest_min_s: float = 1800.0
    rest_current_c_rate: float = 0.02
    ocv_std_v: float = 0.02
    pair_min_soc_drop: float = 0.1
    full_soc_std: float = 0.01
    current_offset_std_a: float = 0.02
    current_gain_std: float = 0.005
    r0_factor_std: float = 0.3
    r0_drift_per_hour: float = 0.02
    step_min_c_rate: float = 0.5
    step_max_dt_s: float = 1.0
    voltage_noise_std_v: float = 0.004
    current_noise_std_a: float = 0.05
    step_model_frac: float = 0.1
    soh_warn: float = 0.8
    soh_dead: float = 0.6
    ocv_ageing_exponent: float = 0.0
    ocv_ageing_pivot_soc: float = 0.0
    ocv_ageing_below_soc: float = 1.0


@dataclass(frozen=True)
class CellSettings:
    """The optional ``cells:`` section: the cells of a series pack (``cells/``), used when the
    bridge sends ``cell_voltage``.

    Every entry has a default (an entry the file leaves out takes it). ``cell_voltage_min_v``
    and ``cell_voltage_max_v`` of 0 mean the pack's limits divided by ``cells_in_series``
    (LFP 2.50 / 3.65 V, SLA 1.75 / 2.45 V); seed 001's BMS protects each cell against
    over-voltage and deep discharge but names no per-cell voltages.

    Attributes:
        imbalance_soc_warn, imbalance_soc_error: max - min cell SoC (fraction) at which
            diagnostics warn and err.
        spread_v_warn, spread_v_error: max - min cell voltage (V) likewise.
        cell_voltage_min_v, cell_voltage_max_v: a cell's under- and over-voltage limits (V).
        absurd_margin_v: a cell reading more than this outside those limits (or not finite)
            is rejected for that cell alone (V).
        soc_spread_std: the prior std of a cell's SoC about the pack's (fraction; 0.05, the
            spread of a pack balanced at the factory).
        capacity_spread_std: the prior std of a cell's capacity about the pack's (fraction).
        resistance_spread_std_ohm: the prior std of a cell's resistance about the pack's
            share (ohm; 0: 20 % of the file's 1-C instantaneous drop per ampere, per cell).
        voltage_std_v: a cell reading's noise and model error at rest (V).
        voltage_std_per_a: the part that grows with the current (V per A): the cells'
            polarization differs by more than their ``R_0``.
        soc_walk_per_hour: the cell SoC deviation's random walk (fraction per sqrt(hour)).
        ocv_soc_std: how far a cell's own OCV curve may sit from the table, in SoC (fraction).
        rest_current_c_rate: |current| (C) at or below which the cells are read (the robot
            stopped).
        rest_min_s: ... once it has lasted this long (s).
        error_corr_s: how long a cell reading's error lasts (s; ``cells/filter.py``).
        cutoff_hold_s: a cell at or below its under-voltage limit this long (s, sample time)
            is the pack's cut-off: the usable SoC reads 0 (a BMS's under-voltage delay; one
            reading at 0 s).
    """

    imbalance_soc_warn: float = 0.05
    imbalance_soc_error: float = 0.10
    spread_v_warn: float = 0.10
    spread_v_error: float = 0.20
    cell_voltage_min_v: float = 0.0
    cell_voltage_max_v: float = 0.0
    absurd_margin_v: float = 1.0
    soc_spread_std: float = 0.05
    capacity_spread_std: float = 0.03
    resistance_spread_std_ohm: float = 0.0
    voltage_std_v: float = 0.003
    voltage_std_per_a: float = 0.0005
    soc_walk_per_hour: float = 0.002
    ocv_soc_std: float = 0.01
    rest_current_c_rate: float = 0.1
    rest_min_s: float = 60.0
    error_corr_s: float = 300.0
    cutoff_hold_s: float = 1.0


#: Bounds of every ``cells:`` entry (lo, hi).
CELL_BOUNDS: dict[str, tuple[float, float]] = {
    "imbalance_soc_warn": (0.0, 1.0),
    "imbalance_soc_error": (0.0, 1.0),
    "spread_v_warn": (0.0, 10.0),
    "spread_v_error": (0.0, 10.0),
    "cell_voltage_min_v": (0.0, 10.0),
    "cell_voltage_max_v": (0.0, 10.0),
    "absurd_margin_v": (0.0, 10.0),
    "soc_spread_std": (1e-4, 0.5),
    "capacity_spread_std": (0.0, 0.5),
    "resistance_spread_std_ohm": (0.0, 1.0),
    "voltage_std_v": (1e-5, 1.0),
    "voltage_std_per_a": (0.0, 1.0),
    "soc_walk_per_hour": (0.0, 1.0),
    "ocv_soc_std": (0.0, 0.5),
    "rest_current_c_rate": (0.0, 10.0),
    "rest_min_s": (0.0, 86400.0),
    "error_corr_s": (0.0, 86400.0),
    "cutoff_hold_s": (0.0, 60.0),
}


#: Bounds of every ``health:`` entry (lo, hi).
HEALTH_BOUNDS: dict[str, tuple[float, float]] = {
    "capacity_std_frac": (1e-4, 1.0),
    "capacity_drift_per_cycle": (0.0, 0.1),
    "rest_min_s": (1.0, 86400.0),
    "rest_current_c_rate": (0.0, 1.0),
    "ocv_std_v": (1e-4, 1.0),
    "pair_min_soc_drop": (0.0, 1.0),
    "full_soc_std": (1e-4, 0.5),
    "current_offset_std_a": (0.0, 100.0),
    "current_gain_std": (0.0, 0.5),
    "r0_factor_std": (1e-4, 5.0),
    "r0_drift_per_hour": (0.0, 5.0),
    "step_min_c_rate": (1e-3, 100.0),
    "step_max_dt_s": (1e-3, 60.0),
    "voltage_noise_std_v": (1e-5, 1.0),
    "current_noise_std_a": (1e-5, 100.0),
    "step_model_frac": (0.0, 10.0),
    "soh_warn": (0.0, 1.0),
    "soh_dead": (0.0, 1.0),
    "ocv_ageing_exponent": (-2.0, 2.0),
    "ocv_ageing_pivot_soc": (0.0, 1.0),
    "ocv_ageing_below_soc": (0.0, 1.0),
}


@dataclass(frozen=True)
class OcvTable:
    """OCV points: ``soc`` (fractions, increasing) and ``voltage_v`` (volts, increasing).

    Optionally the OCV's shift with temperature: ``offset_v[j][i]`` at ``temperature_c[j]`` and
    ``soc[i]`` is added to the curve, interpolated bilinearly and held beyond the grid
    (OCV(SoC, T) = OCV(SoC) + offset(T, SoC)). It holds the entropic term and what a cold cell
    has not relaxed after the identification's rests: measured on the NCR18650PF, the rested
    voltage at 0 degC lies 12-32 mV below the 25 degC curve, 1.5-3 % of SoC.
    """

    soc: tuple[float, ...]
    voltage_v: tuple[float, ...]
    temperature_c: tuple[float, ...] = ()
    offset_v: tuple[tuple[float, ...], ...] = ()

    def curve(self) -> OcvCurve:
        """The PCHIP curve through the points."""
        return OcvCurve(self.soc, self.voltage_v)

    def offset_table(self) -> ParamTable | None:
        """The temperature shift as a table, or None without one."""
        if not self.temperature_c:
            return None
        return ParamTable(soc=self.soc, values=self.offset_v, temperature_c=self.temperature_c)


@dataclass(frozen=True)
class BatteryParams:
    """Everything the estimators know about one battery (pack level)."""

    name: str
    chemistry: str
    nominal_capacity_ah: float
    capacity_ah: float
    cells_in_series: int
    coulomb_efficiency_charge: float
    limits: Limits
    ocv: OcvTable
    rc_model: RcModelParams
    thevenin: TheveninParams
    filters: Mapping[str, Mapping[str, float | tuple[float, ...]]] = field(default_factory=dict)
    source: str = ""
    levels: LevelSettings = field(default_factory=LevelSettings)
    charge: ChargeSettings = field(default_factory=ChargeSettings)
    health: HealthSettings = field(default_factory=HealthSettings)
    cells: CellSettings = field(default_factory=CellSettings)
    #: The rested OCV (the optional ``rest_ocv:`` section): every long rest of the
    #: identification's tests (pulse, rate and load tests), at the reference temperature. The
    #: model's ``ocv`` is fitted together with its branches and lag on the pulse test's rests
    #: alone; this table is what a pack rested for 45 minutes or more reads, for the health
    #: monitor's rest readings (``health/monitor.py``). None: the model's table.
    rest_ocv: OcvTable | None = None
    #: The OCV's charge/discharge hysteresis (the optional ``hysteresis:`` section), identified
    #: where a test holds rests after both directions (``soc_identify --hysteresis-test``);
    #: the tables above are then the discharge branch. None: no hysteresis (no such test).
    hysteresis: Hysteresis | None = None

    def ocv_curve(self) -> OcvCurve:
        """The battery's OCV curve."""
        return self.ocv.curve()

    def rest_ocv_curve(self) -> OcvCurve:
        """The rested OCV curve (:attr:`rest_ocv`, else the model's)."""
        return (self.rest_ocv or self.ocv).curve()

    def thevenin_model(self, thevenin: TheveninParams | None = None) -> TheveninModel:
        """The pack's Thevenin model: its OCV (with the temperature shift), ``thevenin`` (the
        file's tables by default), capacity and charge efficiency."""
        return TheveninModel(
            self.ocv_curve(),
            self.thevenin if thevenin is None else thevenin,
            self.capacity_ah,
            self.coulomb_efficiency_charge,
            self.ocv.offset_table(),
        )


class _Checker:
    """Reads typed values out of the raw YAML tree, raising ParamFileError on the first fault."""

    def __init__(self, source: str) -> None:
        self.source = source

    def fail(self, key: str, value: Any, expected: str) -> ParamFileError:
        return ParamFileError(self.source, key, value, expected)

    def mapping(self, node: Any, key: str) -> Mapping[str, Any]:
        if not isinstance(node, Mapping):
            raise self.fail(key, node, "a mapping")
        return node

    def get(self, node: Mapping[str, Any], name: str, prefix: str) -> Any:
        key = f"{prefix}.{name}" if prefix else name
        if name not in node:
            raise self.fail(key, "<missing>", "this required key")
        return node[name]

    def number(
        self,
        value: Any,
        key: str,
        lo: float | None = None,
        hi: float | None = None,
        lo_open: bool = False,
    ) -> float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise self.fail(key, value, "a number")
        v = float(value)
        if not math.isfinite(v):
            raise self.fail(key, value, "a finite number")
        if lo is not None and (v <= lo if lo_open else v < lo):
            bound = f"> {lo:g}" if lo_open else f">= {lo:g}"
            raise self.fail(key, value, f"a number {bound}" + (f" and <= {hi:g}" if hi else ""))
        if hi is not None and v > hi:
            raise self.fail(key, value, f"a number <= {hi:g}")
        return v

    def positive(self, value: Any, key: str, hi: float | None = None) -> float:
        return self.number(value, key, lo=0.0, hi=hi, lo_open=True)

    def numbers(
        self,
        value: Any,
        key: str,
        positive: bool = False,
        min_len: int = 1,
        bounds: tuple[float, float] | None = None,
    ) -> tuple[float, ...]:
        """A list of numbers: each > 0 with ``positive``, in ``bounds`` (:meth:`within`)
        where given."""
        if isinstance(value, (str, bytes)) or not isinstance(value, Sequence):
            raise self.fail(key, value, "a list of numbers")
        if len(value) < min_len:
            raise self.fail(key, value, f"a list of at least {min_len} numbers")
        if bounds is not None:
            return tuple(self.within(v, f"{key}[{i}]", bounds) for i, v in enumerate(value))
        if positive:
            return tuple(self.positive(v, f"{key}[{i}]") for i, v in enumerate(value))
        return tuple(self.number(v, f"{key}[{i}]") for i, v in enumerate(value))

    def within(self, value: Any, key: str, bounds: tuple[float, float]) -> float:
        """A number in ``bounds`` (an :data:`ABSURD` range: a lowest of 0 means > 0)."""
        lo, hi = bounds
        if lo == 0.0:
            return self.positive(value, key, hi)
        return self.number(value, key, lo, hi)

    def increasing(self, values: tuple[float, ...], key: str, min_step: float = 0.0) -> None:
        """Strictly increasing, by at least ``min_step`` where given."""
        for i in range(1, len(values)):
            if values[i] <= values[i - 1]:
                raise self.fail(
                    f"{key}[{i}]", values[i], f"a value > {values[i - 1]:g} (strictly increasing)"
                )
            if values[i] - values[i - 1] < min_step:
                raise self.fail(
                    f"{key}[{i}]",
                    values[i],
                    f"a value >= {values[i - 1] + min_step:g} (points {min_step:g} apart at least)",
                )

    def table(
        self,
        value: Any,
        key: str,
        soc: tuple[float, ...],
        temps: tuple[float, ...],
        bounds: tuple[float, float],
    ) -> ParamTable:
        """A table of values in ``bounds`` (:meth:`within`): 1-D over SoC (one temperature) or
        2-D (temperature x SoC)."""
        if isinstance(value, Sequence) and value and isinstance(value[0], Sequence):
            rows = [self.numbers(r, f"{key}[{i}]", bounds=bounds) for i, r in enumerate(value)]
        else:
            rows = [self.numbers(value, key, bounds=bounds)]
        if len(rows) != len(temps):
            raise self.fail(key, value, f"{len(temps)} rows, one per thevenin.temperature_c")
        for i, r in enumerate(rows):
            if len(r) != len(soc):
                where = f"{key}[{i}]" if len(rows) > 1 else key
                raise self.fail(where, r, f"{len(soc)} values, one per thevenin.soc point")
        return ParamTable(soc=soc, values=tuple(rows), temperature_c=temps)


def _parse_filters(chk: _Checker, node: Any) -> dict[str, dict[str, float | tuple[float, ...]]]:
    """Tuning blocks: estimator name -> {name: number or list of numbers}.

    Variance-like entries (names starting with ``p0``, ``q`` or ``r``) must be > 0; the
    estimators check which entries they need when they are built.
    """
    out: dict[str, dict[str, float | tuple[float, ...]]] = {}
    for est, block in chk.mapping(node, "filters").items():
        blk = chk.mapping(block, f"filters.{est}")
        parsed: dict[str, float | tuple[float, ...]] = {}
        for name, value in blk.items():
            key = f"filters.{est}.{name}"
            positive = str(name).startswith(("p0", "q", "r"))
            bounds = (0.0 if positive else -ABSURD_TUNING, ABSURD_TUNING)
            if isinstance(value, Sequence) and not isinstance(value, str):
                parsed[str(name)] = chk.numbers(value, key, bounds=bounds)
            else:
                parsed[str(name)] = chk.within(value, key, bounds)
        out[str(est)] = parsed
    return out


def _optional_section(
    chk: _Checker, root: Mapping[str, Any], name: str, bounds: dict[str, tuple[float, float]]
) -> dict[str, float]:
    """An optional section of optional numbers ``{key: (lo, hi)}``; unknown keys refused."""
    node = root.get(name)
    if node is None:
        return {}
    section = chk.mapping(node, name)
    out: dict[str, float] = {}
    for key, value in section.items():
        if key not in bounds:
            raise chk.fail(f"{name}.{key}", value, f"one of the keys {', '.join(bounds)}")
        lo, hi = bounds[key]
        out[str(key)] = chk.number(value, f"{name}.{key}", lo, hi)
    return out


def _parse_levels(chk: _Checker, root: Mapping[str, Any]) -> LevelSettings:
    got = _optional_section(
        chk,
        root,
        "levels",
        {
            "warn_soc": (0.0, 1.0),
            "critical_soc": (0.0, 1.0),
            "emergency_soc": (0.0, 1.0),
            "hysteresis_soc": (0.0, 0.5),
            "debounce_s": (0.0, 3600.0),
        },
    )
    order = [k for k in ("warn_soc", "critical_soc", "emergency_soc") if k in got]
    for upper, lower in zip(order[:-1], order[1:], strict=True):
        if got[lower] > got[upper]:
            raise chk.fail(
                f"levels.{lower}", got[lower], f"a value <= levels.{upper} ({got[upper]:g})"
            )
    return LevelSettings(**got)


def _parse_charge(chk: _Checker, root: Mapping[str, Any], limits: Limits) -> ChargeSettings:
    got = _optional_section(
        chk,
        root,
        "charge",
        {
            "voltage_v": (limits.voltage_min_v, limits.voltage_max_v),
            "voltage_tolerance_v": (0.0, 0.5 * (limits.voltage_max_v - limits.voltage_min_v)),
            "taper_c_rate": (1e-4, 1.0),
            "hold_s": (0.0, 3600.0),
        },
    )
    if "voltage_tolerance_v" in got and not got["voltage_tolerance_v"] > 0.0:
        raise chk.fail("charge.voltage_tolerance_v", got["voltage_tolerance_v"], "a number > 0")
    return ChargeSettings(**got)


def _parse_health(chk: _Checker, root: Mapping[str, Any]) -> HealthSettings:
    got = _optional_section(chk, root, "health", HEALTH_BOUNDS)
    health = HealthSettings(**got)
    if health.soh_dead > health.soh_warn:
        raise chk.fail(
            "health.soh_dead", health.soh_dead, f"a value <= health.soh_warn ({health.soh_warn:g})"
        )
    return health


def _parse_cells(chk: _Checker, root: Mapping[str, Any]) -> CellSettings:
    got = _optional_section(chk, root, "cells", CELL_BOUNDS)
    cells = CellSettings(**got)
    for warn, err in (
        ("imbalance_soc_warn", "imbalance_soc_error"),
        ("spread_v_warn", "spread_v_error"),
    ):
        if getattr(cells, err) < getattr(cells, warn):
            raise chk.fail(
                f"cells.{err}",
                getattr(cells, err),
                f"a value >= cells.{warn} ({getattr(cells, warn):g})",
            )
    lo, hi = cells.cell_voltage_min_v, cells.cell_voltage_max_v
    if lo > 0.0 and hi > 0.0 and hi <= lo:
        raise chk.fail(
            "cells.cell_voltage_max_v", hi, f"a value > cells.cell_voltage_min_v ({lo:g})"
        )
    return cells


def _ocv_points(
    chk: _Checker, node: Mapping[str, Any], key: str, bounds: tuple[float, float]
) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """An OCV table's points (``ocv:``, ``rest_ocv:``): SoC in [0, 1] and volts in ``bounds``,
    both increasing, one voltage per SoC."""
    soc = chk.numbers(chk.get(node, "soc", key), f"{key}.soc", min_len=2)
    volts = chk.numbers(chk.get(node, "voltage_v", key), f"{key}.voltage_v", bounds=bounds)
    if len(volts) != len(soc):
        raise chk.fail(f"{key}.voltage_v", volts, f"{len(soc)} values, one per {key}.soc point")
    for i, x in enumerate(soc):
        chk.number(x, f"{key}.soc[{i}]", 0.0, 1.0)
    chk.increasing(soc, f"{key}.soc", SOC_STEP_MIN)
    chk.increasing(volts, f"{key}.voltage_v")
    return soc, volts


def _parse_rest_ocv(
    chk: _Checker, root: Mapping[str, Any], bounds: tuple[float, float]
) -> OcvTable | None:
    """The optional ``rest_ocv:`` section (:attr:`BatteryParams.rest_ocv`), volts in
    ``bounds``."""
    if "rest_ocv" not in root:
        return None
    soc, volts = _ocv_points(chk, chk.mapping(root["rest_ocv"], "rest_ocv"), "rest_ocv", bounds)
    return OcvTable(soc=soc, voltage_v=volts)


def _parse_hysteresis(chk: _Checker, root: Mapping[str, Any]) -> Hysteresis | None:
    """The optional ``hysteresis:`` section (:attr:`BatteryParams.hysteresis`)."""
    if root.get("hysteresis") is None:
        return None
    key = "hysteresis"
    hm = chk.mapping(root[key], key)
    return Hysteresis(
        gap_v=chk.number(chk.get(hm, "gap_v", key), f"{key}.gap_v", 0.0, 2.0),
        rate_per_soc=chk.number(
            chk.get(hm, "rate_per_soc", key), f"{key}.rate_per_soc", 0.1, 1.0e4
        ),
    )


def parse_battery_params(raw: Any, source: str = "<memory>") -> BatteryParams:
    """Validate a raw YAML tree (already parsed) and build :class:`BatteryParams`."""
    chk = _Checker(source)
    root = chk.mapping(raw, "<top level>")
    version = chk.get(root, "schema_version", "")
    if version != SCHEMA_VERSION:
        raise chk.fail("schema_version", version, f"{SCHEMA_VERSION}")
    name = chk.get(root, "name", "")
    if not isinstance(name, str) or not name.strip():
        raise chk.fail("name", name, "a non-empty string")
    chemistry = chk.get(root, "chemistry", "")
    if chemistry not in CHEMISTRIES:
        raise chk.fail("chemistry", chemistry, f"one of {', '.join(CHEMISTRIES)}")
    nominal = chk.within(
        chk.get(root, "nominal_capacity_ah", ""), "nominal_capacity_ah", ABSURD["capacity_ah"]
    )
    capacity = chk.within(root.get("capacity_ah", nominal), "capacity_ah", ABSURD["capacity_ah"])
    cells = chk.get(root, "cells_in_series", "")
    if isinstance(cells, bool) or not isinstance(cells, int) or cells < 1:
        raise chk.fail("cells_in_series", cells, "an integer >= 1")
    # ABSURD's ranges for this pack (its "per cell" ones times the cells in series).
    absurd = {
        k.removesuffix("_per_cell"): (lo * cells, hi * cells)
        if k.endswith("_per_cell")
        else (lo, hi)
        for k, (lo, hi) in ABSURD.items()
    }
    eta = chk.number(
        chk.get(root, "coulomb_efficiency_charge", ""), "coulomb_efficiency_charge", 0.5, 1.0
    )
    source_text = root.get("source", "")
    if not isinstance(source_text, str):
        raise chk.fail("source", source_text, "a string")

    lim = chk.mapping(chk.get(root, "limits", ""), "limits")
    vmin = chk.within(
        chk.get(lim, "voltage_min_v", "limits"), "limits.voltage_min_v", absurd["voltage_v"]
    )
    vmax = chk.within(
        chk.get(lim, "voltage_max_v", "limits"), "limits.voltage_max_v", absurd["voltage_v"]
    )
    if vmax <= vmin:
        raise chk.fail("limits.voltage_max_v", vmax, f"a value > limits.voltage_min_v ({vmin:g})")
    soc_min = chk.number(chk.get(lim, "soc_min", "limits"), "limits.soc_min", 0.0, 1.0)
    soc_max = chk.number(chk.get(lim, "soc_max", "limits"), "limits.soc_max", 0.0, 1.0)
    if soc_max <= soc_min:
        raise chk.fail("limits.soc_max", soc_max, f"a value > limits.soc_min ({soc_min:g})")
    t_range = absurd["temperature_c"]
    tmin = chk.within(
        chk.get(lim, "temperature_min_c", "limits"), "limits.temperature_min_c", t_range
    )
    tmax = chk.within(
        chk.get(lim, "temperature_max_c", "limits"), "limits.temperature_max_c", t_range
    )
    if tmax <= tmin:
        raise chk.fail("limits.temperature_max_c", tmax, f"a value > {tmin:g}")
    limits = Limits(
        voltage_min_v=vmin,
        voltage_max_v=vmax,
        soc_min=soc_min,
        soc_max=soc_max,
        current_max_discharge_a=chk.within(
            chk.get(lim, "current_max_discharge_a", "limits"),
            "limits.current_max_discharge_a",
            absurd["current_a"],
        ),
        current_max_charge_a=chk.within(
            chk.get(lim, "current_max_charge_a", "limits"),
            "limits.current_max_charge_a",
            absurd["current_a"],
        ),
        temperature_min_c=tmin,
        temperature_max_c=tmax,
    )

    ocv_node = chk.mapping(chk.get(root, "ocv", ""), "ocv")
    ocv_soc, ocv_v = _ocv_points(chk, ocv_node, "ocv", absurd["voltage_v"])
    ocv_temps: tuple[float, ...] = ()
    ocv_offsets: tuple[tuple[float, ...], ...] = ()
    if "temperature_c" in ocv_node or "offset_v" in ocv_node:
        ocv_temps = chk.numbers(chk.get(ocv_node, "temperature_c", "ocv"), "ocv.temperature_c")
        for i, t in enumerate(ocv_temps):
            chk.within(t, f"ocv.temperature_c[{i}]", t_range)
        chk.increasing(ocv_temps, "ocv.temperature_c")
        rows = chk.get(ocv_node, "offset_v", "ocv")
        if (
            isinstance(rows, (str, bytes))
            or not isinstance(rows, Sequence)
            or (len(rows) != len(ocv_temps))
        ):
            raise chk.fail("ocv.offset_v", rows, f"{len(ocv_temps)} rows, one per temperature")
        parsed = []
        for j, row in enumerate(rows):
            r = chk.numbers(row, f"ocv.offset_v[{j}]")
            if len(r) != len(ocv_soc):
                raise chk.fail(f"ocv.offset_v[{j}]", row, f"{len(ocv_soc)} values, one per ocv.soc")
            for i, v in enumerate(r):
                chk.number(v, f"ocv.offset_v[{j}][{i}]", -0.5 * cells, 0.5 * cells)
            parsed.append(r)
        ocv_offsets = tuple(parsed)

    rc = chk.mapping(chk.get(root, "rc_model", ""), "rc_model")
    rc_params = RcModelParams(
        **{
            k: chk.within(chk.get(rc, k, "rc_model"), f"rc_model.{k}", absurd[unit])
            for k, unit in (
                ("c_b_f", "capacitance_f"),
                ("c_s_f", "capacitance_f"),
                ("r_b_ohm", "resistance_ohm"),
                ("r_s_ohm", "resistance_ohm"),
                ("r_t_ohm", "resistance_ohm"),
            )
        }
    )
    # Seed 000's terminal-voltage state relaxes at a33 = R_s / (C_b R_b s) - 1 / (C_s s)
    # (models/rc_saft.py): stable only while the surface capacitor is the faster one.
    tau_s, tau_b = rc_params.c_s_f * rc_params.r_s_ohm, rc_params.c_b_f * rc_params.r_b_ohm
    if not tau_s < tau_b:
        raise chk.fail(
            "rc_model.c_s_f",
            rc_params.c_s_f,
            f"c_s_f r_s_ohm ({tau_s:g} s) < c_b_f r_b_ohm ({tau_b:g} s): the model is unstable "
            "otherwise",
        )

    th = chk.mapping(chk.get(root, "thevenin", ""), "thevenin")
    th_soc = chk.numbers(chk.get(th, "soc", "thevenin"), "thevenin.soc")
    for i, s in enumerate(th_soc):
        chk.number(s, f"thevenin.soc[{i}]", 0.0, 1.0)
    chk.increasing(th_soc, "thevenin.soc", SOC_STEP_MIN)
    temps = chk.numbers(th.get("temperature_c", [25.0]), "thevenin.temperature_c")
    for i, t in enumerate(temps):
        chk.within(t, f"thevenin.temperature_c[{i}]", t_range)
    chk.increasing(temps, "thevenin.temperature_c")
    r0 = chk.table(
        chk.get(th, "r0_ohm", "thevenin"),
        "thevenin.r0_ohm",
        th_soc,
        temps,
        absurd["resistance_ohm"],
    )
    branches_node = chk.get(th, "branches", "thevenin")
    if isinstance(branches_node, (str, bytes)) or not isinstance(branches_node, Sequence):
        raise chk.fail("thevenin.branches", branches_node, "a list of {r_ohm, c_f} branches")
    if not 1 <= len(branches_node) <= 3:
        raise chk.fail("thevenin.branches", branches_node, "1 to 3 RC branches")
    branches = []
    for i, b in enumerate(branches_node):
        key = f"thevenin.branches[{i}]"
        bm = chk.mapping(b, key)
        branches.append(
            RcBranch(
                r_ohm=chk.table(
                    chk.get(bm, "r_ohm", key),
                    f"{key}.r_ohm",
                    th_soc,
                    temps,
                    absurd["resistance_ohm"],
                ),
                c_f=chk.table(
                    chk.get(bm, "c_f", key), f"{key}.c_f", th_soc, temps, absurd["capacitance_f"]
                ),
                i_sat_a=(
                    None
                    if bm.get("i_sat_a") is None
                    else chk.table(
                        bm["i_sat_a"], f"{key}.i_sat_a", th_soc, temps, absurd["current_a"]
                    )
                ),
            )
        )

    kinetic = None
    if th.get("kinetic") is not None:
        km = chk.mapping(th["kinetic"], "thevenin.kinetic")
        kinetic = KineticParams(
            *(
                chk.table(
                    chk.get(km, k, "thevenin.kinetic"),
                    f"thevenin.kinetic.{k}",
                    th_soc,
                    temps,
                    absurd[unit],
                )
                for k, unit in (("a_v", "kinetic_scale_v"), ("i0_a", "current_a"))
            )
        )

    surface_lag = None
    if th.get("surface_lag") is not None:
        key = "thevenin.surface_lag"
        sm = chk.mapping(th["surface_lag"], key)
        bounds = {"gain_soc_per_a": (0.0, 1.0), "tau_s": (0.1, 1.0e5), "soc_max": (0.0, 1.0)}
        modes = {}
        for field_name, (lo, hi) in bounds.items():
            where = f"{key}.{field_name}"
            values = chk.numbers(chk.get(sm, field_name, key), where)
            modes[field_name] = tuple(
                chk.number(v, f"{where}[{i}]", lo, hi) for i, v in enumerate(values)
            )
            n = len(modes["gain_soc_per_a"])
            if len(values) != n:
                raise chk.fail(where, values, f"{n} values, one per gain (mode)")
        surface_lag = SurfaceLag(**modes)

    extrapolation = TemperatureExtrapolation()
    if th.get("extrapolation") is not None:
        key = "thevenin.extrapolation"
        em = chk.mapping(th["extrapolation"], key)
        extrapolation = TemperatureExtrapolation(
            activation_energy_j_per_mol=chk.number(
                em.get("activation_energy_j_per_mol", extrapolation.activation_energy_j_per_mol),
                f"{key}.activation_energy_j_per_mol",
                0.0,
                2.0e5,
            ),
            margin_c=chk.number(
                em.get("margin_c", extrapolation.margin_c), f"{key}.margin_c", 0.0, 100.0
            ),
        )

    fitted_c_rate_max = None
    if th.get("fitted_c_rate_max") is not None:
        fitted_c_rate_max = chk.number(
            th["fitted_c_rate_max"], "thevenin.fitted_c_rate_max", 1.0e-3, 1.0e3
        )

    filters = _parse_filters(chk, root.get("filters", {}))
    levels = _parse_levels(chk, root)
    charge = _parse_charge(chk, root, limits)
    health = _parse_health(chk, root)
    cell_settings = _parse_cells(chk, root)
    return BatteryParams(
        name=name,
        chemistry=chemistry,
        nominal_capacity_ah=nominal,
        capacity_ah=capacity,
        cells_in_series=cells,
        coulomb_efficiency_charge=eta,
        limits=limits,
        ocv=OcvTable(soc=ocv_soc, voltage_v=ocv_v, temperature_c=ocv_temps, offset_v=ocv_offsets),
        rest_ocv=_parse_rest_ocv(chk, root, absurd["voltage_v"]),
        hysteresis=_parse_hysteresis(chk, root),
        rc_model=rc_params,
        thevenin=TheveninParams(
            r0_ohm=r0,
            branches=tuple(branches),
            kinetic=kinetic,
            surface_lag=surface_lag,
            extrapolation=extrapolation,
            fitted_c_rate_max=fitted_c_rate_max,
        ),
        filters=filters,
        source=source_text,
        levels=levels,
        charge=charge,
        health=health,
        cells=cell_settings,
    )


def load_battery_params(path: str | Path) -> BatteryParams:
    """Read and validate a battery parameter file; :class:`ParamFileError` on any fault."""
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except OSError as exc:
        raise ParamFileError(str(p), "<file>", str(exc), "a readable YAML file") from exc
    except UnicodeDecodeError as exc:
        shown = f"{exc.reason} at byte {exc.start}"
        raise ParamFileError(str(p), "<file>", shown, "a UTF-8 text (YAML) file") from exc
    try:
        raw = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise ParamFileError(str(p), "<file>", str(exc).splitlines()[0], "valid YAML") from exc
    return parse_battery_params(raw, str(p))


def battery_params_to_dict(params: BatteryParams) -> dict[str, Any]:
    """The plain-YAML form of ``params`` (inverse of :func:`parse_battery_params`)."""
    th = params.thevenin
    temps = list(th.r0_ohm.temperature_c)

    def table(t: ParamTable) -> list[float] | list[list[float]]:
        rows = [list(r) for r in t.values]
        return rows[0] if len(rows) == 1 else rows

    out: dict[str, Any] = {
        "schema_version": SCHEMA_VERSION,
        "name": params.name,
        "chemistry": params.chemistry,
        "source": params.source,
        "nominal_capacity_ah": params.nominal_capacity_ah,
        "capacity_ah": params.capacity_ah,
        "cells_in_series": params.cells_in_series,
        "coulomb_efficiency_charge": params.coulomb_efficiency_charge,
        "limits": {k: getattr(params.limits, k) for k in Limits.__dataclass_fields__},
        "ocv": {"soc": list(params.ocv.soc), "voltage_v": list(params.ocv.voltage_v)},
        "rc_model": {k: getattr(params.rc_model, k) for k in RcModelParams.__dataclass_fields__},
        "thevenin": {
            "soc": list(th.r0_ohm.soc),
            "temperature_c": temps,
            "r0_ohm": table(th.r0_ohm),
            "branches": [
                {"r_ohm": table(b.r_ohm), "c_f": table(b.c_f)}
                | ({} if b.i_sat_a is None else {"i_sat_a": table(b.i_sat_a)})
                for b in th.branches
            ],
        },
        "filters": {
            est: {k: list(v) if isinstance(v, tuple) else v for k, v in blk.items()}
            for est, blk in params.filters.items()
        },
    }
    if th.kinetic is not None:
        out["thevenin"]["kinetic"] = {"a_v": table(th.kinetic.a_v), "i0_a": table(th.kinetic.i0_a)}
    if th.extrapolation != TemperatureExtrapolation():  # the default is not written
        out["thevenin"]["extrapolation"] = {
            "activation_energy_j_per_mol": th.extrapolation.activation_energy_j_per_mol,
            "margin_c": th.extrapolation.margin_c,
        }
    if th.fitted_c_rate_max is not None:
        out["thevenin"]["fitted_c_rate_max"] = th.fitted_c_rate_max
    if th.surface_lag is not None:
        out["thevenin"]["surface_lag"] = {
            "gain_soc_per_a": list(th.surface_lag.gain_soc_per_a),
            "tau_s": list(th.surface_lag.tau_s),
            "soc_max": list(th.surface_lag.soc_max),
        }
    if params.ocv.temperature_c:
        out["ocv"]["temperature_c"] = list(params.ocv.temperature_c)
        out["ocv"]["offset_v"] = [list(r) for r in params.ocv.offset_v]
    if params.rest_ocv is not None:
        out["rest_ocv"] = {
            "soc": list(params.rest_ocv.soc),
            "voltage_v": list(params.rest_ocv.voltage_v),
        }
    for name, section in (("levels", params.levels), ("charge", params.charge)):
        given = {k: v for k, v in asdict(section).items() if v is not None}
        if given:
            out[name] = given
    defaults = asdict(HealthSettings())
    health = {k: v for k, v in asdict(params.health).items() if v != defaults[k]}
    if health:  # only what differs from the defaults
        out["health"] = health
    if params.hysteresis is not None:
        out["hysteresis"] = asdict(params.hysteresis)
    cell_defaults = asdict(CellSettings())
    cells = {k: v for k, v in asdict(params.cells).items() if v != cell_defaults[k]}
    if cells:
        out["cells"] = cells
    return out


def output_dir_error(path: str | Path) -> str | None:
    """Why a battery file cannot be written at ``path``, said before the work that makes it
    (``soc_identify``'s fits, ``soc_tune``'s search): its directory is missing; else None."""
    parent = Path(path).parent
    return None if parent.is_dir() else f"no directory {parent} for --output"


def write_battery_file(path: str | Path, data: Mapping[str, Any], header: str) -> None:
    """Write ``data`` (:func:`battery_params_to_dict`'s form, perhaps edited) under the comment
    lines ``header`` (each ending in a newline) to ``path``, checked first with every rule of
    :func:`parse_battery_params`: a file that would not load is never written
    (:class:`ParamFileError`; ``OSError`` where ``path`` cannot be written). The one writer of
    ``soc_identify``'s and ``soc_tune``'s files."""
    text = yaml.safe_dump(dict(data), sort_keys=False, width=100, default_flow_style=None)
    parse_battery_params(yaml.safe_load(text), str(path))
    Path(path).write_text(header + text)
