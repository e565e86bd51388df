"""Charge state and the detection of a full pack at the end of a CC-CV charge (ROS-free).

``power_supply_status`` itself is ``messages.supply_status``'s one rule: CHARGING while the
charge current is above ``charging_current_a`` (0.5 A, what Nav2's docking plugins read),
DISCHARGING beyond ``idle_current_a``, NOT_CHARGING between, FULL while :class:`ChargeMonitor`
holds a detected full pack. This module decides FULL and the charge phase the time to full
needs.

A **charge** is confirmed when the charge current stays above ``charging_current_a`` for
``CHARGE_CONFIRM_S`` without a break (a regenerative-braking burst, seconds long, is not a
charge). It lasts until the pack discharges: the current low-passed over ``LOWPASS_TAU_S``
(a 40 mA-noise sensor reads past 0.1 A every few seconds at rest) beyond ``idle_current_a``.

**FULL** ends a confirmed charge at the end of its CV phase, seen either way a charger ends one:

* **held** (a charger that floats, or a recording that rests on the dock): for ``hold_s``
  without a break the terminal voltage is at the charge voltage within the tolerance,
  ``|V - V_cv| <= tol``, and the current has tapered, ``-idle_current_a <= charge current <=
  taper``;
* **terminated** (a charger that stops at its taper current, the usual CC-CV end): a sample in
  the band with the charge current tapered to ``idle_current_a < charge current <=
  TERMINATION_TAPER_FACTOR x taper``, then one no longer charging (``charge current <=
  idle_current_a``: the charger off, or the robot already driving away), with no charge above
  that factor between (samples out of the band at a tapered current between are the stop
  itself, e.g. an interval's mean at ``filter_rate_hz``). Such a charger stops
  the moment its own reading reaches the taper, so the held rule never saw a pack below the
  taper for ``hold_s``: on the corpus' simulated LFP dock charges (a CC-CV charger stopping at
  0.05 C) it found FULL on 2 of 19 (docs/accuracy.md "Charging: FULL at the charger's end").

The tracker then recalibrates the SoC to 1 with std ``FULL_SOC_STD`` (``Tracker.reset_soc``),
and the status is FULL until the pack discharges (the low-passed current beyond
``idle_current_a``) or a new charge starts (the current above ``charging_current_a``:
CHARGING, as the dock sees it).

The charge voltage, tolerance, taper and hold come from the battery file's optional
``charge:`` section, else the rule: ``V_cv = limits.voltage_max_v - 0.05 V x cells_in_series``
(SLA 14.7 -> 14.4 V, 2.40 V per cell; LFP 14.6 -> 14.4 V, 3.60 V per cell: the usual cyclic
charge voltages), tolerance ``0.025 V x cells_in_series``, taper 0.05 C of
``nominal_capacity_ah``, hold 60 s.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import Enum

from ..params import BatteryParams

#: Charge-voltage margin below ``limits.voltage_max_v``, per cell in series (V).
CHARGE_VOLTAGE_MARGIN_V_PER_CELL = 0.05
#: Default tolerance on the charge voltage, per cell in series (V).
CHARGE_VOLTAGE_TOLERANCE_V_PER_CELL = 0.025
#: Default taper current ending a CV charge (C of ``nominal_capacity_ah``).
DEFAULT_TAPER_C_RATE = 0.05
#: Default time the CV end must hold before FULL (s).
DEFAULT_HOLD_S = 60.0
#: A charger that stops at its taper stops on its own reading of the current; ours reads that
#: current through its own gain, offset and noise (the corpus' sensors: 0.30 A read as 0.20-0.36
#: A on the last sample before the stop), so the last charging sample is compared with this
#: multiple of the taper. On LFP 1.5 x 0.05 C in the CV band is at 99.8 % or more (the corpus'
#: dock charges); above the factor the charge counts as interrupted, not ended.
TERMINATION_TAPER_FACTOR = 1.5
#: Charge current above the charging threshold this long without a break confirms a charge (s).
CHARGE_CONFIRM_S = 30.0
#: Low-pass time constant on the current for "the pack discharges" (s).
LOWPASS_TAU_S = 5.0
#: SoC std after the recalibration to full.
FULL_SOC_STD = 0.01


class ChargePhase(str, Enum):
    """Where a charge is."""

    NONE = "none"  # no charge confirmed (regen bursts included)
    CC = "cc"  # confirmed, voltage below the CV band
    CV = "cv"  # confirmed, voltage in the CV band
    FULL = "full"  # a CC-CV end was detected; until the pack discharges

    @property
    def full(self) -> bool:
        """A detected full pack that has not discharged since."""
        return self is ChargePhase.FULL

    @property
    def charging(self) -> bool:
        """A confirmed charge in its CC or CV phase."""
        return self in (ChargePhase.CC, ChargePhase.CV)


@dataclass(frozen=True)
class ChargeSpec:
    """The resolved charge settings.

    Attributes:
        voltage_v: the charge (CV) voltage (V).
        voltage_source: where it came from (the file's key, or the rule).
        voltage_tolerance_v: the band around it (V).
        taper_current_a: the charge current ending a CV charge (A).
        hold_s: how long the CV end must hold (s).
        charging_current_a: charge current above which the pack is charging (A).
        idle_current_a: |current| at or below which the pack is idle (A).
    """

    voltage_v: float
    voltage_source: str
    voltage_tolerance_v: float
    taper_current_a: float
    hold_s: float
    charging_current_a: float
    idle_current_a: float

    @classmethod
    def resolve(
        cls, battery: BatteryParams, charging_current_a: float, idle_current_a: float
    ) -> ChargeSpec:
        """The file's ``charge:`` section where given, else the module docstring's rule."""
        c = battery.charge
        cells = battery.cells_in_series
        if c.voltage_v is not None:
            voltage, source = c.voltage_v, "battery file charge.voltage_v"
        else:
            margin = CHARGE_VOLTAGE_MARGIN_V_PER_CELL * cells
            voltage = battery.limits.voltage_max_v - margin
            per_cell = CHARGE_VOLTAGE_MARGIN_V_PER_CELL
            source = f"limits.voltage_max_v - {margin:g} V ({per_cell} V x {cells} cells)"
        tol = c.voltage_tolerance_v
        taper = DEFAULT_TAPER_C_RATE if c.taper_c_rate is None else c.taper_c_rate
        return cls(
            voltage_v=voltage,
            voltage_source=source,
            voltage_tolerance_v=CHARGE_VOLTAGE_TOLERANCE_V_PER_CELL * cells if tol is None else tol,
            taper_current_a=taper * battery.nominal_capacity_ah,
            hold_s=DEFAULT_HOLD_S if c.hold_s is None else c.hold_s,
            charging_current_a=charging_current_a,
            idle_current_a=idle_current_a,
        )


@dataclass(frozen=True)
class ChargeChange:
    """What one sample changed: ``"confirmed"``, ``"full"`` or ``"released"``, and a log line."""

    kind: str
    message: str


class ChargeMonitor:
    """The charge phase and FULL over a stream of samples (module docstring)."""

    def __init__(self, spec: ChargeSpec) -> None:
        self.spec = spec
        self.phase = ChargePhase.NONE
        self.current_lp_a = 0.0  # low-passed current, core sign (discharge positive)
        self.held_s = 0.0  # how long the CV end has held
        #: The charge current of the last sample in the band with it tapered, while no charge
        #: above the terminated rule's factor came since (that rule), else None.
        self._tapered_a: float | None = None
        self._cc_run_s = 0.0  # how long the charge current has stayed above the threshold
        self._last_t: float | None = None

    @property
    def full(self) -> bool:
        """A detected full pack that has not discharged since (:attr:`ChargePhase.full`)."""
        return self.phase.full

    @property
    def charging(self) -> bool:
        """A confirmed charge in its CC or CV phase (:attr:`ChargePhase.charging`)."""
        return self.phase.charging

    @property
    def hold_left_s(self) -> float:
        """What remains of the CV end's hold (s)."""
        return max(self.spec.hold_s - self.held_s, 0.0)

    def in_cv_band(self, voltage_v: float) -> bool:
        """The terminal voltage at the charge voltage within the tolerance."""
        return abs(voltage_v - self.spec.voltage_v) <= self.spec.voltage_tolerance_v

    def update(self, t_s: float, current_a: float, voltage_v: float) -> ChargeChange | None:
        """One sample (``current_a`` in the core's sign); the change it makes, if any."""
        spec = self.spec
        dt = 0.0 if self._last_t is None else max(t_s - self._last_t, 0.0)
        self._last_t = t_s
        w = 1.0 - math.exp(-dt / LOWPASS_TAU_S) if dt > 0.0 else 1.0
        self.current_lp_a += w * (current_a - self.current_lp_a)
        charge_a = -current_a
        above = charge_a > spec.charging_current_a
        self._cc_run_s = self._cc_run_s + dt if above else 0.0
        discharging = self.current_lp_a > spec.idle_current_a
        if self.phase is ChargePhase.FULL:
            if above or discharging:
                self.phase = ChargePhase.NONE
                self.held_s = 0.0
                why = "a new charge" if above else "the pack discharges"
                return ChargeChange("released", f"FULL released: {why}")
            return None
        if self.phase is ChargePhase.NONE:
            self._tapered_a = None  # a taper belongs to the charge it ended
            if self._cc_run_s >= CHARGE_CONFIRM_S:
                self.phase = ChargePhase.CC
                return ChargeChange(
                    "confirmed",
                    f"charge confirmed: {charge_a:.2f} A for {self._cc_run_s:.0f} s (charge "
                    f"voltage {spec.voltage_v:.2f} V from {spec.voltage_source})",
                )
            return None
        ended_a = self._tapered_a
        if ended_a is not None and charge_a <= spec.idle_current_a:
            return self._full(
                f"charge complete: the charger stopped at {ended_a:.3f} A <= "
                f"{TERMINATION_TAPER_FACTOR:g} x {spec.taper_current_a:.3f} A within "
                f"{spec.voltage_tolerance_v:g} V of {spec.voltage_v:.2f} V"
            )
        if discharging:  # a charge ended without FULL
            self.phase = ChargePhase.NONE
            self.held_s = 0.0
            return ChargeChange("released", "charge ended before full: the pack discharges")
        band = self.in_cv_band(voltage_v)
        self.phase = ChargePhase.CV if band else ChargePhase.CC
        end_a = TERMINATION_TAPER_FACTOR * spec.taper_current_a
        if charge_a > end_a:  # charging harder: not (or no longer) the taper
            self._tapered_a = None
        elif band and charge_a > spec.idle_current_a:
            self._tapered_a = charge_a
        # else kept: a sample between the band and the stop (a filter interval's mean, with
        # filter_rate_hz, holds part of each) still ends a tapered charge
        tapered = -spec.idle_current_a <= charge_a <= spec.taper_current_a
        if band and tapered:
            self.held_s += dt
            if self.held_s >= spec.hold_s:
                return self._full(
                    f"charge complete: {voltage_v:.3f} V within {spec.voltage_tolerance_v:g} V of "
                    f"{spec.voltage_v:.2f} V and {charge_a:.3f} A <= {spec.taper_current_a:.3f} A "
                    f"for {self.held_s:.0f} s"
                )
        else:
            self.held_s = 0.0
        return None

    def _full(self, message: str) -> ChargeChange:
        self.phase = ChargePhase.FULL
        self._tapered_a = None
        return ChargeChange("full", message)
