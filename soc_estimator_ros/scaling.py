"""Scale a chemistry's battery file to another pack of the same cells (issue 26).

A file identified on one pack (``config/*.yaml``) describes its cells; another pack of the
same chemistry with ``cells_in_series`` cells and a rated capacity ``capacity_ah`` is, to the
models, the same cells with ``n = cells / file's cells`` in series and ``q = capacity_ah /
file's nominal_capacity_ah`` times the charge in parallel. Every quantity scales by its unit:

=====================================  ==========
volts (OCV, limits, charge, a_v, ...)  x n
amperes, ampere-hours                  x q
ohms (and V/A)                         x n / q
farads                                 x q / n
V^2, A^2 (variances)                   x n^2, q^2
SoC per ampere (the surface lag gain)  x 1 / q
SoC, temperatures, seconds, C-rates,   x 1
fractions, dimensionless
=====================================  ==========

so every time constant R C, every C-rate and every SoC trajectory are kept: the scaled model
driven by ``q I`` gives ``n V`` where the file's gives ``V`` at the same SoC. A unit here is
its (volt, ampere) exponent pair; time is never scaled, so a rate (V^2/s) scales as its
quantity (V^2). What scaling cannot know is the real pack's capacity and resistance (another
cell lot, its age): the online health estimation (``health/``) learns those.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import replace
from typing import Any

from .estimators import ESTIMATORS, PRESETS
from .estimators.base import Estimator
from .models.tables import ParamTable
from .models.thevenin import KineticParams, RcBranch, SurfaceLag, TheveninParams
from .params import (
    BatteryParams,
    OcvTable,
    battery_params_to_dict,
    parse_battery_params,
)

#: A unit as its exponents of the volt and the ampere (seconds are not scaled).
Unit = tuple[int, int]
NONE: Unit = (0, 0)
VOLT: Unit = (1, 0)
VOLT2: Unit = (2, 0)
AMP: Unit = (0, 1)
OHM: Unit = (1, -1)
FARAD: Unit = (-1, 1)
PER_AMP: Unit = (0, -1)
#: A tuning entry with one value per state of its estimator (the process noise): each state's
#: variance, its unit read from the state's name (``estimators/*.py``: ``soc``, ``*_v``).
PER_STATE_VARIANCE = "per_state_variance"

#: Every filter tuning key (``filters.<estimator or preset>.<key>``, the estimators'
#: ``default_tuning``) and its unit, read from the estimator modules and docs/identification.md.
#: A key missing here is refused by :func:`scale_battery` (it cannot be silently mis-scaled);
#: ``test_scaling`` checks that every estimator's keys are here.
TUNING_UNITS: dict[str, Unit | str] = {
    # coulomb.py: the current sensor's white noise (A), gain error (fraction), offset (A)
    "current_std_a": AMP,
    "gain_error": NONE,
    "offset_a": AMP,
    # ekf.py, rc_kf.py, t2rc_ukf.py: process noise per second (SoC^2/s or V^2/s per state),
    # measurement variance r (V^2), initial branch / terminal voltage variances (V^2)
    "q_diag": PER_STATE_VARIANCE,
    "r": VOLT2,
    "p0_v": VOLT2,
    "p0_vo": VOLT2,
    "alpha": NONE,  # sigma points: dimensionless
    "beta": NONE,
    "kappa": NONE,
    # dcc_ekf.py: the EKF-only phase (s) and the "null current" (A)
    "converge_time_s": NONE,
    "rest_current_a": AMP,
    # hybrid.py: measurement std per ampere (V/A), the update gate (C), rest test (A, s), OCV
    # std (V), NIS watch (s, dimensionless, SoC^2/s), the bias state (V, s), temperature scale
    # (degC), the guard's budget (A, fractions, probability, s, SoC)
    "r_per_a": OHM,
    "update_c_rate_max": NONE,
    "update_charge_c_rate_max": NONE,
    "update_soc_min": NONE,
    "rest_filter_tau_s": NONE,
    "rest_min_s": NONE,
    "ocv_std_v": VOLT,
    "nis_tau_s": NONE,
    "nis_gate": NONE,
    "q_inflate": NONE,
    "bias_std_v": VOLT,
    "bias_tau_s": NONE,
    "extrapolation_scale_c": NONE,
    "current_offset_std_a": AMP,
    "current_gain_std": NONE,
    "capacity_std_frac": NONE,
    "model_prior": NONE,
    "follow_tau_s": NONE,
    "follow_sure_tau_s": NONE,
    "model_soc_std": NONE,
    "flat_soc_std_max": NONE,  # SoC
    "ocv_axis_std_frac": NONE,  # a fraction of the capacity
    "outside_follow_soc_max": NONE,  # SoC
    # fractions of the file's own 5-s pulse resistance, which the scaling carries
    "resistance_std_frac": NONE,
    "resistance_drift_frac_per_h": NONE,
    # item 9: SoC fractions and a count of std
    "ocv_soc_resolution_max": NONE,
    "ocv_contradiction_sigma": NONE,
    "flat_load_soc_std_min": NONE,
    # item 11: a count of std
    "persistent_innovation_sigma": NONE,
    # item 12: SoC std and a count of grid points
    "grid_soc_std_min": NONE,
    "grid_soc_std_off": NONE,
    "grid_points": NONE,
}

#: The unit of each field of the file's sections that carries one (the others are SoC,
#: temperatures, seconds, C-rates or fractions; ``test_scaling`` checks that every field named
#: with a volt or ampere unit is here).
LIMITS_UNITS: dict[str, Unit] = {
    "voltage_min_v": VOLT,
    "voltage_max_v": VOLT,
    "current_max_discharge_a": AMP,
    "current_max_charge_a": AMP,
}
CHARGE_UNITS: dict[str, Unit] = {"voltage_v": VOLT, "voltage_tolerance_v": VOLT}
HEALTH_UNITS: dict[str, Unit] = {
    "ocv_std_v": VOLT,
    "voltage_noise_std_v": VOLT,
    "current_offset_std_a": AMP,
    "current_noise_std_a": AMP,
}
RC_MODEL_UNITS: dict[str, Unit] = {
    "c_b_f": FARAD,
    "c_s_f": FARAD,
    "r_b_ohm": OHM,
    "r_s_ohm": OHM,
    "r_t_ohm": OHM,
}


class _Factors:
    """The factor of each unit for ``n`` times the cells in series and ``q`` times the
    capacity: ``n ** volt_exponent * q ** ampere_exponent``."""

    def __init__(self, n: float, q: float) -> None:
        self.n, self.q = n, q

    def of(self, unit: Unit) -> float:
        volt, amp = unit
        return self.n**volt * self.q**amp


def scale_battery(
    battery: BatteryParams,
    cells_in_series: int | None = None,
    capacity_ah: float | None = None,
) -> BatteryParams:
    """``battery`` scaled to a pack of ``cells_in_series`` cells and a rated capacity of
    ``capacity_ah`` (the label's Ah, the file's ``nominal_capacity_ah``; the measured
    ``capacity_ah`` scales by the same ratio); None keeps the file's.

    The rule is the module docstring's. The filter tunings scaled are the ones each estimator
    runs with on this file: a tuning block per estimator (and each preset block of the file)
    holds the file's entries and the estimator's defaults that carry a unit, scaled, so every
    estimator behaves on the scaled pack as on the file's. Returns a new object (the same
    values for the file's own pack); ``ValueError`` for a bad count or capacity, a tuning key
    or block of unknown unit, or a result the file schema refuses.
    """
    cells = _checked_cells(battery.cells_in_series if cells_in_series is None else cells_in_series)
    rated_ah = _checked_capacity(
        battery.nominal_capacity_ah if capacity_ah is None else capacity_ah
    )
    n = cells / battery.cells_in_series
    q = rated_ah / battery.nominal_capacity_ah
    if n == 1.0 and q == 1.0:
        return replace(battery)
    f = _Factors(n, q)
    scaled = replace(
        battery,
        name=f"{battery.name} scaled to {cells}S {rated_ah:g} Ah",
        source=_scaled_source(battery, cells, rated_ah),
        nominal_capacity_ah=rated_ah,
        capacity_ah=battery.capacity_ah * q,
        cells_in_series=cells,
        limits=_scale_fields(battery.limits, LIMITS_UNITS, f),
        ocv=_scale_ocv(battery.ocv, f),
        rest_ocv=None if battery.rest_ocv is None else _scale_ocv(battery.rest_ocv, f),
        rc_model=_scale_fields(battery.rc_model, RC_MODEL_UNITS, f),
        thevenin=_scale_thevenin(battery.thevenin, f),
        filters=_scale_filters(battery.filters, f),
        charge=_scale_fields(battery.charge, CHARGE_UNITS, f),
        health=_scale_fields(battery.health, HEALTH_UNITS, f),
    )
    try:  # the file schema's bounds hold for the scaled pack too
        parse_battery_params(battery_params_to_dict(scaled), scaled.name)
    except ValueError as exc:
        raise ValueError(f"the scaled file is not a valid battery file: {exc}") from exc
    return scaled


def _checked_cells(cells: Any) -> int:
    if isinstance(cells, bool) or not isinstance(cells, int) or cells < 1:
        raise ValueError(f"cells_in_series must be an integer >= 1, got {cells!r}")
    return cells


def _checked_capacity(capacity_ah: Any) -> float:
    ok = not isinstance(capacity_ah, bool) and isinstance(capacity_ah, (int, float))
    if not ok or not (math.isfinite(capacity_ah) and capacity_ah > 0.0):
        raise ValueError(f"capacity_ah must be a finite number > 0, got {capacity_ah!r}")
    return float(capacity_ah)


def _scaled_source(battery: BatteryParams, cells: int, rated_ah: float) -> str:
    note = (
        f"scaled by soc_estimator_ros.scaling from {battery.cells_in_series}S "
        f"{battery.nominal_capacity_ah:g} Ah to {cells}S {rated_ah:g} Ah"
    )
    return f"{battery.source}; {note}" if battery.source else note


def _scale_fields(section: Any, units: Mapping[str, Unit], f: _Factors) -> Any:
    """A copy of the dataclass ``section`` with each field of ``units`` scaled (None kept)."""
    changes = {}
    for name, unit in units.items():
        value = getattr(section, name)
        if value is not None:
            changes[name] = value * f.of(unit)
    return replace(section, **changes)


def _scale_table(table: ParamTable, factor: float) -> ParamTable:
    values = tuple(tuple(v * factor for v in row) for row in table.values)
    return ParamTable(soc=table.soc, values=values, temperature_c=table.temperature_c)


def _scale_ocv(ocv: OcvTable, f: _Factors) -> OcvTable:
    """The OCV points and their temperature offsets, volts."""
    k = f.of(VOLT)
    return replace(
        ocv,
        voltage_v=tuple(v * k for v in ocv.voltage_v),
        offset_v=tuple(tuple(v * k for v in row) for row in ocv.offset_v),
    )


def _scale_branch(branch: RcBranch, f: _Factors) -> RcBranch:
    return RcBranch(
        r_ohm=_scale_table(branch.r_ohm, f.of(OHM)),
        c_f=_scale_table(branch.c_f, f.of(FARAD)),
        i_sat_a=None if branch.i_sat_a is None else _scale_table(branch.i_sat_a, f.of(AMP)),
    )


def _scale_thevenin(th: TheveninParams, f: _Factors) -> TheveninParams:
    """R0 and branch resistances (ohm), capacitances (F), saturation and exchange currents (A),
    the kinetic amplitude (V) and the surface lag's gain (SoC per A); the extrapolation's
    activation energy and margin, the lag's time constants and SoC limits and the fitted C-rate
    (a current per Ah) are kept."""
    kinetic = th.kinetic
    if kinetic is not None:
        kinetic = KineticParams(
            a_v=_scale_table(kinetic.a_v, f.of(VOLT)),
            i0_a=_scale_table(kinetic.i0_a, f.of(AMP)),
        )
    lag = th.surface_lag
    if lag is not None:
        k = f.of(PER_AMP)
        lag = SurfaceLag(
            gain_soc_per_a=tuple(g * k for g in lag.gain_soc_per_a),
            tau_s=lag.tau_s,
            soc_max=lag.soc_max,
        )
    return replace(
        th,
        r0_ohm=_scale_table(th.r0_ohm, f.of(OHM)),
        branches=tuple(_scale_branch(b, f) for b in th.branches),
        kinetic=kinetic,
        surface_lag=lag,
    )


def _estimator_of_block(block: str) -> type[Estimator]:
    est = PRESETS.get(block, block)
    if est not in ESTIMATORS:
        known = ", ".join(sorted([*ESTIMATORS, *PRESETS]))
        raise ValueError(
            f"filters.{block}: not an estimator or preset ({known}): the units of its "
            "entries are unknown, so it cannot be scaled"
        )
    return ESTIMATORS[est]


def _state_variance_unit(cls: type[Estimator], state: str) -> Unit:
    """The unit of a state's variance, from the state's name (``soc``, ``*_v``)."""
    if state == "soc":
        return NONE
    if state.endswith("_v"):
        return VOLT2
    raise ValueError(f"{cls.name}: state {state!r} has no known unit (soc or *_v)")


def _scale_entry(
    cls: type[Estimator], block: str, key: str, value: float | tuple[float, ...], f: _Factors
) -> float | tuple[float, ...]:
    unit = TUNING_UNITS.get(key)
    if unit is None:
        raise ValueError(
            f"filters.{block}.{key}: a tuning key of unknown unit; add it to "
            "soc_estimator_ros/scaling.py TUNING_UNITS before scaling this file"
        )
    if unit == PER_STATE_VARIANCE:
        values = value if isinstance(value, tuple) else (value,)
        if len(values) > len(cls.state_names):
            raise ValueError(
                f"filters.{block}.{key}: {len(values)} values for the "
                f"{len(cls.state_names)} states {cls.state_names}"
            )
        return tuple(
            v * f.of(_state_variance_unit(cls, s))
            for v, s in zip(values, cls.state_names, strict=False)
        )
    assert isinstance(unit, tuple)
    k = f.of(unit)
    if isinstance(value, tuple):
        return tuple(v * k for v in value)
    return value * k


def _scale_filters(
    filters: Mapping[str, Mapping[str, float | tuple[float, ...]]], f: _Factors
) -> dict[str, dict[str, float | tuple[float, ...]]]:
    """Each block of ``filters`` and a block per estimator that has none, holding the block's
    entries over the estimator's defaults that carry a unit, every entry scaled by its unit
    (:data:`TUNING_UNITS`): the tuning each estimator runs with, for the scaled pack."""
    blocks = [*filters, *(name for name in ESTIMATORS if name not in filters)]
    out: dict[str, dict[str, float | tuple[float, ...]]] = {}
    for block in blocks:
        cls = _estimator_of_block(block)
        given = filters.get(block, {})
        defaults = {
            k: v
            for k, v in cls.default_tuning.items()
            if k not in given and TUNING_UNITS.get(k) != NONE  # unknown: refused below
        }
        entries = {**given, **defaults}
        out[block] = {k: _scale_entry(cls, block, k, v, f) for k, v in entries.items()}
    return out


def scale_to_pack(
    battery: BatteryParams, cells_in_series: int, capacity_ah: float
) -> BatteryParams:
    """:func:`scale_battery` with the node's and ``soc_replay``'s convention: 0 keeps the
    file's value (``cells_in_series`` and ``capacity_ah`` parameters, ``--cells-in-series``,
    ``--capacity-ah``)."""
    return scale_battery(
        battery,
        cells_in_series if cells_in_series else None,
        capacity_ah if capacity_ah else None,
    )
