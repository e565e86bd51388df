"""Read and write the bridge's rosbag2 recordings (MCAP or sqlite3, compressed or not), and CSV.

The bag contract (bags/README.md): ``/battery/state`` carries ``sensor_msgs/BatteryState``
samples from the STM32 bridge (current NEGATIVE while discharging, as ROS defines it);
``/battery/soc_reference`` carries the reference SoC as ``sensor_msgs/BatteryState`` (its
``percentage``) with the same stamps. This module uses ``rosbags`` only, no rclpy, so replay,
identification and tests run without ROS.

A recording on a command line (``soc_replay``, ``soc_identify``) is a bag or a CSV
(``time_s,current_a,voltage_v[,temperature_c][,soc_ref]``): :func:`read_recording` reads
either, :func:`add_recording_arguments` declares the options that go with it.

On reading, the current is converted to the core's convention (positive while discharging);
samples are returned in header-stamp order.
"""

from __future__ import annotations

import argparse
import csv
import heapq
import math
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
from rosbags.highlevel import AnyReader
from rosbags.rosbag2 import Writer
from rosbags.rosbag2.enums import CompressionFormat, CompressionMode, StoragePlugin
from rosbags.typesys import Stores, get_typestore

from .conventions import (
    CurrentSign,
    core_current_from,
    core_current_from_ros,
    ros_current_from_core,
)

STATE_TOPIC = "/battery/state"
REFERENCE_TOPIC = "/battery/soc_reference"
BATTERY_STATE = "sensor_msgs/msg/BatteryState"
TYPESTORE = get_typestore(Stores.ROS2_JAZZY)
_MSG = TYPESTORE.types[BATTERY_STATE]
_HEADER = TYPESTORE.types["std_msgs/msg/Header"]

#: ``power_supply_technology`` per chemistry of the parameter files (Jazzy's constants: LIFE is
#: 4, VRLA 8, LION 2; read from the message definition, never typed by hand).
TECHNOLOGY_BY_CHEMISTRY: dict[str, int] = {
    "lfp": int(_MSG.POWER_SUPPLY_TECHNOLOGY_LIFE),
    "sla": int(_MSG.POWER_SUPPLY_TECHNOLOGY_VRLA),
    "li_ion": int(_MSG.POWER_SUPPLY_TECHNOLOGY_LION),
}
_TIME = TYPESTORE.types["builtin_interfaces/msg/Time"]
FLOAT64_ARRAY = "std_msgs/msg/Float64MultiArray"
_ARRAY = TYPESTORE.types[FLOAT64_ARRAY]
_LAYOUT = TYPESTORE.types["std_msgs/msg/MultiArrayLayout"]
_DIM = TYPESTORE.types["std_msgs/msg/MultiArrayDimension"]


class BagError(ValueError):
    """A bag that cannot be used, with its path and what is wrong."""

    def __init__(self, path: Path | str, problem: str) -> None:
        super().__init__(f"{path}: {problem}")
        self.path = Path(path)
        self.problem = problem


@dataclass(frozen=True)
class BatterySeries:
    """Samples of one recording, aligned, in stamp order.

    Attributes:
        t_s: seconds since the first sample.
        stamp_ns: absolute header stamps (ns).
        current_a: current in A, core convention (positive while discharging).
        voltage_v: pack voltage in V.
        temperature_c: temperature in degC (NaN where the bridge sent none).
        soc_ref: reference SoC (fraction) at each sample, or None without a reference topic.
        design_capacity_ah: the bridge's design capacity (NaN if not sent).
        technology: ``power_supply_technology`` of the first sample.
        reference_capacity_ah: capacity behind the reference SoC, or None.
        repeated_stamps: rows dropped on reading because they repeated the previous row's
            time (a CSV from a cell tester logs a record at both sides of a step boundary).
    """

    t_s: np.ndarray
    stamp_ns: np.ndarray
    current_a: np.ndarray
    voltage_v: np.ndarray
    temperature_c: np.ndarray
    soc_ref: np.ndarray | None = None
    design_capacity_ah: float = math.nan
    technology: int = 0
    reference_capacity_ah: float | None = None
    repeated_stamps: int = 0

    def __len__(self) -> int:
        return len(self.t_s)

    def window(self, lo: int, hi: int | None = None) -> BatterySeries:
        """Samples ``lo`` to ``hi`` (exclusive) as a recording of their own (time from 0)."""
        sl = slice(lo, hi)
        return replace(
            self,
            t_s=self.t_s[sl] - self.t_s[lo],
            stamp_ns=self.stamp_ns[sl],
            current_a=self.current_a[sl],
            voltage_v=self.voltage_v[sl],
            temperature_c=self.temperature_c[sl],
            soc_ref=None if self.soc_ref is None else self.soc_ref[sl],
        )


def _stamp_ns(msg: Any) -> int:
    return int(msg.header.stamp.sec) * 1_000_000_000 + int(msg.header.stamp.nanosec)


def read_battery_bag(
    path: Path | str,
    state_topic: str = STATE_TOPIC,
    reference_topic: str | None = REFERENCE_TOPIC,
) -> BatterySeries:
    """Read a recording; :class:`BagError` for anything that makes it unusable.

    The reference topic is optional: without it ``soc_ref`` is None. Its samples are matched
    to the state samples by stamp; state samples without a reference get NaN.
    """
    p = Path(path)
    if not p.exists():
        raise BagError(p, "no such bag")
    try:
        with AnyReader([p], default_typestore=TYPESTORE) as reader:
            topics = {c.topic: c.msgtype for c in reader.connections}
            if state_topic not in topics:
                have = ", ".join(sorted(topics)) or "none"
                raise BagError(p, f"no topic {state_topic} (topics in the bag: {have})")
            for topic in (state_topic, reference_topic):
                if topic in topics and topics[topic] != BATTERY_STATE:
                    raise BagError(p, f"{topic} is {topics[topic]}, expected {BATTERY_STATE}")
            wanted = [c for c in reader.connections if c.topic in (state_topic, reference_topic)]
            states: list[tuple[int, float, float, float, float, int]] = []
            refs: dict[int, tuple[float, float]] = {}
            for conn, _, raw in reader.messages(connections=wanted):
                msg = reader.deserialize(raw, conn.msgtype)
                if conn.topic == state_topic:
                    states.append(
                        (
                            _stamp_ns(msg),
                            float(msg.current),
                            float(msg.voltage),
                            float(msg.temperature),
                            float(msg.design_capacity),
                            int(msg.power_supply_technology),
                        )
                    )
                else:
                    refs[_stamp_ns(msg)] = (float(msg.percentage), float(msg.capacity))
    except BagError:
        raise
    except Exception as exc:  # rosbags raises many types for damaged files; name them all here
        raise BagError(p, f"cannot be read ({type(exc).__name__}: {exc})") from exc
    if not states:
        raise BagError(p, f"topic {state_topic} has no messages")
    states.sort(key=lambda s: s[0])
    stamps = np.array([s[0] for s in states], dtype=np.int64)
    soc_ref = None
    ref_capacity = None
    if reference_topic is not None and refs:
        soc_ref = np.array([refs.get(int(s), (math.nan, math.nan))[0] for s in stamps])
        ref_capacity = next(iter(refs.values()))[1]
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
    )


def battery_state_message(
    stamp_ns: int,
    voltage_v: float,
    current_a: float,
    *,
    temperature_c: float = math.nan,
    percentage: float = math.nan,
    charge_ah: float = math.nan,
    capacity_ah: float = math.nan,
    design_capacity_ah: float = math.nan,
    technology: int = 0,
    frame_id: str = "battery",
    location: str = "",
    serial_number: str = "",
    present: bool = True,
) -> Any:
    """A rosbags ``BatteryState`` with the core's current converted to ROS's sign."""
    ros_current = ros_current_from_core(current_a)
    if ros_current < 0.0:
        status = _MSG.POWER_SUPPLY_STATUS_DISCHARGING
    elif ros_current > 0.0:
        status = _MSG.POWER_SUPPLY_STATUS_CHARGING
    else:
        status = _MSG.POWER_SUPPLY_STATUS_NOT_CHARGING
    sec, nsec = divmod(int(stamp_ns), 1_000_000_000)
    return _MSG(
        header=_HEADER(stamp=_TIME(sec=sec, nanosec=nsec), frame_id=frame_id),
        voltage=float(voltage_v),
        temperature=float(temperature_c),
        current=float(ros_current),
        charge=float(charge_ah),
        capacity=float(capacity_ah),
        design_capacity=float(design_capacity_ah),
        percentage=float(percentage),
        power_supply_status=status,
        power_supply_health=_MSG.POWER_SUPPLY_HEALTH_UNKNOWN,
        power_supply_technology=int(technology),
        present=present,
        cell_voltage=np.array([], dtype=np.float32),
        cell_temperature=np.array([], dtype=np.float32),
        location=location,
        serial_number=serial_number,
    )


def float64_array_message(label: str, data: Sequence[float]) -> Any:
    """A rosbags ``std_msgs/Float64MultiArray`` with one labelled dimension (the node's
    ``battery/soc_estimate`` layout, see ``outputs.py``)."""
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


def read_csv(path: Path, sign: CurrentSign) -> BatterySeries:
    """A CSV with ``time_s,current_a,voltage_v`` and optional ``temperature_c``, ``soc_ref``.

    Other columns are ignored. A row whose ``time_s`` equals the previous row's is a cell
    tester's second record of a step boundary: the last record of that instant is kept and the
    count of dropped rows is in ``repeated_stamps``. Time running backwards is an error.
    """
    with path.open(newline="") as fh:
        rows = list(csv.DictReader(fh))
    if not rows:
        raise BagError(path, "no data rows")
    missing = {"time_s", "current_a", "voltage_v"} - set(rows[0])
    if missing:
        raise BagError(path, f"missing column(s) {', '.join(sorted(missing))}")

    def col(name: str) -> np.ndarray:
        if name not in rows[0]:
            return np.full(len(rows), math.nan)
        try:
            return np.array([float(r[name]) if r[name] != "" else math.nan for r in rows])
        except ValueError as exc:
            raise BagError(path, f"column {name}: {exc}") from exc

    t = col("time_s")
    dt = np.diff(t)
    if np.any(dt < 0) or not np.all(np.isfinite(t)):
        k = int(np.argmax(~(dt >= 0))) + 1
        raise BagError(path, f"time_s must not decrease (row {k + 2}: {t[k]} after {t[k - 1]})")
    keep = np.concatenate([dt > 0, [True]])  # the last row of each instant

    def kept(name: str) -> np.ndarray:
        return col(name)[keep]

    current = np.array([core_current_from(float(i), sign) for i in kept("current_a")])
    soc_ref = kept("soc_ref")
    t = t[keep]
    return BatterySeries(
        t_s=t - t[0],
        stamp_ns=np.round(t * 1e9).astype(np.int64),
        current_a=current,
        voltage_v=kept("voltage_v"),
        temperature_c=kept("temperature_c"),
        soc_ref=None if np.all(np.isnan(soc_ref)) else soc_ref,
        repeated_stamps=int(np.count_nonzero(~keep)),
    )


def read_recording(
    path: Path | str,
    state_topic: str = STATE_TOPIC,
    sign: CurrentSign = CurrentSign.DISCHARGE_POSITIVE,
    reference_topic: str | None = REFERENCE_TOPIC,
) -> BatterySeries:
    """A CSV file (current sign ``sign``) or a bag (topics as :func:`read_battery_bag`)."""
    path = Path(path)
    if path.is_file() and path.suffix.lower() == ".csv":
        return read_csv(path, sign)
    return read_battery_bag(path, state_topic=state_topic, reference_topic=reference_topic)


def add_recording_arguments(parser: argparse.ArgumentParser) -> None:
    """``--topic`` and ``--current-sign``: how to read a recording given on the command line."""
    parser.add_argument("--topic", default=STATE_TOPIC, help="BatteryState topic in a bag")
    parser.add_argument(
        "--current-sign",
        choices=[s.value for s in CurrentSign],
        default=CurrentSign.DISCHARGE_POSITIVE.value,
        help="sign convention of a CSV",
    )
