"""node/state_saver.py: the state file written on a thread of its own, newest snapshot first."""

from __future__ import annotations

import threading
from pathlib import Path

import pytest

import soc_estimator_ros.node.state_saver as state_saver
from soc_estimator_ros.node.state_saver import StateSaver
from soc_estimator_ros.tracking.persistence import SavedState, load_state, save_state

#: Seconds any wait here may take; each wait ends as soon as its condition holds, so this only
#: bounds a failure (a writer that never writes), it times nothing.
WAIT_S = 10.0


def state(soc: float) -> SavedState:
    return SavedState(soc, 1e-4, 1_778_152_330.0 + soc, "hybrid", "AJC 12 V 5 Ah SLA (seed 000)")


def test_a_submitted_state_is_written_and_flush_waits_for_it(tmp_path: Path) -> None:
    errors: list[Exception] = []
    saver = StateSaver(tmp_path / "state.yaml", errors.append)
    saver.submit(state(0.7))
    assert saver.flush(WAIT_S)
    assert load_state(tmp_path / "state.yaml") == state(0.7)
    assert saver.ok and errors == []
    assert saver.close(WAIT_S)


def test_submit_returns_while_the_disk_stalls_and_the_newest_state_wins(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The node's executor hands a snapshot and goes on: a write that hangs (an fsync on a busy
    disk) holds only the writer. States submitted meanwhile replace one another; the newest is
    written next, the ones between never."""
    started, release = threading.Event(), threading.Event()
    written: list[float] = []

    def stalling_save(path: Path, s: SavedState) -> None:
        started.set()
        assert release.wait(WAIT_S)
        save_state(path, s)
        written.append(s.soc)

    monkeypatch.setattr(state_saver, "save_state", stalling_save)
    saver = StateSaver(tmp_path / "state.yaml", lambda exc: None)
    saver.submit(state(0.70))
    assert started.wait(WAIT_S)  # the writer holds 0.70 and stalls
    for soc in (0.69, 0.68, 0.67):  # each returns at once, the writer still stalled
        saver.submit(state(soc))
    assert not saver.flush(0.0)  # not written yet
    release.set()
    assert saver.flush(WAIT_S)
    assert written == [0.70, 0.67]
    assert load_state(tmp_path / "state.yaml") == state(0.67)
    assert saver.close(WAIT_S)


def test_a_failed_write_is_reported_and_the_next_one_goes_on(tmp_path: Path) -> None:
    blocker = tmp_path / "not_a_dir"
    blocker.write_text("a file where the state's directory should be")
    errors: list[Exception] = []
    saver = StateSaver(blocker / "state.yaml", errors.append)
    saver.submit(state(0.5))
    assert saver.flush(WAIT_S)
    assert not saver.ok and len(errors) == 1 and isinstance(errors[0], OSError)
    blocker.unlink()
    saver.submit(state(0.4))
    assert saver.flush(WAIT_S)
    assert saver.ok and len(errors) == 1
    assert load_state(blocker / "state.yaml") == state(0.4)
    assert saver.close(WAIT_S)


def test_close_writes_what_is_queued_then_refuses_more(tmp_path: Path) -> None:
    saver = StateSaver(tmp_path / "state.yaml", lambda exc: None)
    saver.submit(state(0.3))
    assert saver.close(WAIT_S)
    assert load_state(tmp_path / "state.yaml") == state(0.3)
    with pytest.raises(RuntimeError, match="closed"):
        saver.submit(state(0.2))
