"""Recordings: rosbag2 bags (``bags``) and CSV files (``csv_io``), read into a ``BatterySeries``.

A recording on a command line (``soc_replay``, ``soc_identify``) is a bag or a CSV:
:func:`read_recording` reads either, :func:`add_recording_arguments` declares the options that
go with it. Every unusable recording raises :class:`RecordingError` (one line: path, problem).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from ..series import BatterySeries
from ..units import CurrentSign
from .bags import (
    CELL_REFERENCE_TOPIC,
    REFERENCE_TOPIC,
    STATE_TOPIC,
    RecordingError,
    battery_state_message,
    float64_array_message,
    read_battery_bag,
    write_bag,
    write_battery_bag,
)
from .csv_io import read_csv


def read_recording(
    path: Path | str,
    state_topic: str = STATE_TOPIC,
    sign: CurrentSign = CurrentSign.DISCHARGE_POSITIVE,
    reference_topic: str | None = REFERENCE_TOPIC,
    max_samples: int | None = None,
) -> BatterySeries:
    """A CSV file (current sign ``sign``) or a bag (topics and ``max_samples`` as
    :func:`read_battery_bag`; a CSV is read whole, then cut)."""
    path = Path(path)
    if path.is_file() and path.suffix.lower() == ".csv":
        series = read_csv(path, sign)
        return series if max_samples is None else series.window(0, max_samples)
    return read_battery_bag(
        path, state_topic=state_topic, reference_topic=reference_topic, max_samples=max_samples
    )


def add_recording_arguments(parser: argparse.ArgumentParser) -> None:
    """``--topic`` and ``--current-sign``: how to read a recording given on the command line."""
    parser.add_argument("--topic", default=STATE_TOPIC, help="BatteryState topic in a bag")
    parser.add_argument(
        "--current-sign",
        choices=[s.value for s in CurrentSign],
        default=CurrentSign.DISCHARGE_POSITIVE.value,
        help="sign convention of a CSV",
    )


__all__ = [
    "CELL_REFERENCE_TOPIC",
    "REFERENCE_TOPIC",
    "STATE_TOPIC",
    "BatterySeries",
    "RecordingError",
    "add_recording_arguments",
    "battery_state_message",
    "float64_array_message",
    "read_battery_bag",
    "read_csv",
    "read_recording",
    "write_bag",
    "write_battery_bag",
]
