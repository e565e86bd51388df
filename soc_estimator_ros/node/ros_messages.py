"""rclpy messages from the package's plain message content (``messages.py``): one filler per
message type, used by the node and by the live replay's bridge."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import fields as dataclass_fields
from functools import lru_cache

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

#: ``BatteryStateFields`` set one by one on the message (the stamp and frame go in the header).
_STATE_FIELDS = tuple(
    f.name for f in dataclass_fields(BatteryStateFields) if f.name not in ("stamp_ns", "frame_id")
)


def battery_state_msg(
    fields: BatteryStateFields, header: Header | None = None, into: BatteryState | None = None
) -> BatteryState:
    """A ``BatteryState`` holding ``fields``; ``header`` (the input's) replaces the stamp.

    ``into``: a message to fill instead of a new one (every field is set, none is left from
    its last use; a publisher serializes on ``publish``, so one message serves every sample).
    Attribute by attribute: ``dataclasses.asdict``'s deep copy and a new message per sample
    were a fifth of the node's time per message.
    """
    msg = BatteryState() if into is None else into
    if header is not None:
        msg.header = header
    else:
        msg.header.stamp.sec, msg.header.stamp.nanosec = ns_to_stamp(fields.stamp_ns)
        msg.header.frame_id = fields.frame_id
    for name in _STATE_FIELDS:
        setattr(msg, name, getattr(fields, name))
    return msg


@lru_cache(maxsize=16)
def _estimate_layout(
    state_names: tuple[str, ...], with_health: bool, n_cells: int
) -> tuple[str, int]:
    """The estimate vector's layout label and length (the same for every message of a run)."""
    n = len(estimate_labels(state_names, with_health, n_cells))
    return layout_label(state_names, with_health, n_cells), n


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
    label, n = _estimate_layout(tuple(est.state_names), with_health, n_cells)
    arr = Float64MultiArray()
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
