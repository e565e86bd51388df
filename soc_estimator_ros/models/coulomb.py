"""Coulomb counting (seed 000 eq. 11; seed 001's CC function).

Core convention (``units.py``): current positive while discharging. Then

    SoC(t + dt) = SoC(t) - eta * I * dt / (3600 * Q_ah)

with eta = 1 on discharge (I > 0) and eta = ``coulomb_efficiency_charge`` on charge (I < 0):
only part of the charge pushed into the pack is stored (seed 000 §2.3 after Plett [35]). The
current is held constant over the step (zero-order hold), which is exact for a sensor that
reports the mean current of its interval.

Seed 000 eq. 11 prints ``SoC = -eta I / Q``: the left side is the time derivative dSoC/dt, and
with Q in ampere-hours the right side needs the 3600 s/h factor.
"""

from __future__ import annotations

import numpy as np

from ..units import SECONDS_PER_HOUR


def coulomb_efficiency(current_a: float, efficiency_charge: float) -> float:
    """eta of seed 000 eq. 11: 1 while discharging, ``efficiency_charge`` while charging."""
    return efficiency_charge if current_a < 0.0 else 1.0


def coulomb_efficiency_lanes(current_a: np.ndarray, efficiency_charge: float) -> np.ndarray:
    """:func:`coulomb_efficiency` at every element of ``current_a`` (the batch engine's)."""
    return np.where(current_a < 0.0, efficiency_charge, 1.0)


def coulomb_step(
    soc: float, current_a: float, dt_s: float, capacity_ah: float, efficiency_charge: float = 1.0
) -> float:
    """SoC after ``dt_s`` seconds of ``current_a`` (positive = discharge). Not clipped."""
    eta = coulomb_efficiency(current_a, efficiency_charge)
    return soc - eta * current_a * dt_s / (SECONDS_PER_HOUR * capacity_ah)
