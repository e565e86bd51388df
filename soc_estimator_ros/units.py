"""Sign and unit conventions of the package, and the conversions at its edges (one home).

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

#: A SoC variance past which nothing is known (std 1 for a quantity in [0, 1]); clipping never
#: grows the variance beyond it, and a state file holds at most it.
MAX_SOC_VAR = 1.0


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


#: Nanoseconds per second: stamps are integer nanoseconds everywhere (exact comparisons; no
#: float rounding of 1.7e18 ns stamps).
NS_PER_S = 1_000_000_000


def stamp_to_ns(sec: int, nanosec: int) -> int:
    """A ROS ``builtin_interfaces/Time`` (``sec``, ``nanosec``) as integer nanoseconds."""
    return int(sec) * NS_PER_S + int(nanosec)


def ns_to_stamp(stamp_ns: int) -> tuple[int, int]:
    """Integer nanoseconds as a ROS time's ``(sec, nanosec)``."""
    sec, nanosec = divmod(int(stamp_ns), NS_PER_S)
    return sec, nanosec
