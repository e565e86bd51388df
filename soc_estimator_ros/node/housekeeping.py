"""The node's periodic chores on one timer: the stale output, the diagnostics, the saves.

rclpy's executor rebuilds its wait set from every timer on every spin, so three timers cost
the node rclpy work on every input message (docs/benchmarks.md, "Where the time goes in the
node"). One timer ticking at the shortest period runs each chore when its own period is due.
ROS-free: the node passes ``time.monotonic()`` readings.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any


@dataclass
class _Chore:
    period_s: float
    action: Callable[[], Any]
    due_s: float


class Housekeeping:
    """Chores, each run at most once a tick and no more often than its period."""

    def __init__(self, start_s: float) -> None:
        self._start_s = start_s
        self._chores: list[_Chore] = []

    def every(self, period_s: float, action: Callable[[], Any]) -> None:
        """Run ``action`` every ``period_s`` (first one period after the start)."""
        if not period_s > 0.0:
            raise ValueError(f"a chore's period must be positive, got {period_s}")
        self._chores.append(_Chore(period_s, action, self._start_s + period_s))

    @property
    def tick_s(self) -> float:
        """The timer period: the shortest chore's."""
        return min(chore.period_s for chore in self._chores)

    def run(self, now_s: float) -> None:
        """One tick at ``now_s``: every chore whose time has come, once (a late tick does not
        run a chore twice; after a long stall the schedule restarts from now)."""
        slack_s = 0.5 * self.tick_s  # a timer tick may land a hair before the chore is due
        for chore in self._chores:
            if now_s + slack_s >= chore.due_s:
                chore.due_s += chore.period_s
                if chore.due_s <= now_s:
                    chore.due_s = now_s + chore.period_s
                chore.action()
