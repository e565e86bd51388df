"""Battery parameter files: the schema (``schema.py``: dataclasses and bounds), a loader that
validates everything (``parse.py``) and the one checked writer (``write.py``); import from here.

One YAML file describes one battery (pack level): chemistry, capacity, limits, the OCV table,
the Saft RC model, the n-RC Thevenin model as tables over SoC (temperature optional), the
default filter tunings, and optionally the low-battery levels (``levels:``), the charger's
CC-CV end (``charge:``) and how health is learned (``health:``). ``config/*.yaml`` are
examples; docs/battery_files.md documents every key.

Every problem in a file raises :class:`ParamFileError` with one message that names the file,
the key (dotted path), the value found and what was expected, e.g.::

    config/bad.yaml: thevenin.branches[1].r_ohm[3] = -0.01: expected a number > 0
"""

from .parse import load_battery_params, parse_battery_params
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
from .write import battery_params_to_dict, output_dir_error, write_battery_file

__all__ = [
    "ABSURD",
    "ABSURD_TUNING",
    "CELL_BOUNDS",
    "CHEMISTRIES",
    "HEALTH_BOUNDS",
    "SCHEMA_VERSION",
    "SOC_STEP_MIN",
    "BatteryParams",
    "CellSettings",
    "ChargeSettings",
    "HealthSettings",
    "LevelSettings",
    "Limits",
    "OcvTable",
    "ParamFileError",
    "battery_params_to_dict",
    "load_battery_params",
    "output_dir_error",
    "parse_battery_params",
    "write_battery_file",
]
