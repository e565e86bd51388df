"""The bundled bags keep the bridge's contract (bags/README.md), and bag_io reads what it must.

Every bag is read with rosbags (through ``bag_io``) and compared with its machine-readable
``bag.yaml``. Small bags written here test the error paths.
"""

from __future__ import annotations

import math
from functools import cache
from pathlib import Path

import numpy as np
import pytest
import yaml
from conftest import REPO_ROOT
from rosbags.highlevel import AnyReader
from rosbags.rosbag2 import Reader
from rosbags.rosbag2.storage_mcap import McapReader

from soc_estimator_ros.messages import TECHNOLOGY_BY_CHEMISTRY, TYPESTORE, bridge_state
from soc_estimator_ros.recordings import (
    CELL_REFERENCE_TOPIC,
    REFERENCE_TOPIC,
    STATE_TOPIC,
    RecordingError,
    battery_state_message,
    read_battery_bag,
    write_battery_bag,
)

BAGS = REPO_ROOT / "bags"
ALL = sorted(p.parent for p in BAGS.glob("*/bag.yaml"))


@cache
def meta(bag: Path) -> dict:
    return yaml.safe_load((bag / "bag.yaml").read_text())


@cache
def series(bag: Path):
    return read_battery_bag(bag)


def test_the_bag_set_is_complete() -> None:
    names = {b.name for b in ALL}
    for chem in ("sla", "lfp"):
        assert f"{chem}_pulse_test" in names
        assert f"{chem}_slow_discharge" in names
        runs = [meta(b) for b in ALL if b.name.startswith(f"{chem}_field_run_")]
        assert len(runs) >= 3
        assert any(m["soc_start"] < 0.95 for m in runs), "one run starts part-charged"
        assert any(m["ambient_temperature_c"] != 25.0 for m in runs), "one run at another T"
    storages = {meta(b)["storage"] for b in ALL}
    assert storages == {"mcap", "sqlite3"}  # the package must read both


def test_bags_stay_under_80_mb() -> None:
    # 66 MB: MCAP's message indexes (16 bytes a message) are outside the compressed chunks.
    total = sum(f.stat().st_size for b in ALL for f in b.rglob("*") if f.is_file())
    assert total < 80e6, total


def _mcap_chunk_compressions(mcap: Path) -> set[str]:
    """The ``compression`` of every chunk record (read with rosbags' own MCAP reader)."""
    reader = McapReader(mcap)
    reader.open()
    try:
        assert reader.chunks
        return {chunk.compression for chunk in reader.chunks}
    finally:
        reader.close()


def test_bundled_mcap_bags_are_chunk_compressed() -> None:
    """Every MCAP bag is one plain ``.mcap`` with zstd chunks (Foxglove and PlotJuggler open
    it as is); only the sqlite3 runs are rosbag2 file-compressed (``.db3.zstd``)."""
    for bag in ALL:
        files = sorted(f.name for f in bag.iterdir() if f.suffix not in (".yaml", ".md"))
        info = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
        if meta(bag)["storage"] == "mcap":
            assert files == [f"{bag.name}.mcap"], bag.name
            assert info["compression_mode"] == "" and info["compression_format"] == ""
            assert _mcap_chunk_compressions(bag / files[0]) == {"zstd"}, bag.name
        else:
            assert files == [f"{bag.name}.db3.zstd"], bag.name
            assert info["compression_mode"] == "file"
    assert not list(BAGS.rglob("*.mcap.zstd"))


@pytest.mark.parametrize("bag", ALL, ids=lambda p: p.name)
def test_bag_contract(bag: Path) -> None:
    m = meta(bag)
    with AnyReader([bag], default_typestore=TYPESTORE) as reader:
        topics = {c.topic: c.msgtype for c in reader.connections}
        counts = {c.topic: c.msgcount for c in reader.connections}
    cells = m["kind"] == "cells_mission"
    assert topics == {
        STATE_TOPIC: "sensor_msgs/msg/BatteryState",
        REFERENCE_TOPIC: "sensor_msgs/msg/BatteryState",
        **({CELL_REFERENCE_TOPIC: "std_msgs/msg/Float64MultiArray"} if cells else {}),
    }
    assert counts[STATE_TOPIC] == counts[REFERENCE_TOPIC] == m["samples"]
    s = series(bag)
    if cells:  # every sample has every cell's voltage and reference SoC
        n = len(m["cells"]["capacity_x"])
        assert s.cell_voltage_v is not None and s.cell_soc_ref is not None
        assert s.cell_voltage_v.shape == s.cell_soc_ref.shape == (len(s), n)
        assert np.all(np.isfinite(s.cell_voltage_v)) and np.all(np.isfinite(s.cell_soc_ref))
        # The pack is the cells in series (the pack sensor and the cell ADCs differ by their
        # gain and offset errors: 0.8 % and 4 x 2 mV at most, bags/README.md).
        assert np.allclose(s.cell_voltage_v.sum(axis=1), s.voltage_v, rtol=0.01, atol=0.01)
        # The reference is the usable SoC: the weakest cell's charge over the pack's capacity.
        caps = np.asarray(m["cells"]["capacity_ah"])
        usable = np.min(s.cell_soc_ref * caps, axis=1) / m["reference_capacity_ah"]
        assert np.allclose(usable, s.soc_ref, atol=1e-4)  # bag.yaml rounds to 1e-4 Ah
    else:
        assert s.cell_voltage_v is None and s.cell_soc_ref is None
    assert np.all(np.diff(s.stamp_ns) > 0)  # strictly monotone header stamps
    assert not np.any(np.isnan(s.soc_ref))  # every state sample has its reference
    # Duration and SoC range as documented (bag.yaml rounds to 0.1 s and 1e-4).
    assert s.t_s[-1] == pytest.approx(m["duration_s"], abs=0.1)
    assert s.soc_ref[0] == pytest.approx(m["soc_start"], abs=1e-4)
    assert s.soc_ref[-1] == pytest.approx(m["soc_end"], abs=1e-4)
    assert s.reference_capacity_ah == pytest.approx(m["reference_capacity_ah"], abs=1e-4)
    # Current sign: ROS current negative on discharge, so the core current is mostly positive
    # and the SoC falls (a corpus mission may end charged: its SoC falls where it discharges).
    if m["kind"] == "mission":
        assert np.sum(np.diff(s.soc_ref) * s.current_a[:-1]) < 0
        assert m["split"] in ("tuning", "validation") and m["scenario"]["seed"] == m["seed"]
    else:
        assert np.mean(s.current_a) > 0 and s.soc_ref[-1] < s.soc_ref[0]
    assert s.technology == TECHNOLOGY_BY_CHEMISTRY[m["chemistry"]]  # LIFE = 4 / VRLA = 8
    if m["kind"] == "field_run":
        dt = np.diff(s.t_s)
        assert np.allclose(dt, 0.1, atol=1e-6), "field runs are 10 Hz"
        limit = 0.40 if m["chemistry"] == "sla" else 0.20
        assert s.soc_ref[-1] <= limit + 0.005  # down to the manufacturer's limit
        assert np.max(s.current_a) > 20.0  # drive motors: tens of amperes at peak


@pytest.mark.parametrize("bag", [b for b in ALL if "pulse_test" in b.name], ids=lambda p: p.name)
def test_pulse_test_rests_fall_with_soc(bag: Path) -> None:
    s = series(bag)
    loaded = s.current_a > 0.5
    # The voltage just before each pulse starts (end of each rest).
    starts = np.flatnonzero(loaded[1:] & ~loaded[:-1]) + 1
    rest_v = s.voltage_v[starts - 1]
    assert len(starts) >= 6
    assert np.all(np.diff(rest_v) < 0), rest_v
    # Each pulse removes about 10 % SoC (seed 000 §2.1).
    drops = -np.diff(s.soc_ref[starts])
    assert np.allclose(drops, 0.1, atol=0.015), drops


@pytest.mark.parametrize("bag", [b for b in ALL if "load_test" in b.name], ids=lambda p: p.name)
def test_load_test_steps_and_slow_recovery(bag: Path) -> None:
    """tools/make_bags.py's load test: 10 % steps at 3 C with 1-h rests; the rested voltage
    before each step falls with the SoC, and after a step the pack recovers over minutes (what
    the test is for: the surface lag's slow mode, docs/identification.md)."""
    s = series(bag)
    cap = s.design_capacity_ah
    loaded = s.current_a > 0.5 * cap
    starts = np.flatnonzero(loaded[1:] & ~loaded[:-1]) + 1
    ends = np.flatnonzero(~loaded[1:] & loaded[:-1]) + 1
    assert len(starts) == len(ends) == 7
    # 3 C within the +-0.8 % gain error and a 40 mA quantum (bags/README.md "Sensors").
    assert s.current_a[starts + 5] / cap == pytest.approx(3.0, rel=0.01, abs=0.01)
    assert np.allclose(-np.diff(s.soc_ref[starts]), 0.1, atol=0.01)
    rest_v = s.voltage_v[starts - 1]
    assert np.all(np.diff(rest_v) < 0), rest_v

    def after(k: int, dt_s: float) -> float:
        return float(s.voltage_v[np.searchsorted(s.t_s, s.t_s[k] + dt_s)])

    recovery = [after(k, 600.0) - after(k, 60.0) for k in ends]
    # Measured 4-172 mV between the 1st and the 10th minute of rest, most where a step ends on
    # a bend of the OCV (0.79, 0.38, 0.28). Bound: 0.1 V on the largest.
    assert max(recovery) > 0.1, recovery
    assert min(recovery) >= 0.0, recovery  # the voltage only rises at rest


@pytest.mark.parametrize("bag", [b for b in ALL if "rate_test" in b.name], ids=lambda p: p.name)
def test_rate_test_levels(bag: Path) -> None:
    """tools/make_bags.py's rate test: per SoC level, steps from rest to 0.1-6 C; the rested
    voltage before each level falls with the SoC; the drop per ampere falls with the current
    (what the test is for: a constant R0 would give one value)."""
    m = meta(bag)
    s = series(bag)
    cap = s.design_capacity_ah  # the rates are of the nominal capacity (tools/make_bags.py)
    loaded = s.current_a > 0.05 * cap  # the 0.1 C pulse never dips to it (40 mA noise)
    starts = np.flatnonzero(loaded[1:] & ~loaded[:-1]) + 1
    level_starts = [
        k for n, k in enumerate(starts) if n == 0 or s.t_s[k] - s.t_s[starts[n - 1]] > 600
    ]
    assert len(level_starts) == (5 if m["chemistry"] == "sla" else 7)
    rest_v = s.voltage_v[np.array(level_starts) - 1]
    assert np.all(np.diff(rest_v) < 0), rest_v
    first = starts[:8]  # the first level's eight pulses, in increasing current
    currents = s.current_a[first] - s.current_a[first - 1]
    # 0.05 C: two samples of 40 mA noise and 40 mA steps (0.06 A std) at 4 sigma, plus the
    # +-0.8 % gain error (bags/README.md "Sensors").
    assert currents / cap == pytest.approx(
        [0.1, 0.2, 0.5, 1.0, 2.0, 3.0, 4.0, 6.0], rel=0.01, abs=0.05
    )
    per_amp = (s.voltage_v[first - 1] - s.voltage_v[first]) / currents
    # Sub-linear (Butler-Volmer, not a resistor): from 1 C on each step drops less per ampere,
    # and 6 C less than half of 0.1 C per ampere. Below 1 C the decrease (a few mohm) is within
    # one sample's noise (2 mV over 0.5-1 A: 3-6 mohm on a difference).
    assert np.all(np.diff(per_amp[3:]) < 0), per_amp
    assert per_amp[-1] < 0.5 * per_amp[0], per_amp


# The voltage answering every current step in the same sample, and the rest voltages falling
# with the SoC, are checked on every bag by test/regression/test_bag_physics.py (with
# tools/make_bags.py's own checks).


# -- bag_io on small bags written here -------------------------------------------------------
def _messages(n: int, t0_ns: int = 1_000_000_000):
    return [
        battery_state_message(
            bridge_state(t0_ns + k * 100_000_000, 12.5 - 0.001 * k, 2.0, temperature_c=20.0)
        )
        for k in range(n)
    ]


@pytest.mark.parametrize(
    ("storage", "compression"),
    [
        ("mcap", "chunk"),
        ("mcap", "file"),
        ("mcap", "none"),
        ("sqlite3", "file"),
        ("sqlite3", "none"),
    ],
)
def test_round_trip(tmp_path: Path, storage: str, compression: str) -> None:
    ref = [
        battery_state_message(
            bridge_state(
                m.header.stamp.sec * 10**9 + m.header.stamp.nanosec,
                12.5,
                2.0,
                percentage=0.9,
                capacity_ah=5.0,
            )
        )
        for m in _messages(20)
    ]
    write_battery_bag(
        tmp_path / "b", [(STATE_TOPIC, _messages(20)), (REFERENCE_TOPIC, ref)], storage, compression
    )
    s = read_battery_bag(tmp_path / "b")
    assert len(s) == 20
    assert np.allclose(s.t_s, np.arange(20) * 0.1)
    assert np.allclose(s.current_a, 2.0)  # 2 A discharge written as -2 A in ROS
    assert np.allclose(s.voltage_v, 12.5 - 0.001 * np.arange(20), atol=1e-6)  # float32
    assert np.allclose(s.soc_ref, 0.9) and s.reference_capacity_ah == pytest.approx(5.0)


def _raw(bag: Path) -> list[tuple[str, int, bytes]]:
    with Reader(bag) as reader:
        return [(c.topic, t, bytes(raw)) for c, t, raw in reader.messages()]


def test_default_is_one_chunk_compressed_mcap(tmp_path: Path) -> None:
    """write_bag's default: one plain ``.mcap`` (no ``.zstd``) whose chunks are zstd, that
    rosbag2 does not see as compressed; the same messages as an uncompressed bag, and much
    smaller; a rosbag2 file-compressed MCAP still reads."""
    for name, compression in (("chunk", None), ("none", "none"), ("file", "file")):
        topics = [(STATE_TOPIC, _messages(3000))]
        if compression is None:
            write_battery_bag(tmp_path / name, topics)
        else:
            write_battery_bag(tmp_path / name, topics, compression=compression)
    files = sorted(f.name for f in (tmp_path / "chunk").iterdir())
    assert files == ["chunk.mcap", "metadata.yaml"]
    mcap = tmp_path / "chunk" / "chunk.mcap"
    raw = mcap.read_bytes()
    assert raw[:8] == raw[-8:] == b"\x89MCAP0\r\n"
    assert _mcap_chunk_compressions(mcap) == {"zstd"}
    info = yaml.safe_load((tmp_path / "chunk" / "metadata.yaml").read_text())
    info = info["rosbag2_bagfile_information"]
    assert info["compression_mode"] == "" and info["relative_file_paths"] == ["chunk.mcap"]
    assert _mcap_chunk_compressions(tmp_path / "none" / "none.mcap") == {""}
    assert len(raw) < 0.5 * (tmp_path / "none" / "none.mcap").stat().st_size
    assert sorted(f.name for f in (tmp_path / "file").iterdir()) == [
        "file.mcap.zstd",
        "metadata.yaml",
    ]
    assert _raw(tmp_path / "chunk") == _raw(tmp_path / "none") == _raw(tmp_path / "file")
    assert len(_raw(tmp_path / "chunk")) == 3000
    for name in ("chunk", "file"):
        s = read_battery_bag(tmp_path / name)
        assert np.array_equal(s.voltage_v, read_battery_bag(tmp_path / "none").voltage_v)


def test_compression_choices(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="sqlite3 has no chunks"):
        write_battery_bag(tmp_path / "b", [(STATE_TOPIC, _messages(3))], "sqlite3")
    with pytest.raises(ValueError, match="expected one of chunk, file, none"):
        write_battery_bag(tmp_path / "b", [(STATE_TOPIC, _messages(3))], compression="gzip")
    assert not (tmp_path / "b").exists()


def test_missing_topic_names_what_exists(tmp_path: Path) -> None:
    write_battery_bag(tmp_path / "b", [("/other", _messages(5))])
    with pytest.raises(
        RecordingError, match=r"no topic /battery/state \(topics in the bag: /other\)"
    ):
        read_battery_bag(tmp_path / "b")


def test_empty_topic(tmp_path: Path) -> None:
    write_battery_bag(tmp_path / "b", [(STATE_TOPIC, [])])
    with pytest.raises(RecordingError, match="has no messages"):
        read_battery_bag(tmp_path / "b")


def test_not_a_bag(tmp_path: Path) -> None:
    with pytest.raises(RecordingError, match="no such bag"):
        read_battery_bag(tmp_path / "nothing")
    (tmp_path / "junk").mkdir()
    (tmp_path / "junk" / "metadata.yaml").write_text("not: a bag\n")
    with pytest.raises(RecordingError, match="cannot be read"):
        read_battery_bag(tmp_path / "junk")


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_truncated_bag(tmp_path: Path, storage: str) -> None:
    write_battery_bag(tmp_path / "b", [(STATE_TOPIC, _messages(500))], storage, compression="none")
    data = next(f for f in (tmp_path / "b").iterdir() if f.name != "metadata.yaml")
    raw = data.read_bytes()
    data.write_bytes(raw[: len(raw) // 3])
    with pytest.raises(RecordingError, match="cannot be read"):
        read_battery_bag(tmp_path / "b")


def test_wrong_message_type(tmp_path: Path) -> None:
    src = tmp_path / "b"
    write_battery_bag(src, [(STATE_TOPIC, _messages(3))])
    meta_path = src / "metadata.yaml"
    meta_path.write_text(
        meta_path.read_text().replace("sensor_msgs/msg/BatteryState", "std_msgs/msg/Float32")
    )
    with pytest.raises(RecordingError, match="BatteryState|cannot be read"):
        read_battery_bag(src)


@pytest.mark.parametrize("name", ["sla_field_run_1_full_rest", "lfp4s_cells_2_partial"])
def test_max_samples_reads_the_head_of_a_bag(name: str) -> None:
    """The first n samples, with their references and cell voltages, as the whole bag's."""
    bag = BAGS / name
    if not (bag / "metadata.yaml").is_file():
        pytest.skip(f"bundled bag {name} not present")
    n = 1234
    head = read_battery_bag(bag, max_samples=n)
    whole = series(bag).window(0, n)
    assert len(head) == n
    for field in ("stamp_ns", "t_s", "current_a", "voltage_v", "temperature_c", "soc_ref"):
        np.testing.assert_array_equal(getattr(head, field), getattr(whole, field), field)
    if whole.cell_voltage_v is not None:
        np.testing.assert_array_equal(head.cell_voltage_v, whole.cell_voltage_v)
        np.testing.assert_array_equal(head.cell_soc_ref, whole.cell_soc_ref)


def test_a_bridge_with_cell_temperatures_only_gives_the_pack_their_mean(tmp_path: Path) -> None:
    # A BMS that reports its cells' sensors and leaves the pack's temperature NaN.
    msgs = [
        battery_state_message(
            bridge_state(1_000_000_000 + k * 100_000_000, 13.2, 2.0),
            cell_temperature_c=[4.0, 6.0, math.nan, 5.0],
        )
        for k in range(5)
    ]
    write_battery_bag(tmp_path / "b", [(STATE_TOPIC, msgs)], "mcap", "none")
    s = read_battery_bag(tmp_path / "b", reference_topic=None)
    np.testing.assert_allclose(s.temperature_c, 5.0)
