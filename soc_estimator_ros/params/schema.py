"""The battery file's schema: what each section holds (frozen dataclasses, pack level) and the
bounds a value must keep; :mod:`.parse` reads a file into them, :mod:`.write` writes them back.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from ..errors import SocEstimatorError
from ..models.hysteresis import Hysteresis
from ..models.ocv import OcvCurve
from ..models.rc_saft import RcModelParams
from ..models.tables import ParamTable
from ..models.thevenin import TheveninModel, TheveninParams

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
