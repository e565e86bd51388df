"""Graded low-battery levels with hysteresis and a debounce time (ROS-free).

Levels, from the SoC estimate: OK, WARN below ``warn_soc``, CRITICAL below ``critical_soc``,
EMERGENCY below ``emergency_soc``. The thresholds come, in this order, from the node's
parameters, the battery file's optional ``levels:`` section, or the rule::

    critical = limits.soc_min,  warn = min(critical + 0.10, 1),  emergency = max(critical - 0.05, 0)

(warn and emergency follow the critical level in use, so overriding it keeps the order).

A level changes only when its condition has held for ``debounce_s`` of sample time without a
break:

* more severe (a trip): the SoC below the level's threshold, ``SoC < threshold``;
* less severe (a clear): the SoC above the present level's threshold plus ``hysteresis_soc``,
  ``SoC >= threshold + hysteresis``.

So a sag of the estimate under a burst shorter than the debounce does not trip, and a rebound
at rest smaller than the hysteresis does not clear. The first estimate sets the level at once
(a pack that starts low is low), and so does the first estimate after the thresholds change.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import IntEnum

from ..params import LevelSettings, Limits

#: Defaults of the rule (module docstring).
WARN_ABOVE_CRITICAL = 0.10
EMERGENCY_BELOW_CRITICAL = 0.05
DEFAULT_HYSTERESIS_SOC = 0.02
#: Longer than a burst of the seeder's mission (uphill stretches last 10-40 s), far shorter
#: than the SoC takes to move by the hysteresis under that load (minutes).
DEFAULT_DEBOUNCE_S = 30.0


class BatteryLevel(IntEnum):
    """The low-battery level; the value is the code in ``battery/runtime``."""

    OK = 0
    WARN = 1
    CRITICAL = 2
    EMERGENCY = 3

    @property
    def label(self) -> str:
        """Lower-case name (diagnostics, logs)."""
        return self.name.lower()


@dataclass(frozen=True)
class LevelThresholds:
    """Resolved thresholds (fractions) and the filtering of level changes."""

    warn_soc: float
    critical_soc: float
    emergency_soc: float
    hysteresis_soc: float = DEFAULT_HYSTERESIS_SOC
    debounce_s: float = DEFAULT_DEBOUNCE_S

    def __post_init__(self) -> None:
        if not 1.0 >= self.warn_soc >= self.critical_soc >= self.emergency_soc >= 0.0:
            raise ValueError(
                f"low-battery levels must satisfy 1 >= warn >= critical >= emergency >= 0, got "
                f"warn {self.warn_soc:g}, critical {self.critical_soc:g}, "
                f"emergency {self.emergency_soc:g}"
            )
        if self.hysteresis_soc < 0.0 or self.debounce_s < 0.0:
            raise ValueError(
                f"hysteresis ({self.hysteresis_soc:g}) and debounce ({self.debounce_s:g} s) "
                "must be >= 0"
            )

    @classmethod
    def resolve(
        cls, limits: Limits, file: LevelSettings, overrides: LevelSettings | None = None
    ) -> LevelThresholds:
        """Overrides (node parameters), else the battery file's section, else the rule."""
        o = overrides or LevelSettings()

        def pick(name: str) -> float | None:
            for source in (o, file):
                value = getattr(source, name)
                if value is not None:
                    return float(value)
            return None

        critical = pick("critical_soc")
        critical = limits.soc_min if critical is None else critical
        warn = pick("warn_soc")
        emergency = pick("emergency_soc")
        hysteresis = pick("hysteresis_soc")
        debounce = pick("debounce_s")
        return cls(
            warn_soc=min(critical + WARN_ABOVE_CRITICAL, 1.0) if warn is None else warn,
            critical_soc=critical,
            emergency_soc=(
                max(critical - EMERGENCY_BELOW_CRITICAL, 0.0) if emergency is None else emergency
            ),
            hysteresis_soc=DEFAULT_HYSTERESIS_SOC if hysteresis is None else hysteresis,
            debounce_s=DEFAULT_DEBOUNCE_S if debounce is None else debounce,
        )

    def threshold(self, level: BatteryLevel) -> float:
        """The SoC below which ``level`` applies (inf for OK: every SoC is at least OK)."""
        return {
            BatteryLevel.OK: math.inf,
            BatteryLevel.WARN: self.warn_soc,
            BatteryLevel.CRITICAL: self.critical_soc,
            BatteryLevel.EMERGENCY: self.emergency_soc,
        }[level]

    def level_of(self, soc: float, margin: float = 0.0) -> BatteryLevel:
        """The most severe level whose ``threshold + margin`` is above ``soc``."""
        for level in (BatteryLevel.EMERGENCY, BatteryLevel.CRITICAL, BatteryLevel.WARN):
            if soc < self.threshold(level) + margin:
                return level
        return BatteryLevel.OK


@dataclass(frozen=True)
class LevelChange:
    """A level change: from (None at the first estimate), to, the SoC and how long the
    condition held (s)."""

    old: BatteryLevel | None
    new: BatteryLevel
    soc: float
    held_s: float

    def describe(self, th: LevelThresholds) -> str:
        """One log line."""
        if self.old is None:
            return f"battery level {self.new.label} at start: SoC {self.soc:.3f}" + (
                f" below {th.threshold(self.new):.3f}" if self.new else ""
            )
        if self.new > self.old:
            return (
                f"battery level {self.old.label} -> {self.new.label}: SoC {self.soc:.3f} below "
                f"{th.threshold(self.new):.3f} for {self.held_s:.0f} s"
            )
        return (
            f"battery level {self.old.label} -> {self.new.label}: SoC {self.soc:.3f} at or above "
            f"{th.threshold(self.old):.3f} + {th.hysteresis_soc:.3f} for {self.held_s:.0f} s"
        )


class LevelMonitor:
    """The level over a stream of (time, SoC) (module docstring)."""

    def __init__(self, thresholds: LevelThresholds) -> None:
        self.thresholds = thresholds
        self.level: BatteryLevel | None = None
        self._pending: int = 0  # +1 a trip pending, -1 a clear pending, 0 none
        self._since_s = 0.0

    def reset(self, thresholds: LevelThresholds | None = None) -> None:
        """New thresholds (or the same); the next estimate sets the level at once."""
        if thresholds is not None:
            self.thresholds = thresholds
        self.level = None
        self._pending = 0

    def update(self, t_s: float, soc: float) -> LevelChange | None:
        """One estimate at ``t_s`` (s); the change it makes, if any."""
        th = self.thresholds
        if self.level is None:
            self.level = th.level_of(soc)
            self._pending = 0
            return LevelChange(None, self.level, soc, 0.0)
        trip = th.level_of(soc) > self.level
        clear = th.level_of(soc, th.hysteresis_soc) < self.level
        direction = 1 if trip else -1 if clear else 0
        if direction == 0:
            self._pending = 0
            return None
        if direction != self._pending:
            self._pending, self._since_s = direction, t_s
        held = t_s - self._since_s
        if held < th.debounce_s:
            return None
        new = th.level_of(soc) if direction > 0 else th.level_of(soc, th.hysteresis_soc)
        change = LevelChange(self.level, new, soc, held)
        self.level = new
        self._pending = 0
        return change
