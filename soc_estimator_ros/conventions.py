"""Sign and unit conventions of the estimation core, and the conversions at its edges.

Inside the core, one convention holds everywhere:

* current ``current_a`` in amperes, **positive while discharging** (the Thevenin model's
  convention, seed 000 eqs. 11-14, and the convention of the laboratory CSV files);
* SoC as a fraction in [0, 1] (not percent);
* time in seconds, voltage in volts, charge in ampere-hours, temperature in degrees Celsius.

At the edges:

* ROS ``sensor_msgs/BatteryState.current`` is **negative while discharging** (REP/message
  definition), so :func:`core_current_from_ros` negates it.
* The Saft RC model of seed 000 (eqs. 1-5) is written with the current positive on charge; the
  model class converts internally (see ``models/rc_saft.py``).
* CSV inputs declare their convention with a flag and go through :func:`core_current_from`.
"""

from __future__ import annotations

from enum import Enum

SECONDS_PER_HOUR = 3600.0


class CurrentSign(str, Enum):
    """How an external source signs its current."""

    DISCHARGE_POSITIVE = "discharge_positive"
    CHARGE_POSITIVE = "charge_positive"  # ROS BatteryState, the Saft RC model of seed 000


def core_current_from(current_a: float, sign: CurrentSign) -> float:
    """Convert an external current to the core's discharge-positive convention."""
    if sign is CurrentSign.DISCHARGE_POSITIVE:
        return current_a
    return -current_a


def core_current_from_ros(current_ros_a: float) -> float:
    """ROS BatteryState current (negative while discharging) -> core current (positive)."""
    return -current_ros_a


def ros_current_from_core(current_a: float) -> float:
    """Core current (positive while discharging) -> ROS BatteryState current."""
    return -current_a
