"""Read a battery file: every value checked against :mod:`.schema`'s rules, the first fault
raised as :class:`~.schema.ParamFileError` naming the file, key, value and expectation."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import yaml

from ..models.hysteresis import Hysteresis
from ..models.rc_saft import RcModelParams
from ..models.tables import ParamTable
from ..models.thevenin import (
    KineticParams,
    RcBranch,
    SurfaceLag,
    TemperatureExtrapolation,
    TheveninParams,
)
from .schema import (
    ABSURD,
    ABSURD_TUNING,
    CELL_BOUNDS,
    CHEMISTRIES,
    HEALTH_BOUNDS,
    SCHEMA_VERSION,
    SOC_STEP_MIN,
    BatteryParams,
    CellSettings,
    ChargeSettings,
    HealthSettings,
    LevelSettings,
    Limits,
    OcvTable,
    ParamFileError,
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


def _absurd_for(cells: int) -> dict[str, tuple[float, float]]:
    """ABSURD's ranges for one pack: its "per cell" ones times ``cells`` in series."""
    return {
        k.removesuffix("_per_cell"): (lo * cells, hi * cells)
        if k.endswith("_per_cell")
        else (lo, hi)
        for k, (lo, hi) in ABSURD.items()
    }


def _parse_limits(
    chk: _Checker, root: Mapping[str, Any], absurd: dict[str, tuple[float, float]]
) -> Limits:
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
    return Limits(
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


def _parse_ocv(
    chk: _Checker, root: Mapping[str, Any], absurd: dict[str, tuple[float, float]], cells: int
) -> OcvTable:
    ocv_node = chk.mapping(chk.get(root, "ocv", ""), "ocv")
    ocv_soc, ocv_v = _ocv_points(chk, ocv_node, "ocv", absurd["voltage_v"])
    if "temperature_c" not in ocv_node and "offset_v" not in ocv_node:
        return OcvTable(soc=ocv_soc, voltage_v=ocv_v)
    ocv_temps = chk.numbers(chk.get(ocv_node, "temperature_c", "ocv"), "ocv.temperature_c")
    for i, t in enumerate(ocv_temps):
        chk.within(t, f"ocv.temperature_c[{i}]", absurd["temperature_c"])
    chk.increasing(ocv_temps, "ocv.temperature_c")
    rows = chk.get(ocv_node, "offset_v", "ocv")
    if (
        isinstance(rows, (str, bytes))
        or not isinstance(rows, Sequence)
        or len(rows) != len(ocv_temps)
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
    return OcvTable(soc=ocv_soc, voltage_v=ocv_v, temperature_c=ocv_temps, offset_v=tuple(parsed))


def _parse_rc_model(
    chk: _Checker, root: Mapping[str, Any], absurd: dict[str, tuple[float, float]]
) -> RcModelParams:
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
    return rc_params


class _TableGrid:
    """What every Thevenin table is checked against: the SoC and temperature axes, the ranges."""

    def __init__(
        self,
        chk: _Checker,
        soc: tuple[float, ...],
        temps: tuple[float, ...],
        absurd: dict[str, tuple[float, float]],
    ) -> None:
        self.chk, self.soc, self.temps, self.absurd = chk, soc, temps, absurd

    def table(self, node: Any, key: str, unit: str) -> ParamTable:
        return self.chk.table(node, key, self.soc, self.temps, self.absurd[unit])


def _parse_branches(grid: _TableGrid, th: Mapping[str, Any]) -> tuple[RcBranch, ...]:
    chk = grid.chk
    branches_node = chk.get(th, "branches", "thevenin")
    if isinstance(branches_node, (str, bytes)) or not isinstance(branches_node, Sequence):
        raise chk.fail("thevenin.branches", branches_node, "a list of {r_ohm, c_f} branches")
    if not 1 <= len(branches_node) <= 3:
        raise chk.fail("thevenin.branches", branches_node, "1 to 3 RC branches")
    branches = []
    for i, b in enumerate(branches_node):
        key = f"thevenin.branches[{i}]"
        bm = chk.mapping(b, key)
        r_ohm = grid.table(chk.get(bm, "r_ohm", key), f"{key}.r_ohm", "resistance_ohm")
        c_f = grid.table(chk.get(bm, "c_f", key), f"{key}.c_f", "capacitance_f")
        i_sat = bm.get("i_sat_a")
        i_sat_a = None if i_sat is None else grid.table(i_sat, f"{key}.i_sat_a", "current_a")
        branches.append(RcBranch(r_ohm=r_ohm, c_f=c_f, i_sat_a=i_sat_a))
    return tuple(branches)


def _parse_kinetic(grid: _TableGrid, th: Mapping[str, Any]) -> KineticParams | None:
    if th.get("kinetic") is None:
        return None
    key = "thevenin.kinetic"
    km = grid.chk.mapping(th["kinetic"], key)
    return KineticParams(
        *(
            grid.table(grid.chk.get(km, k, key), f"{key}.{k}", unit)
            for k, unit in (("a_v", "kinetic_scale_v"), ("i0_a", "current_a"))
        )
    )


def _parse_surface_lag(chk: _Checker, th: Mapping[str, Any]) -> SurfaceLag | None:
    if th.get("surface_lag") is None:
        return None
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
    return SurfaceLag(**modes)


def _parse_extrapolation(chk: _Checker, th: Mapping[str, Any]) -> TemperatureExtrapolation:
    default = TemperatureExtrapolation()
    if th.get("extrapolation") is None:
        return default
    key = "thevenin.extrapolation"
    em = chk.mapping(th["extrapolation"], key)
    return TemperatureExtrapolation(
        activation_energy_j_per_mol=chk.number(
            em.get("activation_energy_j_per_mol", default.activation_energy_j_per_mol),
            f"{key}.activation_energy_j_per_mol",
            0.0,
            2.0e5,
        ),
        margin_c=chk.number(em.get("margin_c", default.margin_c), f"{key}.margin_c", 0.0, 100.0),
    )


def _parse_thevenin(
    chk: _Checker, root: Mapping[str, Any], absurd: dict[str, tuple[float, float]]
) -> TheveninParams:
    th = chk.mapping(chk.get(root, "thevenin", ""), "thevenin")
    th_soc = chk.numbers(chk.get(th, "soc", "thevenin"), "thevenin.soc")
    for i, s in enumerate(th_soc):
        chk.number(s, f"thevenin.soc[{i}]", 0.0, 1.0)
    chk.increasing(th_soc, "thevenin.soc", SOC_STEP_MIN)
    temps = chk.numbers(th.get("temperature_c", [25.0]), "thevenin.temperature_c")
    for i, t in enumerate(temps):
        chk.within(t, f"thevenin.temperature_c[{i}]", absurd["temperature_c"])
    chk.increasing(temps, "thevenin.temperature_c")
    grid = _TableGrid(chk, th_soc, temps, absurd)
    r0 = grid.table(chk.get(th, "r0_ohm", "thevenin"), "thevenin.r0_ohm", "resistance_ohm")
    branches = _parse_branches(grid, th)
    kinetic = _parse_kinetic(grid, th)
    surface_lag = _parse_surface_lag(chk, th)
    extrapolation = _parse_extrapolation(chk, th)
    fitted_c_rate_max = None
    if th.get("fitted_c_rate_max") is not None:
        fitted_c_rate_max = chk.number(
            th["fitted_c_rate_max"], "thevenin.fitted_c_rate_max", 1.0e-3, 1.0e3
        )
    return TheveninParams(
        r0_ohm=r0,
        branches=branches,
        kinetic=kinetic,
        surface_lag=surface_lag,
        extrapolation=extrapolation,
        fitted_c_rate_max=fitted_c_rate_max,
    )


def parse_battery_params(raw: Any, source: str = "<memory>") -> BatteryParams:
    """Validate a raw YAML tree (already parsed) and build :class:`BatteryParams`, section by
    section in the file's order (the first fault found is the one raised)."""
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
    absurd = _absurd_for(cells)
    eta = chk.number(
        chk.get(root, "coulomb_efficiency_charge", ""), "coulomb_efficiency_charge", 0.5, 1.0
    )
    source_text = root.get("source", "")
    if not isinstance(source_text, str):
        raise chk.fail("source", source_text, "a string")
    limits = _parse_limits(chk, root, absurd)
    ocv = _parse_ocv(chk, root, absurd, cells)
    rc_model = _parse_rc_model(chk, root, absurd)
    thevenin = _parse_thevenin(chk, root, absurd)
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
        ocv=ocv,
        rest_ocv=_parse_rest_ocv(chk, root, absurd["voltage_v"]),
        hysteresis=_parse_hysteresis(chk, root),
        rc_model=rc_model,
        thevenin=thevenin,
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
