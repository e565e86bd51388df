"""rosbag2 bags of the bridge's recordings: read (MCAP or sqlite3, compressed or not) and write.

The bag contract (bags/README.md): ``/battery/state`` carries ``sensor_msgs/BatteryState``
samples from the STM32 bridge (current NEGATIVE while discharging, as ROS defines it);
``/battery/soc_reference`` carries the reference SoC as ``sensor_msgs/BatteryState`` (its
``percentage``) with the same stamps. ``rosbags`` only, no rclpy, so replay, identification and
tests run without ROS. On reading, the current is converted to the core's convention (positive
while discharging) and samples are returned in header-stamp order.
"""

from __future__ import annotations

import heapq
import math
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import asdict
from pathlib import Path
from typing import Any

import numpy as np
from rosbags.highlevel import AnyReader
from rosbags.rosbag2 import Writer
from rosbags.rosbag2.enums import CompressionFormat, CompressionMode, StoragePlugin

from ..errors import SocEstimatorError
from ..messages import (
    BATTERY_STATE,
    FLOAT64_ARRAY,
    TYPESTORE,
    BatteryStateFields,
    pack_temperature_c,
)
from ..series import BatterySeries
from ..units import core_current_from_ros, ns_to_stamp, stamp_to_ns

STATE_TOPIC = "/battery/state"
REFERENCE_TOPIC = "/battery/soc_reference"
#: The simulator's true SoC of every cell (``std_msgs/Float64MultiArray``, labelled
#: ``fields:cell_soc_1,...``), written at the bag time of its ``/battery/state`` sample.
CELL_REFERENCE_TOPIC = "/battery/cell_soc_reference"
_MSG = TYPESTORE.types[BATTERY_STATE]
_HEADER = TYPESTORE.types["std_msgs/msg/Header"]

_TIME = TYPESTORE.types["builtin_interfaces/msg/Time"]
_ARRAY = TYPESTORE.types[FLOAT64_ARRAY]
_LAYOUT = TYPESTORE.types["std_msgs/msg/MultiArrayLayout"]
_DIM = TYPESTORE.types["std_msgs/msg/MultiArrayDimension"]


class RecordingError(SocEstimatorError, ValueError):
    """A recording (bag or CSV) that cannot be used, with its path and what is wrong."""

    def __init__(self, path: Path | str, problem: str) -> None:
        super().__init__(f"{path}: {problem}")
        self.path = Path(path)
        self.problem = problem


def _stamp_ns(msg: Any) -> int:
    return stamp_to_ns(msg.header.stamp.sec, msg.header.stamp.nanosec)


def read_battery_bag(
    path: Path | str,
    state_topic: str = STATE_TOPIC,
    reference_topic: str | None = REFERENCE_TOPIC,
    max_samples: int | None = None,
) -> BatterySeries:
    """Read a recording; :class:`RecordingError` for anything that makes it unusable.

    The reference topic is optional: without it ``soc_ref`` is None. Its samples are matched
    to the state samples by stamp; state samples without a reference get NaN.
    ``max_samples``: read only the first that many state samples (in bag order; a preview, a
    test on a recording's head) and the references up to them.
    """
    p = Path(path)
    if not p.exists():
        raise RecordingError(p, "no such bag")
    try:
        with AnyReader([p], default_typestore=TYPESTORE) as reader:
            topics = {c.topic: c.msgtype for c in reader.connections}
            if state_topic not in topics:
                have = ", ".join(sorted(topics)) or "none"
                raise RecordingError(p, f"no topic {state_topic} (topics in the bag: {have})")
            for topic in (state_topic, reference_topic):
                if topic in topics and topics[topic] != BATTERY_STATE:
                    raise RecordingError(p, f"{topic} is {topics[topic]}, expected {BATTERY_STATE}")
            cell_topic = CELL_REFERENCE_TOPIC if reference_topic is not None else None
            wanted = [
                c
                for c in reader.connections
                if c.topic in (state_topic, reference_topic, cell_topic)
            ]
            states: list[tuple[int, float, float, float, float, int]] = []
            cells: dict[int, np.ndarray] = {}
            serial_number = ""
            refs: dict[int, tuple[float, float]] = {}
            cell_refs: dict[int, np.ndarray] = {}
            for conn, bag_ns, raw in reader.messages(connections=wanted):
                msg: Any = reader.deserialize(raw, conn.msgtype)
                if conn.topic == cell_topic:
                    cell_refs[int(bag_ns)] = np.asarray(msg.data, dtype=float)
                elif conn.topic == state_topic:
                    if not states:
                        serial_number = str(msg.serial_number)
                    if len(msg.cell_voltage):
                        cells[_stamp_ns(msg)] = np.asarray(msg.cell_voltage, dtype=float)
                    states.append(
                        (
                            _stamp_ns(msg),
                            float(msg.current),
                            float(msg.voltage),
                            pack_temperature_c(float(msg.temperature), msg.cell_temperature),
                            float(msg.design_capacity),
                            int(msg.power_supply_technology),
                        )
                    )
                    # One state past the limit: every reference of the kept ones was read
                    # (a bag is in receive order; a sample's reference comes before the next).
                    if max_samples is not None and len(states) > max_samples:
                        break
                else:
                    refs[_stamp_ns(msg)] = (float(msg.percentage), float(msg.capacity))
    except RecordingError:
        raise
    except Exception as exc:  # rosbags raises many types for damaged files; name them all here
        raise RecordingError(p, f"cannot be read ({type(exc).__name__}: {exc})") from exc
    if not states:
        raise RecordingError(p, f"topic {state_topic} has no messages")
    states.sort(key=lambda s: s[0])
    if max_samples is not None:
        states = states[:max_samples]
    stamps = np.array([s[0] for s in states], dtype=np.int64)
    soc_ref = None
    ref_capacity = None
    if reference_topic is not None and refs:
        soc_ref = np.array([refs.get(int(s), (math.nan, math.nan))[0] for s in stamps])
        ref_capacity = next(iter(refs.values()))[1]
    cell_voltage_v = _cell_rows(cells, stamps)
    cell_soc_ref = _cell_rows(cell_refs, stamps) if cell_voltage_v is not None else None
    return BatterySeries(
        t_s=(stamps - stamps[0]) * 1e-9,
        stamp_ns=stamps,
        current_a=np.array([core_current_from_ros(s[1]) for s in states]),
        voltage_v=np.array([s[2] for s in states]),
        temperature_c=np.array([s[3] for s in states]),
        soc_ref=soc_ref,
        design_capacity_ah=states[0][4],
        technology=states[0][5],
        reference_capacity_ah=ref_capacity,
        serial_number=serial_number,
        cell_voltage_v=cell_voltage_v,
        cell_soc_ref=cell_soc_ref,
    )


def _cell_rows(by_stamp: dict[int, np.ndarray], stamps: np.ndarray) -> np.ndarray | None:
    """Per-cell rows at ``stamps`` ((samples, cells); NaN where a sample has none), or None
    when no sample has any. The number of cells is the first row's."""
    if not by_stamp:
        return None
    n = len(next(iter(by_stamp.values())))
    out = np.full((stamps.size, n), math.nan)
    for k, s in enumerate(stamps):
        row = by_stamp.get(int(s))
        if row is not None and row.size == n:
            out[k] = row
    return out


def battery_state_message(
    fields: BatteryStateFields,
    cell_voltage_v: Sequence[float] | np.ndarray = (),
    cell_temperature_c: Sequence[float] | np.ndarray = (),
) -> Any:
    """A rosbags ``sensor_msgs/BatteryState`` with ``fields`` (``messages`` holds the rules),
    the cells' voltages (V, in series order; empty: not measured) and temperatures (degC)."""
    values = asdict(fields)
    sec, nsec = ns_to_stamp(values.pop("stamp_ns"))
    frame_id = values.pop("frame_id")
    return _MSG(
        header=_HEADER(stamp=_TIME(sec=sec, nanosec=nsec), frame_id=frame_id),
        cell_voltage=np.asarray(cell_voltage_v, dtype=np.float32),
        cell_temperature=np.asarray(cell_temperature_c, dtype=np.float32),
        **values,
    )


def float64_array_message(label: str, data: Sequence[float]) -> Any:
    """A rosbags ``std_msgs/Float64MultiArray`` with one labelled dimension (the node's
    ``battery/soc_estimate`` layout, see ``messages.py``)."""
    return _ARRAY(
        layout=_LAYOUT(
            dim=[_DIM(label=label, size=len(data), stride=len(data))],
            data_offset=0,
        ),
        data=np.asarray(data, dtype=np.float64),
    )


def _tagged(
    index: int, conn: Any, msgtype: str, stamped: Iterable[tuple[int, Any]]
) -> Iterator[tuple[int, int, Any, str, Any]]:
    for t, msg in stamped:
        yield t, index, conn, msgtype, msg


def write_bag(
    path: Path | str,
    topics: Sequence[tuple[str, str, Iterable[tuple[int, Any]]]],
    storage: str = "mcap",
    compression: str = "chunk",
) -> None:
    """Write messages to a new bag.

    Args:
        path: the bag directory to create (must not exist).
        topics: ``(topic, message type, (bag time ns, message) pairs)``, each in time order.
        storage: ``"mcap"`` or ``"sqlite3"``.
        compression: ``"chunk"``: zstd-compressed MCAP chunks in a plain ``.mcap`` that
            Foxglove and PlotJuggler open as is (MCAP only; metadata.yaml says no compression);
            ``"file"``: rosbag2's ``--compression-mode file`` (the whole ``.mcap.zstd`` /
            ``.db3.zstd``); ``"none"``.
    """
    plugin = {"mcap": StoragePlugin.MCAP, "sqlite3": StoragePlugin.SQLITE3}[storage]
    modes = {
        "chunk": CompressionMode.STORAGE,
        "file": CompressionMode.FILE,
        "none": CompressionMode.NONE,
    }
    if compression not in modes:
        raise ValueError(f"compression {compression!r}: expected one of {', '.join(modes)}")
    if compression == "chunk" and plugin != StoragePlugin.MCAP:
        raise ValueError(f"{storage} has no chunks: compression 'file' or 'none'")
    writer = Writer(Path(path), version=Writer.VERSION_LATEST, storage_plugin=plugin)
    writer.set_compression(modes[compression], CompressionFormat.ZSTD)
    with writer:
        streams = [
            _tagged(index, writer.add_connection(topic, msgtype, typestore=TYPESTORE), msgtype, m)
            for index, (topic, msgtype, m) in enumerate(topics)
        ]
        # Interleave the topics in time order, as a recorder would.
        for stamp, _, conn, msgtype, msg in heapq.merge(*streams, key=lambda item: item[:2]):
            writer.write(conn, stamp, TYPESTORE.serialize_cdr(msg, msgtype))


def write_battery_bag(
    path: Path | str,
    topics: Sequence[tuple[str, Iterable[Any]]],
    storage: str = "mcap",
    compression: str = "chunk",
) -> None:
    """Write ``BatteryState`` messages to a new bag, each at its header stamp
    (``topics``: ``(topic, messages)`` pairs in stamp order; see :func:`write_bag`)."""
    write_bag(
        path,
        [(topic, BATTERY_STATE, ((_stamp_ns(m), m) for m in msgs)) for topic, msgs in topics],
        storage,
        compression,
    )
