"""Validation of incoming battery samples before they reach an estimator (no ROS).

The node feeds every sample through :class:`InputGate` first. A sample is rejected, and the
estimator never sees it, when:

* the battery is reported absent (``present == False``): ``NOT_PRESENT``;
* its current or voltage is NaN or infinite: ``NON_FINITE``;
* its voltage lies outside an "absurd" range (default ``[0.5 * voltage_min_v,
  1.5 * voltage_max_v]`` of the battery file's limits): ``VOLTAGE_RANGE`` -- a sensor fault,
  not a deep discharge (a real under-voltage inside the range is accepted and reported by the
  node's diagnostics instead);
* its current exceeds ``current_factor`` times the battery's current limits (discharge limit
  for positive core currents, charge limit for negative ones): ``CURRENT_RANGE``;
* its stamp is older than the newest accepted stamp by more than ``stale_timeout_s``, or (when
  the caller passes ``now_ns``) older than ``now_ns`` by more than ``stale_timeout_s``:
  ``STALE``;
* its stamp is older than the newest accepted stamp (within the stale window):
  ``OUT_OF_ORDER``;
* its stamp equals the newest accepted stamp: ``DUPLICATE``;
* its stamp runs ahead of the newest accepted stamp by more than the receiver's clock has
  advanced since, plus ``time_jump_s`` (only when the caller passes ``clock_ns``): ``TIME_JUMP``
  -- a source whose clock jumped forward (a bad stamp, a clock sync), never integrated as time.

The checks run in that order and the first failing one names the rejection. ``ESTIMATOR_DT``
and ``ESTIMATOR_ERROR`` are not produced by the gate: the tracker records them
(:meth:`InputGate.record`) when an estimator itself rejects a sample's time step
(``StepStatus.REJECTED_DT``) or raises on it, so every lost sample is counted in one place.

A temperature is never a reason to reject a sample: NaN means "not measured" (as
``BatteryState`` defines it); an infinite one, or one outside ``[temperature_min_c,
temperature_max_c]`` (sensor faults), is ignored (the estimator runs as without a temperature)
and counted in ``temperature_ignored`` (:meth:`InputGate.temperature`).

Currents are in the core's convention (A, positive while discharging), voltages in V, stamps
in integer nanoseconds (exact comparisons; no float rounding of 1.7e18 ns stamps).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import Enum

from ..params import Limits
from ..units import NS_PER_S


class Verdict(str, Enum):
    """What the gate decided about one sample (``ACCEPTED`` or the reason for rejecting it)."""

    ACCEPTED = "accepted"
    NOT_PRESENT = "not_present"
    NON_FINITE = "non_finite"
    VOLTAGE_RANGE = "voltage_out_of_range"
    CURRENT_RANGE = "current_out_of_range"
    STALE = "stale"
    OUT_OF_ORDER = "out_of_order"
    DUPLICATE = "duplicate"
    TIME_JUMP = "time_jump"
    ESTIMATOR_DT = "estimator_dt"
    ESTIMATOR_ERROR = "estimator_error"

    @property
    def accepted(self) -> bool:
        """True for ``ACCEPTED``."""
        return self is Verdict.ACCEPTED


#: Every rejection reason, in report order.
REJECTIONS: tuple[Verdict, ...] = tuple(v for v in Verdict if v is not Verdict.ACCEPTED)


@dataclass(frozen=True)
class GateConfig:
    """Thresholds of the gate.

    Attributes:
        voltage_min_v: lowest plausible pack voltage (V); below it a sample is a sensor fault.
        voltage_max_v: highest plausible pack voltage (V).
        current_max_discharge_a: largest plausible discharge current (A, > 0).
        current_max_charge_a: largest plausible charge current magnitude (A, > 0).
        stale_timeout_s: how much older than the newest accepted stamp (or than ``now``) a
            sample may be before it is ``STALE`` (s, > 0).
        time_jump_s: how far a stamp may run ahead of the receiver's clock since the newest
            accepted sample before it is ``TIME_JUMP`` (s, > 0).
        temperature_min_c: lowest plausible temperature (degC); below it a reading is ignored.
        temperature_max_c: highest plausible temperature (degC).
    """

    voltage_min_v: float
    voltage_max_v: float
    current_max_discharge_a: float
    current_max_charge_a: float
    stale_timeout_s: float = 2.0
    time_jump_s: float = 10.0
    temperature_min_c: float = -60.0
    temperature_max_c: float = 125.0

    def __post_init__(self) -> None:
        if not (math.isfinite(self.voltage_min_v) and math.isfinite(self.voltage_max_v)):
            raise ValueError("the voltage range must be finite")
        if not self.voltage_max_v > self.voltage_min_v:
            raise ValueError(
                f"voltage_max_v ({self.voltage_max_v}) must be > voltage_min_v "
                f"({self.voltage_min_v})"
            )
        if not (self.current_max_discharge_a > 0.0 and self.current_max_charge_a > 0.0):
            raise ValueError("the current limits must be > 0")
        if not self.stale_timeout_s > 0.0:
            raise ValueError(f"stale_timeout_s must be > 0, got {self.stale_timeout_s}")
        if not self.time_jump_s > 0.0:
            raise ValueError(f"time_jump_s must be > 0, got {self.time_jump_s}")
        if not self.temperature_max_c > self.temperature_min_c:
            raise ValueError("temperature_max_c must be > temperature_min_c")

    @classmethod
    def from_limits(
        cls,
        limits: Limits,
        *,
        voltage_low_factor: float = 0.5,
        voltage_high_factor: float = 1.5,
        current_factor: float = 2.0,
        stale_timeout_s: float = 2.0,
        time_jump_s: float = 10.0,
        voltage_min_v: float | None = None,
        voltage_max_v: float | None = None,
        temperature_margin_c: float = 40.0,
    ) -> GateConfig:
        """Thresholds from a battery's limits; explicit ``voltage_min_v/max_v`` override them.

        Plausible temperatures: the file's temperature limits widened by
        ``temperature_margin_c`` either way (a pack may really be outside its limits: that is
        reported as COLD/OVERHEAT health, not ignored).
        """
        low = voltage_low_factor * limits.voltage_min_v
        high = voltage_high_factor * limits.voltage_max_v
        return cls(
            voltage_min_v=voltage_min_v if voltage_min_v is not None else low,
            voltage_max_v=voltage_max_v if voltage_max_v is not None else high,
            current_max_discharge_a=current_factor * limits.current_max_discharge_a,
            current_max_charge_a=current_factor * limits.current_max_charge_a,
            stale_timeout_s=stale_timeout_s,
            time_jump_s=time_jump_s,
            temperature_min_c=limits.temperature_min_c - temperature_margin_c,
            temperature_max_c=limits.temperature_max_c + temperature_margin_c,
        )


class InputGate:
    """Accepts or rejects samples (see the module docstring) and counts every verdict.

    :meth:`check` judges a sample and commits it (:meth:`commit`: an accepted stamp becomes the
    newest accepted stamp); rejected samples change nothing but their counter.
    """

    def __init__(self, config: GateConfig) -> None:
        self.config = config
        self._newest_stamp_ns: int | None = None
        self._newest_clock_ns: int | None = None
        self.counts: dict[Verdict, int] = {v: 0 for v in Verdict}
        self.temperature_ignored = 0

    @property
    def newest_stamp_ns(self) -> int | None:
        """The stamp of the newest accepted sample (None before the first or after a rebase)."""
        return self._newest_stamp_ns

    @property
    def accepted_count(self) -> int:
        """Samples accepted so far."""
        return self.counts[Verdict.ACCEPTED]

    @property
    def rejected_count(self) -> int:
        """Samples rejected so far, all reasons together."""
        return sum(self.counts[v] for v in REJECTIONS)

    def record(self, verdict: Verdict) -> None:
        """Count a verdict reached outside the gate (e.g. ``ESTIMATOR_DT``)."""
        self.counts[verdict] += 1

    def rebase(self) -> None:
        """Forget the newest accepted stamp: the source's time line has restarted."""
        self._newest_stamp_ns = None
        self._newest_clock_ns = None

    def temperature(self, temperature_c: float) -> float:
        """The temperature to use (NaN = unknown); an implausible one is ignored and counted."""
        if math.isnan(temperature_c):
            return temperature_c
        cfg = self.config
        if not cfg.temperature_min_c <= temperature_c <= cfg.temperature_max_c:
            self.temperature_ignored += 1
            return math.nan
        return temperature_c

    def evaluate(
        self,
        stamp_ns: int,
        current_a: float,
        voltage_v: float,
        present: bool = True,
        now_ns: int | None = None,
        clock_ns: int | None = None,
    ) -> Verdict:
        """The verdict for a sample, without counting or committing anything (args as
        :meth:`check`)."""
        cfg = self.config
        if not present:
            return Verdict.NOT_PRESENT
        if not (math.isfinite(current_a) and math.isfinite(voltage_v)):
            return Verdict.NON_FINITE
        if not (cfg.voltage_min_v <= voltage_v <= cfg.voltage_max_v):
            return Verdict.VOLTAGE_RANGE
        if current_a > cfg.current_max_discharge_a or -current_a > cfg.current_max_charge_a:
            return Verdict.CURRENT_RANGE
        stale_ns = int(round(cfg.stale_timeout_s * NS_PER_S))
        if now_ns is not None and now_ns - stamp_ns > stale_ns:
            return Verdict.STALE
        newest = self._newest_stamp_ns
        if newest is not None:
            if newest - stamp_ns > stale_ns:
                return Verdict.STALE
            if stamp_ns < newest:
                return Verdict.OUT_OF_ORDER
            if stamp_ns == newest:
                return Verdict.DUPLICATE
            if clock_ns is not None and self._newest_clock_ns is not None:
                ahead_ns = (stamp_ns - newest) - (clock_ns - self._newest_clock_ns)
                if ahead_ns > int(round(cfg.time_jump_s * NS_PER_S)):
                    return Verdict.TIME_JUMP
        return Verdict.ACCEPTED

    def check(
        self,
        stamp_ns: int,
        current_a: float,
        voltage_v: float,
        present: bool = True,
        now_ns: int | None = None,
        clock_ns: int | None = None,
    ) -> Verdict:
        """Judge a sample, count the verdict and, if accepted, make its stamp the newest.

        Args:
            stamp_ns: the sample's stamp (ns).
            current_a: current (A, core convention: positive while discharging).
            voltage_v: pack voltage (V).
            present: the message's ``present`` flag.
            now_ns: the receiver's clock (ns) for the age check, or None to skip it.
            clock_ns: the receiver's clock (ns) when the sample arrived, for the time-jump
                check (stamps compared with the clock's own advance), or None to skip it.
        """
        verdict = self.evaluate(stamp_ns, current_a, voltage_v, present, now_ns, clock_ns)
        self.commit(verdict, stamp_ns, clock_ns)
        return verdict

    def commit(self, verdict: Verdict, stamp_ns: int, clock_ns: int | None = None) -> None:
        """Count a verdict of :meth:`evaluate`; an accepted stamp becomes the newest."""
        self.counts[verdict] += 1
        if verdict is Verdict.ACCEPTED:
            self._newest_stamp_ns = int(stamp_ns)
            self._newest_clock_ns = None if clock_ns is None else int(clock_ns)
