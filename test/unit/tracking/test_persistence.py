"""tracking/persistence.py: the atomic state file, its validation and the resume decision."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
import yaml
from conftest import REPO_ROOT

from soc_estimator_ros.health import HealthState
from soc_estimator_ros.tracking.persistence import (
    CellsState,
    SavedState,
    StateFileError,
    load_state,
    resume_decision,
    resume_health,
    save_state,
)

SLA = REPO_ROOT / "config" / "sla_12v5ah.yaml"
S = 1_000_000_000  # ns per s


# -- persistence -----------------------------------------------------------------------------
STATE = SavedState(soc=0.7312, soc_var=1.2e-5, stamp_s=1_778_152_330.1, estimator="hybrid",
                   battery="AJC 12 V 5 Ah SLA (seed 000)")  # fmt: skip


def test_save_and_load_round_trip(tmp_path: Path) -> None:
    path = tmp_path / "deep" / "dir" / "state.yaml"
    save_state(path, STATE)
    assert load_state(path) == STATE
    # Overwrite atomically: no temporary file left behind.
    save_state(path, SavedState(0.5, 1e-4, STATE.stamp_s + 10, "coulomb", STATE.battery))
    assert load_state(path).soc == 0.5
    assert sorted(os.listdir(path.parent)) == ["state.yaml"]


def test_save_keeps_the_old_file_when_writing_fails(tmp_path: Path, monkeypatch) -> None:
    path = tmp_path / "state.yaml"
    save_state(path, STATE)

    def broken_fsync(fd: int) -> None:
        raise OSError("disk on fire")

    monkeypatch.setattr(os, "fsync", broken_fsync)
    with pytest.raises(OSError, match="disk on fire"):
        save_state(path, SavedState(0.1, 1e-4, 0.0, "x", "y"))
    monkeypatch.undo()
    assert load_state(path) == STATE
    assert sorted(os.listdir(tmp_path)) == ["state.yaml"]


@pytest.mark.parametrize(
    ("content", "problem"),
    [
        ("", "mapping"),
        ("[1, 2]", "mapping"),
        ("format: 2\nsoc: 0.5", "format"),
        ("{format: 1, soc: 1.5, soc_var: 0.1, stamp_s: 1, estimator: h, battery: b}", "soc ="),
        ("{format: 1, soc: .nan, soc_var: 0.1, stamp_s: 1, estimator: h, battery: b}", "finite"),
        ("{format: 1, soc: 0.5, soc_var: 0, stamp_s: 1, estimator: h, battery: b}", "soc_var"),
        ("{format: 1, soc: 0.5, soc_var: 0.1, stamp_s: x, estimator: h, battery: b}", "stamp_s"),
        ("{format: 1, soc: 0.5, soc_var: 0.1, stamp_s: 1, estimator: '', battery: b}", "estim"),
        ("{format: 1, soc: 0.5, soc_var: 0.1, stamp_s: 1, estimator: h}", "battery"),
        ("soc: [unclosed", "YAML"),
    ],
)
def test_load_validates(tmp_path: Path, content: str, problem: str) -> None:
    path = tmp_path / "state.yaml"
    path.write_text(content)
    with pytest.raises(StateFileError, match=problem):
        load_state(path)


def test_load_missing_file(tmp_path: Path) -> None:
    with pytest.raises(StateFileError, match="no such file"):
        load_state(tmp_path / "nope.yaml")


def test_resume_decision(tmp_path: Path) -> None:
    path = tmp_path / "state.yaml"
    save_state(path, STATE)
    fresh = resume_decision(path, STATE.stamp_s + 30.0, 600.0, STATE.battery)
    assert fresh.resume and fresh.state == STATE and "resuming" in fresh.reason
    old = resume_decision(path, STATE.stamp_s + 601.0, 600.0, STATE.battery)
    assert not old.resume and "older than resume_max_age_s" in old.reason
    other = resume_decision(path, STATE.stamp_s + 1.0, 600.0, "another pack")
    assert not other.resume and "another pack" in other.reason
    future = resume_decision(path, STATE.stamp_s - 100.0, 600.0, STATE.battery)
    assert not future.resume and "future" in future.reason
    jitter = resume_decision(path, STATE.stamp_s - 0.5, 600.0, STATE.battery)
    assert jitter.resume
    missing = resume_decision(tmp_path / "none.yaml", 0.0, 600.0, STATE.battery)
    assert not missing.resume and "no such file" in missing.reason


def test_state_file_is_plain_yaml(tmp_path: Path) -> None:
    path = tmp_path / "state.yaml"
    save_state(path, STATE)
    raw = yaml.safe_load(path.read_text())
    optional = ("health", "cells", "hysteresis")  # written only when learned or estimated
    saved = {k: getattr(STATE, k) for k in STATE.__dataclass_fields__ if k not in optional}
    assert raw == {"format": 1, **saved}


def test_a_binary_state_file_is_one_line_and_is_set_aside(tmp_path: Path) -> None:
    path = tmp_path / "state.yaml"
    path.write_bytes(b"\x89PNG\r\n\x1a\n\xff\xfe\x00")
    with pytest.raises(StateFileError, match="not a text file") as info:
        load_state(path)
    assert "\n" not in str(info.value)
    decision = resume_decision(path, 0.0, 3600.0, "any")
    assert not decision.resume and "set aside" in decision.reason
    assert not path.exists() and (tmp_path / "state.yaml.unusable").exists()


def test_temp_files_left_by_a_kill_are_removed(tmp_path: Path) -> None:
    from soc_estimator_ros.tracking.persistence import remove_stale_temp_files

    path = tmp_path / "state.yaml"
    save_state(path, SavedState(0.5, 1e-4, 1.0, "hybrid", "pack"))
    left = [tmp_path / ".state.yaml.k1ll.tmp", tmp_path / ".state.yaml.x9.tmp"]
    for p in left:
        p.write_text("soc: 0.")
    other = tmp_path / ".other.yaml.a.tmp"
    other.write_text("")
    assert sorted(remove_stale_temp_files(path)) == sorted(left)
    assert path.exists() and other.exists() and not any(p.exists() for p in left)


# -- health ----------------------------------------------------------------------------------
HEALTH = HealthState(4.71, 0.0049, 1.32, 0.0025, "SLA-0042", STATE.stamp_s, 0.35)


def test_health_round_trips_and_a_file_without_it_still_loads(tmp_path: Path) -> None:
    path = tmp_path / "state.yaml"
    with_health = SavedState(**{**STATE.__dict__, "health": HEALTH})
    save_state(path, with_health)
    assert load_state(path) == with_health  # every number as written (YAML repr is exact)
    assert yaml.safe_load(path.read_text())["health"]["serial_number"] == "SLA-0042"
    unknown = SavedState(**{**STATE.__dict__, "health": HealthState(5.0, 0.25, 1.0, 0.04)})
    save_state(path, unknown)  # no last sample yet: NaN stamp and current
    loaded = load_state(path).health
    assert loaded is not None and loaded.capacity_ah == 5.0 and loaded.stamp_s != loaded.stamp_s
    save_state(path, STATE)  # a file from before health: no health entry
    assert "health" not in yaml.safe_load(path.read_text()) and load_state(path).health is None


@pytest.mark.parametrize(
    ("health", "problem"),
    [
        ("[1]", "health: expected a mapping"),
        ("{capacity_ah: 0, capacity_var_ah2: 1, r0_factor: 1, r0_factor_var: 1, stamp_s: 1, "
         "current_a: 0}", "health.capacity_ah"),
        ("{capacity_ah: 5, capacity_var_ah2: 1, r0_factor: .nan, r0_factor_var: 1, stamp_s: 1, "
         "current_a: 0}", "health.r0_factor"),
        ("{capacity_ah: 5, capacity_var_ah2: 1, r0_factor: 1, r0_factor_var: 1, stamp_s: 1}",
         "health.current_a"),
        ("{capacity_ah: 5, capacity_var_ah2: 1, r0_factor: 1, r0_factor_var: 1, stamp_s: 1, "
         "current_a: 0, serial_number: 7}", "serial_number"),
    ],
)  # fmt: skip
def test_a_bad_health_entry_is_a_clear_error(tmp_path: Path, health: str, problem: str) -> None:
    check_bad_entry(tmp_path, "health", health, problem)


def check_bad_entry(tmp_path: Path, key: str, entry: str, problem: str) -> None:
    """A state file valid but for its ``key`` entry fails to load, naming ``problem``."""
    path = tmp_path / "state.yaml"
    path.write_text(
        "{format: 1, soc: 0.5, soc_var: 0.1, stamp_s: 1, estimator: h, battery: b, "
        f"{key}: {entry}}}"
    )
    with pytest.raises(StateFileError, match=problem):
        load_state(path)


def test_health_resumes_whatever_its_age_for_the_same_battery_only(tmp_path: Path) -> None:
    """The SoC of a week-old file is not resumed; its health is (a pack keeps its capacity)."""
    path = tmp_path / "state.yaml"
    save_state(path, SavedState(**{**STATE.__dict__, "health": HEALTH}))
    week_s = 7 * 86400.0
    assert not resume_decision(path, STATE.stamp_s + week_s, 3600.0, STATE.battery).resume
    health, reason = resume_health(path, STATE.battery, 5.0)
    assert health == HEALTH and "capacity 4.710 Ah" in reason and "SLA-0042" in reason
    other, reason = resume_health(path, "another pack", 5.0)
    assert other is None and "another pack" in reason
    save_state(path, STATE)
    assert resume_health(path, STATE.battery, 5.0) == (None, f"no saved health in {path}")
    missing, reason = resume_health(tmp_path / "none.yaml", STATE.battery, 5.0)
    assert missing is None and "no such file" in reason
    # A health no pack of this file has (a corrupted or edited file) is not applied: a
    # capacity of 1e300 Ah held the SoC still; an R0 factor of 1000.
    for change in ({"capacity_ah": 1e300}, {"capacity_ah": 0.5}, {"r0_factor": 1000.0}):
        odd = HealthState(**{**HEALTH.__dict__, **change})
        save_state(path, SavedState(**{**STATE.__dict__, "health": odd}))
        none, reason = resume_health(path, STATE.battery, 5.0)
        assert none is None and "not this pack's" in reason and "file's values" in reason


CELLS = CellsState(
    x=((0.012, 0.0, 0.0004), (-0.008, 0.0, -0.0002)),
    p=(
        ((1e-5, 2e-7, 0.0), (2e-7, 9e-4, 0.0), (0.0, 0.0, 4e-6)),
        ((2e-5, 1e-7, 0.0), (1e-7, 9e-4, 0.0), (0.0, 0.0, 4e-6)),
    ),
)


def test_cells_round_trip_and_a_file_without_them_still_loads(tmp_path: Path) -> None:
    path = tmp_path / "state.yaml"
    with_cells = SavedState(**{**STATE.__dict__, "cells": CELLS})
    save_state(path, with_cells)
    assert load_state(path) == with_cells  # every number as written (YAML repr is exact)
    save_state(path, STATE)
    assert "cells" not in yaml.safe_load(path.read_text()) and load_state(path).cells is None


@pytest.mark.parametrize(
    ("cells", "problem"),
    [
        ("[1]", "cells: expected a mapping"),
        ("{x: [[0, 0, 0]], p: [[[1, 0, 0], [0, 1, 0], [0, 0, 1]]]}", "N >= 2"),
        ("{x: [[0, 0], [0, 0]], p: [[[1]], [[1]]]}", "expected \\(N, 3\\)"),
        ("{x: [[0, 0, .nan], [0, 0, 0]], p: [[[1, 0, 0], [0, 1, 0], [0, 0, 1]], "
         "[[1, 0, 0], [0, 1, 0], [0, 0, 1]]]}", "finite"),
        ("{x: [[0, 0, 0], [0, 0, 0]], p: [[[-1, 0, 0], [0, 1, 0], [0, 0, 1]], "
         "[[1, 0, 0], [0, 1, 0], [0, 0, 1]]]}", "negative variance"),
        ("{x: [[a, 0, 0], [0, 0, 0]], p: []}", "cells: expected numbers"),
    ],
)  # fmt: skip
def test_a_bad_cells_entry_is_a_clear_error(tmp_path: Path, cells: str, problem: str) -> None:
    check_bad_entry(tmp_path, "cells", cells, problem)
