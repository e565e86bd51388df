"""The Saft RC model (seed 000 §2.2, Fig. 4a, eqs. 1-5), derived from its circuit.

Circuit: a bulk capacitor ``C_b`` behind ``R_b`` and a surface capacitor ``C_s`` behind ``R_s``
meet at an internal node n; the terminal resistance ``R_t`` joins n to the terminal. The paper
writes the current ``I`` positive on CHARGE (into the pack), the opposite of the Thevenin model;
this module's public methods take the core's discharge-positive ``current_a`` and use
``I = -current_a`` inside.

Derivation (KCL at n, charge-positive I, S = R_b + R_s)::

    I = (V_n - V_cb)/R_b + (V_n - V_cs)/R_s
    V_n = (R_s V_cb + R_b V_cs + R_b R_s I) / S
    dV_cb/dt = (V_n - V_cb)/(R_b C_b) = (-V_cb + V_cs + R_s I) / (C_b S)
    dV_cs/dt = (V_n - V_cs)/(R_s C_s) = ( V_cb - V_cs + R_b I) / (C_s S)
    V_o = V_n + R_t I = (R_s V_cb + R_b V_cs)/S + R_eq I,   R_eq = R_t + R_b R_s / S

Rows 1 and 2 are the paper's eq. 1. The paper keeps V_o as a third state: differentiating V_o
and eliminating V_cs = (S (V_o - R_eq I) - R_s V_cb) / R_b gives::

    dV_o/dt = A31 V_cb + A33 V_o + B31 I + R_eq dI/dt
    A33 = R_s/(C_b R_b S) - 1/(C_s S)                                  (paper eq. 4: correct)
    A31 = -A33 = -R_s/(C_b R_b S) + 1/(C_s S)
    B31 = R_b^2/(C_s S^2) - R_s R_t/(C_b R_b S) + R_t/(C_s S) + R_s R_b/(C_s S^2)

Where the paper is wrong:

* eq. 5 prints the second term of B31 as ``R_s R_s / (C_b R_b S)``; the derivation gives
  ``R_s R_t / (C_b R_b S)`` (the R_eq I term of V_cs carries R_t, and the R_b R_s/S part of
  R_eq cancels against the first term);
* eq. 3 spreads A31 over four terms; they sum to -A33 above, which is what it must be (a
  rested pack with V_o = V_cb = V_cs has dV_o/dt = 0). Check any transcription against -A33;
* eq. 1 drops the ``R_eq dI/dt`` term: with V_o as a state, a current step moves V_o
  instantly by R_eq times the step, which no finite A, B can produce. The discrete model here
  restores it exactly as a feed-through of the current increment (see :meth:`discretize`);
* V_o as a third state adds a mode the circuit has not (the circuit's are 0 and
  ``-(1/C_b + 1/C_s)/S``): A33, excited by any filter update that moves V_o off the circuit's
  value, and growing where A33 > 0, i.e. ``C_s R_s > C_b R_b`` (the surface capacitor the
  slower). The battery file's parser refuses such a model (``params/parse.py``).

Discretization is exact for a current held constant between samples (zero-order hold) for any
dt: ``[[F, g], [0, 1]] = expm([[A, B], [0, 0]] dt)``, then ``V_o`` jumps by
``R_eq (I_{k+1} - I_k)`` at the sample where the current changes. The bulk capacitor voltage
V_cb stands for the OCV (seed 000 §2.2), so SoC = OCV^-1(V_cb).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.linalg import expm


@dataclass(frozen=True)
class RcModelParams:
    """Saft RC model parameters (pack level).

    Attributes:
        c_b_f: bulk capacitance in farads (stores the charge: about 3600 Q_ah / OCV span).
        c_s_f: surface capacitance in farads.
        r_b_ohm: bulk resistance in ohms.
        r_s_ohm: surface resistance in ohms.
        r_t_ohm: terminal resistance in ohms.
    """

    c_b_f: float
    c_s_f: float
    r_b_ohm: float
    r_s_ohm: float
    r_t_ohm: float


class SaftRcModel:
    """Linear state-space RC model with states ``x = [V_cb, V_cs, V_o]`` in volts."""

    STATE_NAMES = ("v_cb_v", "v_cs_v", "v_o_v")

    def __init__(self, params: RcModelParams) -> None:
        p = params
        self.params = p
        s = p.r_b_ohm + p.r_s_ohm
        self.r_eq_ohm = p.r_t_ohm + p.r_b_ohm * p.r_s_ohm / s
        a33 = p.r_s_ohm / (p.c_b_f * p.r_b_ohm * s) - 1.0 / (p.c_s_f * s)
        b31 = (
            p.r_b_ohm**2 / (p.c_s_f * s**2)
            - p.r_s_ohm * p.r_t_ohm / (p.c_b_f * p.r_b_ohm * s)
            + p.r_t_ohm / (p.c_s_f * s)
            + p.r_s_ohm * p.r_b_ohm / (p.c_s_f * s**2)
        )
        #: Continuous A (charge-positive current), seed 000 eq. 1 with A31 = -A33.
        self.a_c = np.array(
            [
                [-1.0 / (p.c_b_f * s), 1.0 / (p.c_b_f * s), 0.0],
                [1.0 / (p.c_s_f * s), -1.0 / (p.c_s_f * s), 0.0],
                [-a33, 0.0, a33],
            ]
        )
        #: Continuous B for a CHARGE-positive current, seed 000 eq. 1 with B31 corrected.
        self.b_c_charge = np.array([p.r_s_ohm / (p.c_b_f * s), p.r_b_ohm / (p.c_s_f * s), b31])
        #: Output row: the terminal voltage is the third state (seed 000 eq. 2).
        self.h = np.array([0.0, 0.0, 1.0])
        self._cache: dict[float, tuple[np.ndarray, np.ndarray]] = {}

    def discretize(self, dt_s: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Exact ZOH discretization for a step of ``dt_s`` seconds, in the core convention.

        Returns ``(F, g_hold, g_jump)`` such that, with discharge-positive currents
        ``i_k`` held over ``[t_k, t_k + dt)`` and ``i_next`` from ``t_k + dt`` on::

            x_next = F @ x + g_hold * i_k + g_jump * (i_next - i_k)
        """
        if not dt_s > 0.0:
            raise ValueError(f"dt_s must be > 0, got {dt_s}")
        key = round(dt_s, 9)
        hit = self._cache.get(key)
        if hit is None:
            m = np.zeros((4, 4))
            m[:3, :3] = self.a_c
            m[:3, 3] = self.b_c_charge
            e = expm(m * dt_s)
            hit = (e[:3, :3].copy(), -e[:3, 3].copy())  # minus: core current = -charge current
            if len(self._cache) > 64:
                self._cache.clear()
            self._cache[key] = hit
        f, g_hold = hit
        g_jump = np.array([0.0, 0.0, -self.r_eq_ohm])
        return f, g_hold, g_jump

    def step(
        self, x: np.ndarray, current_a: float, next_current_a: float, dt_s: float
    ) -> np.ndarray:
        """State after ``dt_s`` of ``current_a``, with the current then stepping to ``next``."""
        f, g_hold, g_jump = self.discretize(dt_s)
        return f @ x + g_hold * current_a + g_jump * (next_current_a - current_a)

    def rested_state(self, ocv_v: float, current_a: float = 0.0) -> np.ndarray:
        """Equilibrium state for a pack at ``ocv_v`` that starts carrying ``current_a`` now."""
        return np.array([ocv_v, ocv_v, ocv_v - self.r_eq_ohm * current_a])

    def terminal_voltage(self, x: np.ndarray) -> float:
        """Terminal voltage in volts (seed 000 eq. 2)."""
        return float(x[2])

    def consistent_terminal_voltage(self, x: np.ndarray, current_a: float) -> float:
        """V_o computed from V_cb, V_cs and the current (no V_o state): the circuit's output."""
        p = self.params
        s = p.r_b_ohm + p.r_s_ohm
        return float((p.r_s_ohm * x[0] + p.r_b_ohm * x[1]) / s - self.r_eq_ohm * current_a)
