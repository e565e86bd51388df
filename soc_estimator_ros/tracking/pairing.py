"""Pairing of separate current and voltage readings into samples (no ROS).

Some bridges publish current and voltage on two ``std_msgs/Float32`` (or ``Float64``) topics.
Those messages carry no stamp, so the node stamps each reading with its receive time on the node
clock and hands it to :class:`ScalarPairer`, which forms ``(stamp_ns, current_a, voltage_v)``
samples:

* a reading waits for the other quantity; when the other one arrives within
  ``pair_tolerance_s`` of it, the two form a sample stamped with the **later** of the two
  receive times (so consecutive samples are stamped in order);
* newest wins: a second reading of the same quantity replaces a waiting one (the replaced one
  is counted in ``dropped``), and a waiting reading older than the tolerance is dropped
  (counted too) instead of being paired with a much later one;
* each reading is used in at most one sample.

Stamps are integer nanoseconds, currents in A (whatever sign the caller uses: the node converts
to the core's convention first), voltages in V.
"""

from __future__ import annotations

from dataclasses import dataclass

from ..units import NS_PER_S


@dataclass(frozen=True)
class PairedSample:
    """A current and a voltage reading close enough in time to form one sample."""

    stamp_ns: int
    current_a: float
    voltage_v: float


@dataclass(frozen=True)
class _Reading:
    stamp_ns: int
    value: float


class ScalarPairer:
    """Pairs current and voltage readings by receive time (see the module docstring)."""

    def __init__(self, pair_tolerance_s: float = 0.05) -> None:
        if not pair_tolerance_s >= 0.0:
            raise ValueError(f"pair_tolerance_s must be >= 0, got {pair_tolerance_s}")
        self.pair_tolerance_s = pair_tolerance_s
        self._tol_ns = int(round(pair_tolerance_s * NS_PER_S))
        self._current: _Reading | None = None
        self._voltage: _Reading | None = None
        self.paired = 0
        self.dropped = 0

    def add_current(self, stamp_ns: int, current_a: float) -> PairedSample | None:
        """A current reading (A) received at ``stamp_ns``; a sample if it completes one."""
        reading = _Reading(int(stamp_ns), float(current_a))
        if self._current is not None:
            self.dropped += 1
        self._current = reading
        return self._try_pair(reading.stamp_ns)

    def add_voltage(self, stamp_ns: int, voltage_v: float) -> PairedSample | None:
        """A voltage reading (V) received at ``stamp_ns``; a sample if it completes one."""
        reading = _Reading(int(stamp_ns), float(voltage_v))
        if self._voltage is not None:
            self.dropped += 1
        self._voltage = reading
        return self._try_pair(reading.stamp_ns)

    def _try_pair(self, now_ns: int) -> PairedSample | None:
        cur, volt = self._current, self._voltage
        # A waiting reading too old to pair with anything newer is discarded.
        if cur is not None and now_ns - cur.stamp_ns > self._tol_ns:
            self._current, cur = None, None
            self.dropped += 1
        if volt is not None and now_ns - volt.stamp_ns > self._tol_ns:
            self._voltage, volt = None, None
            self.dropped += 1
        if cur is None or volt is None:
            return None
        if abs(cur.stamp_ns - volt.stamp_ns) > self._tol_ns:
            return None  # unreachable after the age checks above; kept as a guard
        self._current = self._voltage = None
        self.paired += 1
        return PairedSample(max(cur.stamp_ns, volt.stamp_ns), cur.value, volt.value)

    def reset(self) -> None:
        """Forget any waiting reading (counters are kept)."""
        self._current = self._voltage = None
