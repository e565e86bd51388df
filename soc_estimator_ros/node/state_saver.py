"""The state file written on a thread of its own, so the node's executor never waits on a disk.

:func:`~soc_estimator_ros.tracking.persistence.save_state` is atomic and durable: it ``fsync``-s
the file and its directory. An ``fsync`` usually takes a millisecond here, but on a busy disk
one took 286 ms in 40 (a robot's SD card or eMMC stalls longer); run by the executor's timer,
it holds every input message behind it (the likely cause of a benchmark round whose p99
latency was near 100 ms: docs/benchmarks.md). So the node only takes a
snapshot (a :class:`SavedState`, immutable, built under its lock) and hands it here; one writer
thread writes the newest snapshot it has been given. A snapshot that arrives while another is
being written replaces any one still waiting: only the newest state matters. ROS-free.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from pathlib import Path

from ..tracking.persistence import SavedState, save_state


class StateSaver:
    """Writes :class:`SavedState` snapshots to ``path`` on a daemon thread, newest first.

    ``on_error`` is called (on the writer thread) with the exception of a failed write (an
    ``OSError`` from the disk); the next snapshot is written as usual.
    """

    def __init__(self, path: Path, on_error: Callable[[Exception], None]) -> None:
        self.path = path
        self._on_error = on_error
        self._cv = threading.Condition()
        self._pending: SavedState | None = None
        self._writing = False
        self._closed = False
        #: Whether the last write succeeded (True before the first).
        self.ok = True
        self._thread = threading.Thread(target=self._run, name="soc_state_saver", daemon=True)
        self._thread.start()

    def submit(self, state: SavedState) -> None:
        """Queue ``state`` for writing (replacing a queued one not yet written); returns at
        once."""
        with self._cv:
            if self._closed:
                raise RuntimeError("the state saver is closed")
            self._pending = state
            self._cv.notify_all()

    def flush(self, timeout_s: float | None = None) -> bool:
        """Wait until every submitted state is written; False if ``timeout_s`` ran out first."""
        with self._cv:
            return self._cv.wait_for(lambda: self._pending is None and not self._writing, timeout_s)

    def close(self, timeout_s: float | None = None) -> bool:
        """Write what is queued, then stop the thread; False if ``timeout_s`` ran out first."""
        done = self.flush(timeout_s)
        with self._cv:
            self._closed = True
            self._cv.notify_all()
        self._thread.join(timeout_s)
        return done

    def _run(self) -> None:
        while True:
            with self._cv:
                self._cv.wait_for(lambda: self._pending is not None or self._closed)
                if self._pending is None:  # closed with nothing left to write
                    return
                state, self._pending = self._pending, None
                self._writing = True
            ok = True
            try:
                save_state(self.path, state)
            except Exception as exc:  # a failed write must not end the writer
                ok = False
                self._on_error(exc)
            finally:
                with self._cv:
                    self.ok = ok
                    self._writing = False
                    self._cv.notify_all()
