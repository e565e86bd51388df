"""``soc_replay`` at fleet size (``replay/fleet.py``): jobs on a local Dask cluster, inputs as
fsspec URLs, and one-line errors for an unreachable cluster or a missing URL.

Inputs are short bags (12-minute pieces of a bundled field run, written by the tests) so
each replay takes about a second; the comparisons are of the printed tables, which must be
identical: the same tracker runs the same samples wherever the job runs.
"""

from __future__ import annotations

import shutil
from functools import cache
from pathlib import Path

import fsspec
import pytest
from conftest import bag_path

from soc_estimator_ros.messages import bridge_state
from soc_estimator_ros.recordings import battery_state_message, read_battery_bag, write_battery_bag
from soc_estimator_ros.replay import fleet
from soc_estimator_ros.replay.cli import main as replay_main

N = 7200  # 12 minutes at 10 Hz: past the 10-minute window, so the tables hold errors


@cache
def _field_run():
    return read_battery_bag(bag_path("lfp_field_run_1_full_rest"))


def write_short_bag(path: Path, offset: int = 0) -> Path:
    """``N`` samples of the LFP field run (from ``offset``) as a bag with a reference topic."""
    s = _field_run().window(offset, offset + N)
    assert s.soc_ref is not None
    state = [
        battery_state_message(
            bridge_state(
                int(t), float(v), float(i), temperature_c=float(c), technology=s.technology
            )
        )
        for t, v, i, c in zip(s.stamp_ns, s.voltage_v, s.current_a, s.temperature_c, strict=True)
    ]
    ref = [
        battery_state_message(bridge_state(int(t), float(v), 0.0, percentage=float(r)))
        for t, v, r in zip(s.stamp_ns, s.voltage_v, s.soc_ref, strict=True)
    ]
    write_battery_bag(path, [("/battery/state", state), ("/battery/soc_reference", ref)])
    return path


@pytest.fixture
def fleet_dir(tmp_path) -> Path:
    root = tmp_path / "fleet"
    root.mkdir()
    write_short_bag(root / "robot_a")
    write_short_bag(root / "robot_b", offset=N)
    return root


def run(args: list[str], capsys) -> tuple[int, str, str]:
    code = replay_main(args)
    out = capsys.readouterr()
    return code, out.out, out.err


def test_a_local_cluster_prints_what_the_process_pool_prints(fleet_dir, capsys):
    # coulomb: the cheapest estimator; what is compared is where the jobs run, not the filter
    one = ["--estimator", "coulomb", "--jobs", "2"]
    code_pool, pool, _ = run([str(fleet_dir), *one], capsys)
    code_dask, dask, err = run([str(fleet_dir), *one, "--scheduler", "local"], capsys)
    assert code_pool == 0 and code_dask == 0, err
    assert "robot_a" in pool and "robot_b" in pool and "rejected: none" in pool
    assert pool.count(" - ") == 0  # every row has its errors: the reference was read
    assert dask == pool


def test_urls_replay_as_the_local_paths_do(fleet_dir, capsys):
    """A file:// URL of a directory of bags, and a memory:// copy of it (fetched by the job
    into a temporary directory), print the local directory's table."""
    one = ["--estimator", "coulomb", "--jobs", "1"]
    code, local, err = run([str(fleet_dir), *one], capsys)
    assert code == 0, err
    code, from_file, err = run([fleet_dir.as_uri(), *one], capsys)
    assert code == 0, err
    assert from_file == local
    mem = fsspec.filesystem("memory")
    mem.put(str(fleet_dir), "/soc_test_fleet", recursive=True)
    try:
        assert fleet.expand_url("memory:///soc_test_fleet") == [
            "memory:///soc_test_fleet/robot_a",
            "memory:///soc_test_fleet/robot_b",
        ]
        code, from_memory, err = run(["memory:///soc_test_fleet", *one], capsys)
        assert code == 0, err
        assert from_memory == local
    finally:
        mem.rm("/soc_test_fleet", recursive=True)


def test_a_fetched_copy_is_removed_after_its_job(fleet_dir, tmp_path, monkeypatch):
    made: list[Path] = []
    real_fetch = fleet.fetch

    def fetch(url: str, into: Path) -> Path:
        made.append(into)
        return real_fetch(url, into)

    monkeypatch.setattr(fleet, "fetch", fetch)
    job = fleet.ReplayJob(
        path=Path(), estimators=("coulomb",), url=(fleet_dir / "robot_a").as_uri()
    )
    with fleet.local_copy(job) as local:
        assert (local.path / "metadata.yaml").is_file()
        assert local.name == "robot_a"
    assert made and not made[0].exists()


def test_errors_are_one_line(fleet_dir, capsys, monkeypatch):
    code, _, err = run(["memory:///no/such/bag"], capsys)
    assert code == 2 and err.count("\n") == 1 and "no such file or directory" in err
    code, _, err = run(["nosuchprotocol://bag"], capsys)
    assert code == 2 and err.count("\n") == 1 and "nosuchprotocol://bag" in err
    # Nothing listens on port 1 of this machine: the connection is refused or times out.
    monkeypatch.setattr(fleet, "CONNECT_TIMEOUT_S", 2.0)
    code, _, err = run([str(fleet_dir), "--scheduler", "tcp://127.0.0.1:1"], capsys)
    assert code == 2 and err.count("\n") == 1 and "cannot connect" in err
    code, _, err = run(
        [str(fleet_dir), "--scheduler", "tcp://127.0.0.1:1", "--plot-dir", "plots"], capsys
    )
    assert code == 2 and "write where a job runs" in err
    code, _, err = run([str(fleet_dir / "robot_a"), "--scheduler", "local", "--live"], capsys)
    assert code == 2 and "not --live" in err


def test_fetch_copies_a_bag_directory_byte_for_byte(fleet_dir, tmp_path):
    out = fleet.fetch((fleet_dir / "robot_a").as_uri(), tmp_path)
    for f in (fleet_dir / "robot_a").iterdir():
        assert (out / f.name).read_bytes() == f.read_bytes()
    shutil.rmtree(out)
