"""The node's parameters: one table (:data:`PARAMETERS`) for declaration, ``--help`` and
docs/node.md, and the parsing of the values that need it.

ROS is imported only to build a descriptor (:meth:`ParamSpec.descriptor`), so the table can be
read (``--help``, the docs generator) without a ROS context.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ..errors import SocEstimatorError
from ..estimators import DEFAULT_ESTIMATOR, ESTIMATORS, PRESETS
from ..params import LevelSettings
from ..resources import BUNDLED_FILES, DEFAULT_CHEMISTRY, PACKAGE

NODE_NAME = "soc_estimator_node"
KNOWN_ESTIMATORS = tuple(sorted([*ESTIMATORS, *PRESETS]))


class NodeConfigError(SocEstimatorError, ValueError):
    """A parameter value the node cannot start with."""


@dataclass(frozen=True)
class ParamSpec:
    """One node parameter: name, default, description and constraints (for declare and --help)."""

    name: str
    default: Any
    description: str
    read_only: bool = True
    float_range: tuple[float, float] | None = None
    int_range: tuple[int, int] | None = None
    constraints: str = ""
    #: Accept any type (``initial_soc``: ``-p initial_soc:=0.8`` arrives as a double).
    dynamic_typing: bool = False

    def descriptor(self) -> Any:
        """The rcl ``ParameterDescriptor`` for this parameter (imports ROS only here)."""
        from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor

        d = ParameterDescriptor(
            name=self.name,
            description=self.description,
            read_only=self.read_only,
            additional_constraints=self.constraints,
            dynamic_typing=self.dynamic_typing,
        )
        if self.float_range is not None:
            d.floating_point_range = [
                FloatingPointRange(
                    from_value=float(self.float_range[0]),
                    to_value=float(self.float_range[1]),
                    step=0.0,
                )
            ]
        if self.int_range is not None:
            d.integer_range = [
                IntegerRange(
                    from_value=int(self.int_range[0]), to_value=int(self.int_range[1]), step=1
                )
            ]
        return d


PARAMETERS: tuple[ParamSpec, ...] = (
    ParamSpec(
        "estimator",
        DEFAULT_ESTIMATOR,
        "SoC estimator; settable at run time (switches, keeping the SoC)",
        read_only=False,
        constraints="one of " + ", ".join(KNOWN_ESTIMATORS),
    ),
    ParamSpec(
        "battery_file",
        "",
        "battery parameter file (YAML); empty = the bundled " + BUNDLED_FILES[DEFAULT_CHEMISTRY],
    ),
    ParamSpec(
        "cells_in_series",
        0,
        "cells in series of this pack: the battery file is scaled to it (docs/battery_files.md"
        "); 0 = the file's. BatteryState.cell_voltage with this many values runs the per-cell "
        "SoC (docs/cells.md)",
        int_range=(0, 1000),
    ),
    ParamSpec(
        "capacity_ah",
        0.0,
        "rated capacity (Ah) of this pack: the battery file is scaled to it; 0 = the file's",
        float_range=(0.0, 100000.0),
    ),
    ParamSpec("state_topic", "battery/state", "input sensor_msgs/BatteryState topic"),
    ParamSpec("output_topic", "battery/soc", "output sensor_msgs/BatteryState topic"),
    ParamSpec(
        "estimate_topic",
        "battery/soc_estimate",
        "output std_msgs/Float64MultiArray topic (full estimator state, labelled layout)",
    ),
    ParamSpec(
        "runtime_topic",
        "battery/runtime",
        "output std_msgs/Float64MultiArray topic (time to empty/full, state of power, level; "
        "labelled layout), once a second of sample time",
    ),
    ParamSpec(
        "current_topic",
        "",
        "separate current topic (std_msgs Float32/64, A); with voltage_topic replaces state_topic",
    ),
    ParamSpec("voltage_topic", "", "separate voltage topic (std_msgs Float32/64, V)"),
    ParamSpec(
        "scalar_type",
        "float32",
        "type of current_topic/voltage_topic",
        constraints="float32|float64",
    ),
    ParamSpec(
        "current_sign",
        "ros",
        "sign of current_topic: 'ros' (negative while discharging) or 'discharge_positive'",
        constraints="ros|discharge_positive",
    ),
    ParamSpec(
        "pair_tolerance_s",
        0.05,
        "max receive-time difference (s) between a paired current and voltage reading",
        float_range=(0.0, 10.0),
    ),
    ParamSpec(
        "input_reliability",
        "best_effort",
        "input QoS reliability; best_effort matches every publisher, reliable is lossless "
        "from a reliable publisher",
        constraints="best_effort|reliable",
    ),
    ParamSpec(
        "qos_depth", 50, "history depth of the input and output topics", int_range=(1, 10000)
    ),
    ParamSpec(
        "initial_soc",
        "resume",
        "initial SoC: a fraction (0.8 or '0.8'), 'ocv' (from the first sample's voltage) or "
        "'resume' (saved state if recent, else ocv)",
        dynamic_typing=True,
    ),
    ParamSpec(
        "initial_soc_std",
        0.1,
        "std of a numeric initial_soc (fraction)",
        float_range=(1e-4, 1.0),
    ),
    ParamSpec(
        "ocv_voltage_std_v",
        0.05,
        "voltage uncertainty (V) when a voltage is read as an OCV (initial 'ocv', reset)",
        float_range=(1e-4, 5.0),
    ),
    ParamSpec(
        "publish_rate_hz",
        0.0,
        "output rate (Hz): battery/soc once per 1/rate s of sample time, right after the "
        "sample it carries (node/output_rate.py); 0 = on every accepted sample",
        float_range=(0.0, 1000.0),
    ),
    ParamSpec(
        "filter_rate_hz",
        0.0,
        "filter steps per second (Hz): the samples between two steps are counted as charge "
        "and their voltages averaged, and still published; 0 = a step on every sample. "
        "10 suits a 50-100 Hz bridge (docs/node.md)",
        float_range=(0.0, 1000.0),
    ),
    ParamSpec("location", "", "BatteryState.location; empty = copied from the input", False),
    ParamSpec(
        "serial_number", "", "BatteryState.serial_number; empty = copied from the input", False
    ),
    ParamSpec(
        "state_file",
        "",
        "persistence file; empty = $ROS_HOME (~/.ros)/soc_estimator_ros/<node name>.yaml, "
        "'none' = no persistence",
    ),
    ParamSpec(
        "learn_health",
        False,
        "learn the pack's full capacity and R0 factor online (health/), publish them "
        "(BatteryState.capacity, power_supply_health DEAD below health.soh_dead, diagnostics, "
        "soc_estimate) and keep them in the state file across restarts",
    ),
    ParamSpec(
        "save_period_s",
        5.0,
        "period (s) of state saves; 0 = only on shutdown",
        float_range=(0.0, 86400.0),
    ),
    ParamSpec(
        "resume_max_age_s",
        3600.0,
        "a saved state older than this (s, vs the first sample's stamp) is not resumed",
        float_range=(0.0, 1.0e9),
    ),
    ParamSpec(
        "stale_timeout_s",
        2.0,
        "samples older than the newest accepted one by more (s) are 'stale'; no accepted "
        "sample for this long (s) is reported as stale input",
        float_range=(1e-3, 3600.0),
    ),
    ParamSpec(
        "stale_vs_clock",
        False,
        "also reject samples whose stamp is older than the node clock by stale_timeout_s "
        "(needs synchronized clocks or use_sim_time with a /clock)",
    ),
    ParamSpec(
        "time_jump_s",
        10.0,
        "a stamp running ahead of the node clock's own advance by more (s) is a clock jump: "
        "rejected, and the time base re-anchored once the source stays on the new time line",
        float_range=(1e-3, 86400.0),
    ),
    ParamSpec(
        "voltage_absurd_min_v",
        -1.0,
        "voltages below (V) are sensor faults; < 0 = 0.5 x limits.voltage_min_v",
        float_range=(-1.0, 1000.0),
    ),
    ParamSpec(
        "voltage_absurd_max_v",
        -1.0,
        "voltages above (V) are sensor faults; < 0 = 1.5 x limits.voltage_max_v",
        float_range=(-1.0, 1000.0),
    ),
    ParamSpec(
        "current_absurd_factor",
        2.0,
        "currents beyond this factor x the battery's current limits are sensor faults",
        float_range=(1.0, 100.0),
    ),
    ParamSpec(
        "low_soc_warn",
        -1.0,
        "level WARN (diagnostics WARN) below this SoC; < 0 = the battery file's "
        "levels.warn_soc, else the critical level + 0.1",
        read_only=False,
        float_range=(-1.0, 1.0),
    ),
    ParamSpec(
        "low_soc_error",
        -1.0,
        "level CRITICAL (diagnostics ERROR) below this SoC; < 0 = the battery file's "
        "levels.critical_soc, else limits.soc_min",
        read_only=False,
        float_range=(-1.0, 1.0),
    ),
    ParamSpec(
        "low_soc_emergency",
        -1.0,
        "level EMERGENCY (diagnostics ERROR) below this SoC; < 0 = the battery file's "
        "levels.emergency_soc, else the critical level - 0.05 (at least 0)",
        read_only=False,
        float_range=(-1.0, 1.0),
    ),
    ParamSpec(
        "low_soc_hysteresis",
        -1.0,
        "a level clears once the SoC is this far above its threshold; < 0 = the battery "
        "file's levels.hysteresis_soc, else 0.02",
        read_only=False,
        float_range=(-1.0, 0.5),
    ),
    ParamSpec(
        "low_soc_debounce_s",
        -1.0,
        "a level changes once its condition held this long (s, sample time); < 0 = the "
        "battery file's levels.debounce_s, else 30",
        read_only=False,
        float_range=(-1.0, 3600.0),
    ),
    ParamSpec(
        "idle_current_a",
        0.1,
        "|current| (A) at or below which power_supply_status is NOT_CHARGING (DISCHARGING "
        "beyond it); a FULL pack is released when its low-passed discharge exceeds it",
        read_only=False,
        float_range=(0.0, 100.0),
    ),
    ParamSpec(
        "charging_current_a",
        0.5,
        "charge current (A) above which power_supply_status is CHARGING (Nav2's docking "
        "charging_threshold)",
        float_range=(0.0, 100.0),
    ),
    ParamSpec(
        "runtime_window_s",
        300.0,
        "the time-to-empty load forecast: the mean discharge power over this window (s)",
        float_range=(10.0, 86400.0),
    ),
    ParamSpec(
        "mission_power_w",
        0.0,
        "the load (W) the time to empty assumes, set by the robot for its mission; "
        "0 = the mean over runtime_window_s",
        read_only=False,
        float_range=(0.0, 100000.0),
    ),
    ParamSpec(
        "reset_soc_to",
        -1.0,
        "set at run time to a SoC in [0, 1] to reset the estimate to it; -1 = no reset",
        read_only=False,
        float_range=(-1.0, 1.0),
    ),
    ParamSpec(
        "reset_soc_std",
        0.05,
        "std (fraction) of the SoC after a reset_soc_to reset",
        read_only=False,
        float_range=(1e-4, 1.0),
    ),
)


def default_state_file(node_name: str, namespace: str = "/") -> Path:
    """``$ROS_HOME/soc_estimator_ros/<node>.yaml`` (``ROS_HOME`` defaults to ``~/.ros``)."""
    ros_home = Path(os.environ.get("ROS_HOME") or Path.home() / ".ros")
    ns = namespace.strip("/").replace("/", "__")
    stem = f"{ns}__{node_name}" if ns else node_name
    return ros_home / PACKAGE / f"{stem}.yaml"


def parse_initial_soc(value: str | float | int) -> float | str:
    """``initial_soc``: a fraction in [0, 1] (number or text), ``'ocv'`` or ``'resume'``."""
    if isinstance(value, bool) or not isinstance(value, (str, float, int)):
        raise NodeConfigError(
            f"initial_soc = {value!r}: expected a fraction in [0, 1], 'ocv' or 'resume'"
        )
    text = str(value)
    t = text.strip().lower()
    if t in ("ocv", "resume"):
        return t
    try:
        value = float(t)
    except ValueError:
        raise NodeConfigError(
            f"initial_soc = {text!r}: expected a fraction in [0, 1], 'ocv' or 'resume'"
        ) from None
    if not 0.0 <= value <= 1.0:
        raise NodeConfigError(f"initial_soc = {text!r}: expected a fraction in [0, 1]")
    return value


def usage() -> str:
    """The ``--help`` text: what the node does and its parameters."""
    lines = [
        f"usage: ros2 run {PACKAGE} {NODE_NAME} [--ros-args -p NAME:=VALUE ...]",
        "",
        "Live battery SoC estimator: subscribes to battery/state (sensor_msgs/BatteryState),",
        "publishes battery/soc (BatteryState), battery/soc_estimate and battery/runtime",
        "(Float64MultiArray) and /diagnostics; service ~/reset_soc_from_ocv (std_srvs/Trigger).",
        "",
        "parameters:",
    ]
    for spec in PARAMETERS:
        flag = "" if spec.read_only else " [run-time]"
        lines.append(f"  {spec.name} (default {spec.default!r}){flag}")
        lines.append(f"      {spec.description}")
    return "\n".join(lines)


def parameter_table() -> str:
    """docs/node.md's parameter table (Markdown), from :data:`PARAMETERS`."""
    rows = [
        "| Parameter | Default | Run-time | Description |",
        "|---|---|---|---|",
    ]
    for spec in PARAMETERS:
        desc = spec.description
        if spec.constraints:
            desc += f" ({spec.constraints})"
        runtime = "" if spec.read_only else "yes"
        rows.append(f"| `{spec.name}` | `{spec.default!r}` | {runtime} | {desc} |")
    return "\n".join(rows)


#: The level parameters and the ``LevelSettings`` entries they override.
LEVEL_PARAMETERS = {
    "low_soc_warn": "warn_soc",
    "low_soc_error": "critical_soc",
    "low_soc_emergency": "emergency_soc",
    "low_soc_hysteresis": "hysteresis_soc",
    "low_soc_debounce_s": "debounce_s",
}


def level_overrides(values: dict[str, float]) -> LevelSettings:
    """The level parameters as overrides: a value < 0 leaves the entry to the battery file
    (or the rule)."""
    return LevelSettings(
        **{
            field_name: (None if float(values[name]) < 0.0 else float(values[name]))
            for name, field_name in LEVEL_PARAMETERS.items()
        }
    )
