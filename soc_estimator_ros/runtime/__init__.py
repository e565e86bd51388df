"""What the robot asks next, ROS-free: time to empty and to full, state of power
(``prediction``), graded low-battery levels (``levels``), the charge state and FULL
(``charging``), and the monitor that runs them beside the tracker's estimator (``monitor``)."""

from __future__ import annotations

from .charging import ChargeMonitor, ChargePhase, ChargeSpec
from .levels import BatteryLevel, LevelChange, LevelMonitor, LevelThresholds
from .monitor import Notice, PredictionInput, RuntimeConfig, RuntimeMonitor, RuntimeReport
from .prediction import (
    LoadForecast,
    PackState,
    PowerWindow,
    StateOfPower,
    TimeToEmpty,
    max_current_a,
    state_of_power,
    time_to_empty,
    time_to_full,
)

__all__ = [
    "BatteryLevel",
    "ChargeMonitor",
    "ChargePhase",
    "ChargeSpec",
    "LevelChange",
    "LevelMonitor",
    "LevelThresholds",
    "LoadForecast",
    "Notice",
    "PackState",
    "PowerWindow",
    "PredictionInput",
    "RuntimeConfig",
    "RuntimeMonitor",
    "RuntimeReport",
    "StateOfPower",
    "TimeToEmpty",
    "max_current_a",
    "state_of_power",
    "time_to_empty",
    "time_to_full",
]
