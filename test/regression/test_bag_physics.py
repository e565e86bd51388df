"""The simulator checks of tools/make_bags.py, re-run on every bundled bag as read back.

``make_bags.py`` refuses to write a bag whose simulated signals are not physical; here the same
functions (``voltage_step_failures``, ``rest_order_failures``) run on the true current and
voltage that each bundled bag carries on ``/battery/soc_reference`` (the simulator's own
signals, without the sensor noise of ``/battery/state``): every current step moves the voltage
in the same sample, and the rest voltages fall as the SoC falls. The tool is imported without
PyBaMM (it imports it only to simulate). The messages are decoded from their CDR bytes with
numpy (rosbags' deserializer would take half a minute for the 1.2 M messages).
"""

from __future__ import annotations

import importlib.util
import sys
from functools import cache
from pathlib import Path
from types import ModuleType
from typing import Any

import numpy as np
import pytest
import yaml
from conftest import REPO_ROOT
from rosbags.highlevel import AnyReader

from soc_estimator_ros.messages import TYPESTORE
from soc_estimator_ros.recordings import REFERENCE_TOPIC

BAGS = sorted(p.parent for p in (REPO_ROOT / "bags").glob("*/bag.yaml"))


@cache
def make_bags() -> ModuleType:
    path = REPO_ROOT / "tools" / "make_bags.py"
    spec = importlib.util.spec_from_file_location("make_bags", path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules["make_bags"] = module  # its dataclasses look their module up
    spec.loader.exec_module(module)
    return module


@cache
def true_signals(bag: Path) -> tuple[np.ndarray, ...]:
    """Time (s), current (A, discharge +), voltage (V) and SoC of ``/battery/soc_reference``.

    ``sensor_msgs/BatteryState`` in little-endian CDR: 4 bytes of encapsulation, the stamp
    (int32 s, uint32 ns), ``frame_id`` (uint32 length, the bytes, padding to 4), then float32
    voltage, temperature, current, charge, capacity, design_capacity, percentage.
    """
    with AnyReader([bag], default_typestore=TYPESTORE) as reader:
        (conn,) = [c for c in reader.connections if c.topic == REFERENCE_TOPIC]
        raws = [raw for _, _, raw in reader.messages(connections=[conn])]
        first: Any = reader.deserialize(raws[0], conn.msgtype)
    assert len({len(r) for r in raws}) == 1, "one message size per bag"
    data = np.frombuffer(b"".join(raws), dtype=np.uint8).reshape(len(raws), -1)
    name_len = int(data[0, 12:16].view("<u4")[0])
    base = 16 + -(-name_len // 4) * 4

    def f32(offset: int) -> np.ndarray:
        return np.ascontiguousarray(data[:, offset : offset + 4]).view("<f4")[:, 0].astype(float)

    stamp_ns = np.ascontiguousarray(data[:, 4:8]).view("<i4")[:, 0].astype(np.int64) * 10**9
    stamp_ns += np.ascontiguousarray(data[:, 8:12]).view("<u4")[:, 0]
    voltage, current, soc = f32(base), -f32(base + 8), f32(base + 24)
    # The decoding agrees with rosbags' deserializer on the first message.
    assert (voltage[0], -current[0], soc[0]) == pytest.approx(
        (first.voltage, first.current, first.percentage), rel=1e-6
    )
    order = np.argsort(stamp_ns, kind="stable")
    t = (stamp_ns[order] - stamp_ns[order][0]) * 1e-9
    return t, current[order], voltage[order], soc[order]


@pytest.mark.parametrize("bag", BAGS, ids=lambda p: p.name)
def test_voltage_answers_every_current_step(bag: Path) -> None:
    _, i, v, _ = true_signals(bag)
    bad = make_bags().voltage_step_failures(i, v)
    assert bad.size == 0, f"{bad.size} steps, first at sample {bad[:1]}"


@pytest.mark.parametrize("bag", BAGS, ids=lambda p: p.name)
def test_rest_voltages_fall_with_soc(bag: Path) -> None:
    t, i, v, soc = true_signals(bag)
    assert make_bags().rest_order_failures(t, i, v, soc) == []


def test_the_checks_catch_a_frozen_voltage() -> None:
    """A voltage that ignores a step (only its drift goes on) and rests out of SoC order fail."""
    mb = make_bags()
    i = np.array([1.0, 1.0, 1.0, 5.0, 5.0])
    v = np.array([13.0, 12.99, 12.98, 12.97, 12.96])  # drifts on at the 1 -> 5 A step
    assert list(mb.voltage_step_failures(i, v)) == [2]
    assert mb.voltage_step_failures(i, np.array([13.0, 12.99, 12.98, 12.80, 12.79])).size == 0
    # Two rests after discharges, 20 % of SoC apart, the lower one at the higher voltage.
    t = np.arange(0.0, 4000.0, 10.0)
    cur = np.where((t % 2000.0) < 1000.0, 3.0, 0.05)
    soc = np.linspace(0.9, 0.5, t.size)  # the rests' probes at 77 % and 57 %
    later = t > 2000.0
    rising = np.where(cur > 1.0, 12.5, np.where(later, 13.0, 12.9))
    assert len(mb.rest_order_failures(t, cur, rising, soc)) == 1
    falling = np.where(cur > 1.0, 12.5, np.where(later, 12.8, 12.9))
    assert mb.rest_order_failures(t, cur, falling, soc) == []


def _meta(bag: Path) -> dict:
    return yaml.safe_load((bag / "bag.yaml").read_text())


#: Bundled battery-health sequences (``make_bags.py --aged``): pack name -> its missions' bags.
HEALTH: dict[str, list[Path]] = {}
for _bag in BAGS:
    if _meta(_bag)["kind"] == "health_mission":
        HEALTH.setdefault(_meta(_bag)["health"]["pack"], []).append(_bag)


@pytest.mark.parametrize("pack", sorted(HEALTH), ids=str)
def test_health_sequence_is_one_pack_from_full_with_rests(pack: str) -> None:
    """A bundled aged pack's missions (bags/README.md, "Aged packs and packs of other sizes"):
    one pack (serial, measured capacity), in time order, each from full at rest down to its SoC
    limit plus at most 5 %, with a rest of 30-60 min half-way and at the end; the reference
    capacity is the aged pack's own measured one, the README's table says the same."""
    mb = make_bags()
    bags = sorted(HEALTH[pack], key=lambda b: _meta(b)["health"]["mission"])
    metas = [_meta(b) for b in bags]
    h = metas[0]["health"]
    assert [m["health"]["mission"] for m in metas] == list(range(1, h["of"] + 1))
    assert {m["health"]["serial_number"] for m in metas} == {h["serial_number"]}
    assert {m["reference_capacity_ah"] for m in metas} == {h["capacity_ah"]}
    assert len({m["seed"] for m in metas}) == len(metas) and metas[0]["split"] == "validation"
    limit = mb.PACKS[h["chemistry"]].soc_limit
    for m, bag in zip(metas, bags, strict=True):
        t, i, v, soc = true_signals(bag)
        assert soc[0] == pytest.approx(1.0, abs=1e-6)
        assert limit - 0.01 <= soc[-1] <= limit + mb.HEALTH_END_DSOC + 0.01
        probes = mb.rest_probes(t, i, v, soc)
        assert len(probes) == 2, "a rest half-way and one at the end"
        rest_s = [m["health"]["mid_rest_s"], m["health"]["end_rest_s"]]
        assert all(1800.0 <= r <= 3600.0 for r in rest_s)
        assert t[-1] - t[probes[-1]] == pytest.approx(rest_s[1] - mb.REST_PROBE_S, abs=1.0)
    starts = [read_start_ns(b) for b in bags]
    assert starts == sorted(starts)
    row = f"| `{pack}` |"
    table = (REPO_ROOT / "bags" / "README.md").read_text().splitlines()
    (line,) = [x for x in table if x.startswith(row)]
    assert f"{h['capacity_ah']:.4f}" in line and f"{h['resistance_factor']:.2f}" in line


def read_start_ns(bag: Path) -> int:
    info = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    return int(info["starting_time"]["nanoseconds_since_epoch"])
