"""The node's chores on one timer (soc_estimator_ros/node/housekeeping.py), on a fake clock."""

from __future__ import annotations

import pytest

from soc_estimator_ros.node.housekeeping import Housekeeping


def ticks(start_s: float, period_s: float, n: int, jitter_s: float = 0.0) -> list[float]:
    """``n`` timer ticks after ``start_s``, alternately ``jitter_s`` early and late."""
    return [start_s + k * period_s + (jitter_s if k % 2 else -jitter_s) for k in range(1, n + 1)]


def test_each_chore_runs_at_its_own_period_on_the_shortest_tick():
    hk = Housekeeping(100.0)
    runs: dict[str, list[float]] = {"stale": [], "diag": [], "save": []}
    now = [0.0]
    hk.every(0.2, lambda: runs["stale"].append(now[0]))
    hk.every(1.0, lambda: runs["diag"].append(now[0]))
    hk.every(5.0, lambda: runs["save"].append(now[0]))
    assert hk.tick_s == 0.2
    # 10 s of ticks, each up to 20 ms off (a loaded executor): the counts are exact.
    for t in ticks(100.0, hk.tick_s, 50, jitter_s=0.02):
        now[0] = t
        hk.run(t)
    assert (len(runs["stale"]), len(runs["diag"]), len(runs["save"])) == (50, 10, 2)
    assert runs["diag"][0] == pytest.approx(101.0, abs=0.021)


def test_a_stall_runs_each_chore_once_then_restarts_the_schedule():
    hk = Housekeeping(0.0)
    runs: list[float] = []
    hk.every(1.0, lambda: runs.append(0.0))
    hk.run(1.0)
    assert len(runs) == 1
    hk.run(30.0)  # the process was stopped for half a minute: one run, not 29
    assert len(runs) == 2
    for t in (31.0, 32.0, 33.0):  # and then once a period again
        hk.run(t)
    assert len(runs) == 5


def test_a_period_must_be_positive():
    with pytest.raises(ValueError, match="positive"):
        Housekeeping(0.0).every(0.0, lambda: None)
