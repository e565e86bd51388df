"""Write a battery file: the plain-YAML form of :class:`~.schema.BatteryParams`, and the one
writer that checks a file with :mod:`.parse`'s rules before it is written."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import asdict
from pathlib import Path
from typing import Any

import yaml

from ..models.rc_saft import RcModelParams
from ..models.tables import ParamTable
from ..models.thevenin import TemperatureExtrapolation
from .parse import parse_battery_params
from .schema import SCHEMA_VERSION, BatteryParams, CellSettings, HealthSettings, Limits


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
