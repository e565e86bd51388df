"""The OCV's charge/discharge hysteresis: Plett's one-state model, on the discharge branch.

A LFP pack rested after a charge reads a higher voltage than the same pack at the same SoC
rested after a discharge (the two-phase cathode; tens of millivolts on a 4S pack, where the
plateau's slope is a few millivolts per point of SoC). Plett's enhanced self-correcting (ESC)
model (G. L. Plett, *Battery Management Systems* vol. I, §2.8; J. Power Sources 134 (2004),
eq. 7) carries one state ``h`` in [-1, 1]::

    h[k+1] = A h[k] + (A - 1) sgn(i[k]),   A = exp(-|eta i[k] gamma dt / (3600 Q)|)
    v = OCV(z) + M h - ...                                       (i > 0: discharge)

with ``OCV`` the mean of the two branches. This project's OCV tables are the **discharge**
branch (a slow discharge, the pulse tests' rests after discharges), so the state here is
Plett's moved to [0, 1], ``b = (h + 1) / 2``, and the gap between the branches is ``2 M``::

    b[k+1] = A b[k] + (1 - A) c[k],   c = 1 charging, 0 discharging      (exact for i held)
    v = OCV_discharge(z) + gap_v b - ...

``b = 0`` is the discharge branch (the tables as they are: a file without hysteresis is this
with ``gap_v = 0``), ``b = 1`` the charge branch. ``A`` depends on the charge moved only, not
on the SoC, so ``b`` is known from the current alone once its start is: the tracker carries it
beside the filters and hands every consumer the voltage referred to the discharge branch,
``v - gap_v b`` (``tracking/tracker.py``). Plett's instantaneous term ``M_0 sgn(i)`` is not
modelled: it is indistinguishable from the series resistance in a pulse test.

``b``'s start is often unknown (a node started without its state file): it then starts
uncertain (midway, either branch as likely: variance 1/4), its variance contracted by ``A^2``
on every step (the current drives it to a branch whatever it was), so the start's reading of
the OCV (``soc_from_ocv``) adds ``gap_v std(b)`` to its voltage's std and the filters read the
voltage accordingly (``estimators/hybrid.py``, item 10).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from ..units import SECONDS_PER_HOUR
from .coulomb import coulomb_efficiency


@dataclass(frozen=True)
class Hysteresis:
    """The charge/discharge OCV hysteresis of a pack (module docstring).

    Attributes:
        gap_v: the charge branch's rest voltage above the discharge branch's at the same SoC,
            volts (pack); Plett's ``2 M``.
        rate_per_soc: Plett's ``gamma``: a charge moving the SoC by ``dz`` takes the state
            ``1 - exp(-gamma dz)`` of the way to its branch (per unit SoC, > 0).
    """

    gap_v: float
    rate_per_soc: float

    def __post_init__(self) -> None:
        if not (self.gap_v >= 0.0 and math.isfinite(self.gap_v)):
            raise ValueError(f"gap_v must be finite and >= 0, got {self.gap_v}")
        if not (self.rate_per_soc > 0.0 and math.isfinite(self.rate_per_soc)):
            raise ValueError(f"rate_per_soc must be finite and > 0, got {self.rate_per_soc}")

    def decay(self, current_a: float, dt_s: float, capacity_ah: float, eta_charge: float) -> float:
        """``A`` for ``current_a`` (discharge positive) held over ``dt_s`` seconds: the charge
        stored on a charge counts at ``eta_charge``, as the SoC's (``models/coulomb.py``)."""
        eta = coulomb_efficiency(current_a, eta_charge)
        dz = abs(eta * current_a) * dt_s / (SECONDS_PER_HOUR * capacity_ah)
        return math.exp(-self.rate_per_soc * dz)

    def step(
        self,
        state: HysteresisState,
        current_a: float,
        dt_s: float,
        capacity_ah: float,
        eta_charge: float = 1.0,
    ) -> HysteresisState:
        """The state after ``current_a`` held for ``dt_s``; unchanged at zero current."""
        if current_a == 0.0 or not dt_s > 0.0:
            return state
        a = self.decay(current_a, dt_s, capacity_ah, eta_charge)
        target = 1.0 if current_a < 0.0 else 0.0
        return HysteresisState(a * state.branch + (1.0 - a) * target, a * a * state.var)

    def offset_v(self, state: HysteresisState) -> float:
        """The rest voltage above the discharge branch in ``state``: ``gap_v b``."""
        return self.gap_v * state.branch

    def std_v(self, state: HysteresisState) -> float:
        """The offset's std from the state's own uncertainty: ``gap_v std(b)``."""
        return self.gap_v * math.sqrt(state.var)


@dataclass(frozen=True)
class HysteresisState:
    """Where the pack is between its OCV branches.

    Attributes:
        branch: ``b`` in [0, 1]: 0 on the discharge branch, 1 on the charge branch.
        var: ``b``'s variance (0: known; ``UNKNOWN`` when nothing is known of the start).
    """

    branch: float
    var: float = 0.0

    #: The variance of ``b`` when nothing tells the start: a pack sits on one branch or the
    #: other (a rest keeps the branch of the current before it), each as likely: ``b`` is 0 or
    #: 1, variance 1/4 (a uniform over [0, 1], 1/12, would take a pack on a branch, the usual
    #: case, as 1.7 std off the midway guess).
    UNKNOWN_VAR = 0.25

    @classmethod
    def unknown(cls) -> HysteresisState:
        """A start nothing tells about: midway, either branch as likely."""
        return cls(0.5, cls.UNKNOWN_VAR)
