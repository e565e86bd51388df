"""rclpy messages from the package's plain message content (``messages.py``): one filler per
message type, used by the node and by the live replay's bridge."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import asdict

from sensor_msgs.msg import BatteryState
from std_msgs.msg import Float64MultiArray, Header, MultiArrayDimension

from ..cells import CellEstimate
from ..estimators.base import Estimate
from ..messages import (
    RUNTIME_FIELDS,
    BatteryStateFields,
    estimate_labels,
    estimate_vector,
    layout_label,
    runtime_layout_label,
    runtime_vector,
)
from ..runtime import RuntimeReport
from ..units import ns_to_stamp


def battery_state_msg(fields: BatteryStateFields, header: Header | None = None) -> BatteryState:
    """A ``BatteryState`` holding ``fields``; ``header`` (the input's) replaces the stamp."""
    values = asdict(fields)
    stamp_ns = values.pop("stamp_ns")
    frame_id = values.pop("frame_id")
    msg = BatteryState()
    if header is not None:
        msg.header = header
    else:
        msg.header.stamp.sec, msg.header.stamp.nanosec = ns_to_stamp(stamp_ns)
        msg.header.frame_id = frame_id
    for name, value in values.items():
        setattr(msg, name, value)
    return msg


def estimate_msg(
    stamp_s: float,
    est: Estimate,
    health: Mapping[str, float] | None = None,
    cells: CellEstimate | None = None,
) -> Float64MultiArray:
    """The labelled estimate vector (``messages.py``) as a ``Float64MultiArray``, with the
    learned ``health`` (``HealthMonitor.fields()``) and the ``cells`` when given."""
    with_health = health is not None
    n_cells = 0 if cells is None else cells.cells
    n = len(estimate_labels(est.state_names, with_health, n_cells))
    arr = Float64MultiArray()
    label = layout_label(est.state_names, with_health, n_cells)
    arr.layout.dim = [MultiArrayDimension(label=label, size=n, stride=n)]
    arr.layout.data_offset = 0
    arr.data = estimate_vector(stamp_s, est, health, cells)
    return arr


def runtime_msg(report: RuntimeReport) -> Float64MultiArray:
    """The labelled runtime vector (``messages.RUNTIME_FIELDS``) as a ``Float64MultiArray``."""
    n = len(RUNTIME_FIELDS)
    arr = Float64MultiArray()
    arr.layout.dim = [MultiArrayDimension(label=runtime_layout_label(), size=n, stride=n)]
    arr.layout.data_offset = 0
    arr.data = runtime_vector(report.fields())
    return arr
