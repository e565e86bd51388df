"""A learned factor on the model's series resistance ``R_0``, from the pack's current steps.

PX4's battery estimator learns the internal resistance online from how the voltage answers
the current (``src/lib/battery``: a recursive least-squares fit of ``V = OCV - R I``). A step of
the current from one sample to the next is the cleanest such answer: within one sample the
OCV and the slow branches barely move, so the voltage's change is the series drop's
(``dV = -R_0 dI``) plus what the model's faster branches and Butler-Volmer term add. The
model knows those; what it gets wrong on an aged or another pack is mostly ``R_0``. With the
model's own voltage change ``dV_m`` over the step (its branches stepped over the same interval,
at the present factor ``f``), the factor that makes the model answer the step as measured is

    f_obs = f + (dV_m - dV) / (dI R_0(SoC, T))            (dV_m is linear in f through R_0)

with ``R_0(SoC, T)`` the file's table and temperature law at factor 1: the learned factor sits
on top of the temperature dependence, so cold and age are told apart (a cold pack raises the
table's ``R_0``; the factor only learns what the table misses).

Each ``f_obs`` is a scalar measurement of ``f`` with variance

    var = (var_dV + (f R_0 std_dI)^2) / (dI R_0)^2 + model_frac^2

(the ADC's and the current sensor's noise on two samples, and the model's own error of a
step's answer as a fraction), and ``f`` is a random walk (``drift_per_hour``). A scalar Kalman
filter keeps it; an observation beyond ``GATE_SIGMA`` standard deviations is rejected and
counted (a step the sensors caught between two samples, a contact bounce). ``GATE_RESET``
rejections in a row on the same side are not outliers but a prior that is wrong (an aged pack
whose grown resistance lies beyond the prior's reach): the variance is then widened to the
innovation's square and the observation taken, so the gate cannot lock the filter out of the
pack it measures (measured on the simulated aged-75 % LFP pack: every one of 263 steps said
f = 9.2-11.9 against the prior 1 +- 0.3, all rejected, the factor stuck at 1).
"""

from __future__ import annotations

import math

#: Observations further than this many standard deviations from the estimate are rejected.
GATE_SIGMA = 4.0
#: Rejections in a row, on one side of the estimate, that widen the prior (module docstring).
GATE_RESET = 10
#: The factor is kept within these bounds (beyond them the file describes another pack). The
#: upper one is wide: where the file's ``R_0`` is a small part of the instantaneous drop (LFP:
#: 4.8 mOhm beside its kinetic term), an ohmic film grown on an aged pack is a factor of 10
#: (the aged-75 % LFP pack's steps: 9.2-11.9).
FACTOR_RANGE = (0.3, 30.0)


class ResistanceFactor:
    """Scalar Kalman filter on ``f`` (module docstring)."""

    def __init__(self, factor: float, factor_var: float, drift_per_hour: float) -> None:
        if not (factor > 0.0 and factor_var > 0.0 and drift_per_hour >= 0.0):
            raise ValueError(
                f"bad resistance factor prior {factor}, {factor_var}, {drift_per_hour}"
            )
        self.factor = factor
        self.var = factor_var
        self.drift_per_hour = drift_per_hour
        self.used = 0
        self.rejected = 0
        self._rejected_run = 0  # consecutive rejections, signed by their side

    def predict(self, dt_s: float) -> None:
        """The random walk over ``dt_s`` seconds."""
        if dt_s > 0.0:
            self.var += self.drift_per_hour**2 * dt_s / 3600.0

    def update(self, observed: float, observed_var: float) -> bool:
        """Take one observation of ``f``; False (and counted) if the gate rejects it."""
        s = self.var + observed_var
        innovation = observed - self.factor
        if innovation * innovation > GATE_SIGMA**2 * s:
            side = 1 if innovation > 0.0 else -1
            run = self._rejected_run
            self._rejected_run = run + side if run * side >= 0 else side
            if abs(self._rejected_run) < GATE_RESET:
                self.rejected += 1
                return False
            self.var = max(self.var, innovation * innovation)  # the prior was wrong: widen it
            s = self.var + observed_var
        self._rejected_run = 0
        k = self.var / s
        lo, hi = FACTOR_RANGE
        self.factor = min(max(self.factor + k * innovation, lo), hi)
        self.var = (1.0 - k) * self.var
        self.used += 1
        return True

    @property
    def std(self) -> float:
        """The factor's standard deviation."""
        return math.sqrt(self.var)


def step_observation(
    factor: float,
    model_dv_v: float,
    measured_dv_v: float,
    current_step_a: float,
    r0_ohm: float,
    voltage_noise_std_v: float,
    current_noise_std_a: float,
    model_frac: float,
) -> tuple[float, float]:
    """``(f_obs, var)`` of one current step (module docstring).

    Args:
        factor: the present factor ``f`` (the one ``model_dv_v`` was computed with).
        model_dv_v: the model's voltage change over the step (V).
        measured_dv_v: the measured voltage change (V).
        current_step_a: the current's change ``dI`` (A, discharge +).
        r0_ohm: ``R_0(SoC, T)`` at factor 1 (ohms).
        voltage_noise_std_v, current_noise_std_a: one sample's sensor noise.
        model_frac: the model's relative error on a step's answer.
    """
    scale = current_step_a * r0_ohm
    observed = factor + (model_dv_v - measured_dv_v) / scale
    var_dv = 2.0 * voltage_noise_std_v**2
    var_di = 2.0 * current_noise_std_a**2
    var = (var_dv + (factor * r0_ohm) ** 2 * var_di) / (scale * scale) + model_frac**2
    return observed, var
