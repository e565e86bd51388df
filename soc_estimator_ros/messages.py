"""What the package's output messages hold, as plain data (no rclpy): one rule for each.

* ``sensor_msgs/BatteryState``: :func:`estimate_state` is the one rule for what the node
  publishes on ``battery/soc`` (and ``soc_replay --output-bag`` writes): percentage, charge,
  capacity, ``power_supply_status`` (:func:`supply_status`: CHARGING above the charging
  threshold, as Nav2's docking reads the current; DISCHARGING beyond the idle dead band; FULL
  after a detected CC-CV end; UNKNOWN while the input is stale), ``power_supply_health`` from
  the battery's limits (DEAD too below the learned state of health's ``soh_dead``),
  technology from its chemistry. :func:`bridge_state` is what a
  bridge publishes (the bundled bags' input, the live replay's input). Both return a
  :class:`BatteryStateFields`; ``recordings.bags`` turns it into a rosbags message and
  ``node.ros_messages`` into an rclpy one, field by field.
* ``std_msgs/Float64MultiArray`` on ``battery/soc_estimate``: one flat float64 vector per
  estimate::

      data = [stamp_s, soc, soc_var, soc_std, voltage_pred_v, innovation_v, nis,
              x[0..n-1], P[0,0], P[0,1], ..., P[n-1,n-1]]      (P row-major)

  with ``layout.dim[0].label = "fields:" + ",".join(labels)``.
* ``std_msgs/Float64MultiArray`` on ``battery/runtime``: what the robot asks next, one flat
  vector per prediction (:data:`RUNTIME_FIELDS`, the same ``fields:`` label scheme): time to
  empty and its std, time to full, the state of power, the low-battery level, the load.

The message constants (status, health, technology) are read from the Jazzy message definitions
(rosbags' type store), never typed by hand.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from rosbags.typesys import Stores, get_typestore

from .cells.bank import CellEstimate, cell_field_names
from .estimators.base import Estimate
from .health.monitor import HEALTH_FIELDS
from .params import BatteryParams, Limits
from .units import ros_current_from_core

TYPESTORE = get_typestore(Stores.ROS2_JAZZY)
BATTERY_STATE = "sensor_msgs/msg/BatteryState"
FLOAT64_ARRAY = "std_msgs/msg/Float64MultiArray"
_BS: Any = TYPESTORE.types[BATTERY_STATE]  # constants are set on the generated class

STATUS_UNKNOWN = int(_BS.POWER_SUPPLY_STATUS_UNKNOWN)
STATUS_CHARGING = int(_BS.POWER_SUPPLY_STATUS_CHARGING)
STATUS_DISCHARGING = int(_BS.POWER_SUPPLY_STATUS_DISCHARGING)
STATUS_NOT_CHARGING = int(_BS.POWER_SUPPLY_STATUS_NOT_CHARGING)
STATUS_FULL = int(_BS.POWER_SUPPLY_STATUS_FULL)
HEALTH_UNKNOWN = int(_BS.POWER_SUPPLY_HEALTH_UNKNOWN)
HEALTH_GOOD = int(_BS.POWER_SUPPLY_HEALTH_GOOD)
HEALTH_OVERHEAT = int(_BS.POWER_SUPPLY_HEALTH_OVERHEAT)
HEALTH_DEAD = int(_BS.POWER_SUPPLY_HEALTH_DEAD)
HEALTH_OVERVOLTAGE = int(_BS.POWER_SUPPLY_HEALTH_OVERVOLTAGE)
HEALTH_COLD = int(_BS.POWER_SUPPLY_HEALTH_COLD)
TECHNOLOGY_UNKNOWN = int(_BS.POWER_SUPPLY_TECHNOLOGY_UNKNOWN)

#: Charge current (A, ROS sign: positive) above which the pack is CHARGING: Nav2's docking
#: plugins (``SimpleChargingDock``) call a dock charging when ``current > charging_threshold``,
#: 0.5 A by default, so the two agree on every message.
CHARGING_CURRENT_A = 0.5
#: |current| (A) at or below which an idle pack is NOT_CHARGING (the node's idle_current_a).
IDLE_CURRENT_A = 0.1

#: ``power_supply_technology`` per chemistry of the battery files (Jazzy: LIFE 4, VRLA 8, LION 2).
TECHNOLOGY_BY_CHEMISTRY: dict[str, int] = {
    "lfp": int(_BS.POWER_SUPPLY_TECHNOLOGY_LIFE),
    "sla": int(_BS.POWER_SUPPLY_TECHNOLOGY_VRLA),
    "li_ion": int(_BS.POWER_SUPPLY_TECHNOLOGY_LION),
}


def chemistry_of_technology(technology: int) -> str | None:
    """The battery-file chemistry of a ``power_supply_technology`` (None if none matches)."""
    for chemistry, tech in TECHNOLOGY_BY_CHEMISTRY.items():
        if tech == technology:
            return chemistry
    return None


@dataclass(frozen=True)
class BatteryStateFields:
    """The fields of one ``sensor_msgs/BatteryState`` (``current`` in ROS's sign: negative
    while discharging; NaN where a value is not known, as the message defines)."""

    stamp_ns: int
    voltage: float
    current: float
    temperature: float = math.nan
    percentage: float = math.nan
    charge: float = math.nan
    capacity: float = math.nan
    design_capacity: float = math.nan
    power_supply_status: int = STATUS_UNKNOWN
    power_supply_health: int = HEALTH_UNKNOWN
    power_supply_technology: int = TECHNOLOGY_UNKNOWN
    present: bool = True
    location: str = ""
    serial_number: str = ""
    frame_id: str = "battery"


def supply_status(
    current_ros_a: float,
    idle_current_a: float,
    charging_current_a: float | None = None,
    *,
    full: bool = False,
    stale: bool = False,
) -> int:
    """``power_supply_status`` of one message (``current_ros_a`` in ROS's sign).

    UNKNOWN when ``stale`` (the input went silent); FULL when a CC-CV end was detected and
    the pack has not discharged since (``full``, ``runtime/charging.py``); CHARGING above
    ``charging_current_a`` (A; ``None``: ``idle_current_a``, a bridge's plain sign rule);
    DISCHARGING below ``-idle_current_a``; else NOT_CHARGING. CHARGING is exactly "current
    above the threshold", what Nav2's docking reads, so ``IsBatteryCharging`` (status ==
    CHARGING) and the dock agree on every message; a CV taper below the threshold is
    NOT_CHARGING until it ends in FULL.
    """
    if stale:
        return STATUS_UNKNOWN
    if full:
        return STATUS_FULL
    charging = idle_current_a if charging_current_a is None else charging_current_a
    if current_ros_a > charging:
        return STATUS_CHARGING
    if current_ros_a < -idle_current_a:
        return STATUS_DISCHARGING
    return STATUS_NOT_CHARGING


def supply_health(voltage_v: float, temperature_c: float, limits: Limits) -> int:
    """OVERVOLTAGE / DEAD outside the voltage limits, COLD / OVERHEAT outside the temperature
    limits (an unknown, NaN, temperature is not judged), else GOOD."""
    if voltage_v > limits.voltage_max_v:
        return HEALTH_OVERVOLTAGE
    if voltage_v < limits.voltage_min_v:
        return HEALTH_DEAD
    if math.isfinite(temperature_c) and temperature_c < limits.temperature_min_c:
        return HEALTH_COLD
    if math.isfinite(temperature_c) and temperature_c > limits.temperature_max_c:
        return HEALTH_OVERHEAT
    return HEALTH_GOOD


def estimate_state(
    battery: BatteryParams,
    soc: float,
    stamp_ns: int,
    voltage_v: float,
    current_a: float,
    temperature_c: float = math.nan,
    *,
    idle_current_a: float = IDLE_CURRENT_A,
    charging_current_a: float = CHARGING_CURRENT_A,
    full: bool = False,
    stale: bool = False,
    location: str = "",
    serial_number: str = "",
    frame_id: str = "battery",
    capacity_ah: float | None = None,
    soh: float | None = None,
) -> BatteryStateFields:
    """The node's ``battery/soc`` message for a SoC estimate (``current_a`` in the core's sign).

    ``percentage`` is the SoC (0..1), ``charge`` SoC x ``capacity``, ``capacity`` the learned
    full capacity ``capacity_ah`` (``health/``; None: the file's ``capacity_ah``),
    ``design_capacity`` the file's ``nominal_capacity_ah``; the status is
    :func:`supply_status`'s, the health :func:`supply_health`'s, and DEAD where that is GOOD
    but the state of health ``soh`` is below the file's ``health.soh_dead`` (seed 001: 0.6,
    end of life). ``stale``: the input went silent; the SoC is the last one carried forward
    (never NaN: Nav2's ``IsBatteryLow`` never counts a NaN as low), status and health UNKNOWN,
    and voltage, current and temperature NaN (not measured now).
    """
    current_ros = ros_current_from_core(current_a)
    if stale:
        voltage_v = current_ros = temperature_c = math.nan
        health = HEALTH_UNKNOWN
    else:
        health = supply_health(voltage_v, temperature_c, battery.limits)
        if health == HEALTH_GOOD and soh is not None and soh < battery.health.soh_dead:
            health = HEALTH_DEAD
    capacity = battery.capacity_ah if capacity_ah is None else capacity_ah
    return BatteryStateFields(
        stamp_ns=int(stamp_ns),
        voltage=float(voltage_v),
        current=float(current_ros),
        temperature=float(temperature_c),
        percentage=float(soc),
        charge=float(soc * capacity),
        capacity=float(capacity),
        design_capacity=float(battery.nominal_capacity_ah),
        power_supply_status=supply_status(
            current_ros, idle_current_a, charging_current_a, full=full, stale=stale
        ),
        power_supply_health=health,
        power_supply_technology=TECHNOLOGY_BY_CHEMISTRY.get(battery.chemistry, TECHNOLOGY_UNKNOWN),
        present=True,
        location=location,
        serial_number=serial_number,
        frame_id=frame_id,
    )


def pack_temperature_c(temperature_c: float, cell_temperature_c: Sequence[float]) -> float:
    """The pack's temperature (degC) from a ``BatteryState``: its ``temperature``, or where
    that is NaN (not measured, as the message defines it) the mean of the finite
    ``cell_temperature`` values (a BMS that reports its cells' sensors only); NaN when neither
    is given. The mean: the models take one temperature for the pack's lumped cells."""
    if math.isfinite(temperature_c):
        return temperature_c
    cells = [t for t in cell_temperature_c if math.isfinite(t)]
    return float(sum(cells) / len(cells)) if cells else math.nan


def bridge_state(
    stamp_ns: int,
    voltage_v: float,
    current_a: float,
    *,
    temperature_c: float = math.nan,
    percentage: float = math.nan,
    charge_ah: float = math.nan,
    capacity_ah: float = math.nan,
    design_capacity_ah: float = math.nan,
    technology: int = TECHNOLOGY_UNKNOWN,
    present: bool = True,
    location: str = "",
    serial_number: str = "",
    frame_id: str = "battery",
) -> BatteryStateFields:
    """What the robot's bridge publishes on ``battery/state`` (``current_a`` in the core's sign):
    status from the current's sign, health unknown, charge and capacity NaN unless given.
    ``percentage`` carries the reference SoC on ``/battery/soc_reference`` (bags/README.md)."""
    current_ros = ros_current_from_core(current_a)
    return BatteryStateFields(
        stamp_ns=int(stamp_ns),
        voltage=float(voltage_v),
        current=float(current_ros),
        temperature=float(temperature_c),
        percentage=float(percentage),
        charge=float(charge_ah),
        capacity=float(capacity_ah),
        design_capacity=float(design_capacity_ah),
        power_supply_status=supply_status(current_ros, 0.0),
        power_supply_technology=int(technology),
        present=present,
        location=location,
        serial_number=serial_number,
        frame_id=frame_id,
    )


ESTIMATE_FIELDS = (
    "stamp_s",
    "soc",
    "soc_var",
    "soc_std",
    "voltage_pred_v",
    "innovation_v",
    "nis",
)


def estimate_labels(state_names: Sequence[str], health: bool = False, cells: int = 0) -> list[str]:
    """Labels of the estimate vector for an estimator's state names; with ``health`` the
    learned health follows (``health.<name>``, :data:`~soc_estimator_ros.health.HEALTH_FIELDS`),
    then with ``cells`` cells the cells' (``cell.<name>``,
    :func:`~soc_estimator_ros.cells.cell_field_names`: ``cell.soc_1`` ... ``cell.soc_N``,
    ``cell.soc_std_1`` ..., ``cell.usable_soc``, ``cell.usable_soc_std``,
    ``cell.usable_charge_soc``, ``cell.weakest`` (1-based), ``cell.imbalance_soc``,
    ``cell.spread_v``). ``soc`` stays the pack's lumped estimate."""
    names = list(state_names)
    return [
        *ESTIMATE_FIELDS,
        *(f"x.{n}" for n in names),
        *(f"P.{a}.{b}" for a in names for b in names),
        *((f"health.{k}" for k in HEALTH_FIELDS) if health else ()),
        *(f"cell.{k}" for k in (cell_field_names(cells) if cells else ())),
    ]


def layout_label(state_names: Sequence[str], health: bool = False, cells: int = 0) -> str:
    """``layout.dim[0].label`` of the estimate vector."""
    return "fields:" + ",".join(estimate_labels(state_names, health, cells))


def estimate_row(
    stamp_s: float,
    soc: float,
    soc_var: float,
    voltage_pred_v: float,
    innovation_v: float,
    nis: float,
    x: np.ndarray,
    p: np.ndarray,
) -> list[float]:
    """The estimate vector from its parts."""
    head = [stamp_s, soc, soc_var, math.sqrt(max(soc_var, 0.0)), voltage_pred_v, innovation_v, nis]
    return (
        [float(v) for v in head] + [float(v) for v in np.ravel(x)] + [float(v) for v in np.ravel(p)]
    )


def estimate_vector(
    stamp_s: float,
    est: Estimate,
    health: Mapping[str, float] | None = None,
    cells: CellEstimate | None = None,
) -> list[float]:
    """The estimate vector of one :class:`Estimate`, and the learned ``health``
    (``HealthMonitor.fields()``) and the ``cells`` when given."""
    row = estimate_row(
        stamp_s, est.soc, est.soc_var, est.voltage_pred_v, est.innovation_v, est.nis, est.x, est.p
    )
    row += [float(health[k]) for k in HEALTH_FIELDS] if health is not None else []
    return row + (list(cells.fields().values()) if cells is not None else [])


def decode_estimate(msg: Any) -> dict[str, float]:
    """A ``Float64MultiArray`` estimate message (rclpy's or rosbags') as {label: value}."""
    label = msg.layout.dim[0].label
    if not label.startswith("fields:"):
        raise ValueError(f"not a soc_estimate layout: {label!r}")
    names = label.removeprefix("fields:").split(",")
    return dict(zip(names, (float(v) for v in msg.data), strict=True))


#: The ``battery/runtime`` vector, in order (``runtime/monitor.py``'s ``RuntimeReport``):
#: times in s (``inf``: never, e.g. no discharge load; NaN: not applicable, e.g. time to full
#: while not charging), currents in A as magnitudes, ``level`` the low-battery level's code
#: (0 ok, 1 warn, 2 critical, 3 emergency), the load forecast in W (discharge positive).
RUNTIME_FIELDS = (
    "stamp_s",
    "time_to_empty_s",
    "time_to_empty_std_s",
    "time_to_full_s",
    "max_discharge_current_10s_a",
    "max_discharge_current_60s_a",
    "max_charge_current_10s_a",
    "max_charge_current_60s_a",
    "level",
    "load_power_w",
    "load_power_std_w",
)


def runtime_layout_label() -> str:
    """``layout.dim[0].label`` of the runtime vector."""
    return "fields:" + ",".join(RUNTIME_FIELDS)


def runtime_vector(values: dict[str, float]) -> list[float]:
    """The runtime vector from {label: value} (every label of :data:`RUNTIME_FIELDS`)."""
    return [float(values[k]) for k in RUNTIME_FIELDS]


def decode_runtime(msg: Any) -> dict[str, float]:
    """A ``battery/runtime`` message (rclpy's or rosbags') as {label: value}."""
    return decode_estimate(msg)
