"""The do-no-harm guard: a charge count with its own error budget, and a two-model fusion.

A voltage-based filter is only as good as its voltage model. Where the model is wrong (a cold
pack outside the temperatures it was identified at, another pack of the same kind, an aged
one), every update reads the model's error as SoC, and the filter's covariance, which assumes
the model right, does not show it (issue 24: 2-12 % errors reported as 0.1-0.9 %). Coulomb
counting from the same start has no such failure: its error is the current sensor's and the
capacity's, and both are known in advance from the sensor's datasheet and the pack's spread.

The guard keeps that count beside the filter and asks, every sample, which of two hypotheses
explains their difference ``d = u - c`` (``u`` the filter's SoC, ``c`` the count's):

* **the model holds** (prior probability ``p``): the filter and the count are two readings of
  the SoC, each within its own error, so ``d ~ N(0, P_u + P_c)``;
* **the model does not hold** (``1 - p``): the filter has been dragged anywhere, ``d`` uniform
  over [-1, 1] (density 1/2).

The posterior weight of the first is ``w = p N(d) / (p N(d) + (1 - p) / 2)``. Under the first
the SoC is the two readings fused by their variances, ``f = c + a d`` with ``a = P_c / (P_u +
P_c)``; the errors of the two are correlated by an unknown amount (the count follows the
filter, below, and both count the same current), so ``f``'s variance is taken at the worst
correlation, 1: ``P_f = ((1 - a) sqrt(P_c) + a sqrt(P_u))^2``, between the two variances and
never below the surer one's (the independent ``P_u P_c / (P_u + P_c)``, tried with the count
following at 30 minutes throughout, held the error on 27 of the 30 LFP tuning missions from
std 0.1 where this held it on 30: docs/accuracy.md). The published estimate
is the two-component mixture (Bar-Shalom, Li & Kirubarajan, *Estimation with Applications to
Tracking and Navigation*, 2001, §11.6: the moments of a Gaussian mixture):

    soc = w f + (1 - w) c,        var = w P_f + (1 - w) P_c + w (1 - w) (f - c)^2

so a filter that strays further from the count than the count's own error budget explains is
weighed out, the variance carries the disagreement (an honest sigma, not the filter's), and a
filter that moves the SoC where it knows no more than the count (LFP's plateau under a model
error: its variance floored above the count's) moves the published SoC only by its share
``a`` (with ``u`` alone in its place, a sure start followed the filter's error in full:
``lfp_tuning_1036``, a pack 6 mOhm below its file, 2.5 points beyond the count's max). The
filter itself runs unchanged beside the guard: when its model holds again its ``d`` comes back
within the budget and its weight returns.

The count's variance since its anchor (a start, a reset, a CC-CV end, a rest OCV reading):

    P_c = P_0 + (s_b t / (3600 Q))^2 + (s_g^2 + s_Q^2) (c - c_0)^2

``s_b`` the current sensor's offset std (A), ``s_g`` its gain std, ``s_Q`` the capacity's
relative std (pack-to-pack spread, ageing): bias-type errors, so they grow linearly with time
and charge moved, not as a random walk. Two readings are fused into the count as scalar Kalman
updates, the count's variance never below the floor from either unless it was below already
(the floor is the hybrid's, ``Hybrid._model_soc_var``: ``model_soc_std^2``, more where the OCV
is flat; both readings go through the model, whose error persists), nor below the filter's
``max(P_u, floor)`` from the filter's SoC:

* a rest reading of the OCV (once per rest, linearized at the count's own SoC, so a millivolt
  on LFP's plateau moves it as little as it moves the filter): the result is a new anchor;
* while the model is trusted (inside the temperatures it was identified at, or outside them
  where the OCV resolves the SoC: ``Hybrid._resolves_outside``; its innovations consistent,
  and not persistently off: hybrid item 11), the filter's own SoC, de-weighted by its
  correlation: one independent reading per ``follow_tau_s`` while the count is less sure than
  the filter (a wrong start the filter corrects), per ``follow_sure_tau_s`` once it is as sure
  (taken once a minute, the count followed ``lfp_tuning_1036``'s dragged filter within minutes
  and the fusion above had nothing left to weigh), its variance ``max(P_u, floor)`` (the UKF's
  ``P_u`` takes the model's error as white, so it leaves out what a persistent one costs).
  This reading does not re-anchor the count: it moves the count, its variance comes off the
  anchor's part, and the growth since the anchor goes on (the sensor's and the capacity's
  errors are not learned from a filter whose error persists; re-anchored on every sample, the
  budget stood still: a sure start's count reported 1.5 % for two hours in which its error
  reached 3.3 points, ``lfp_tuning_1024``).

So a wrong start that the filter corrects at light load is followed within minutes, and a
model dragged outside its envelope is not. A gap or a consistency inflation of the filter
inflates the count too.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from ..models.coulomb import coulomb_step
from ..units import MAX_SOC_VAR, SECONDS_PER_HOUR

#: Density of the "model does not hold" hypothesis: d uniform over [-1, 1].
_WRONG_MODEL_DENSITY = 0.5


@dataclass(frozen=True)
class CountErrorModel:
    """What coulomb counting gets wrong, from the sensor's datasheet and the pack's spread."""

    current_offset_std_a: float
    current_gain_std: float
    capacity_std_frac: float

    def __post_init__(self) -> None:
        for name in ("current_offset_std_a", "current_gain_std", "capacity_std_frac"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0.0):
                raise ValueError(f"{name} must be finite and >= 0, got {value}")


#: The count's error budget, from the sensor and the pack's spread (bags/README.md "Sensors": a
#: Hall sensor's offset within +-30 mA and gain within +-0.8 %, uniform: std 17 mA and 0.46 %;
#: the corpus' capacity spread +-5 %: 2.9 %): the hybrid's tuning entries of these names.
COUNT_ERROR_DEFAULTS = {
    "current_offset_std_a": 0.02,
    "current_gain_std": 0.005,
    "capacity_std_frac": 0.03,
}


def count_errors(entries: Mapping[str, Any]) -> CountErrorModel:
    """The count error budget in ``entries`` (the hybrid's tuning, or a battery file's
    ``filters.hybrid`` block) under :data:`COUNT_ERROR_DEFAULTS`' names, the defaults where
    they have none. One budget per file: the hybrid's guard and every other filter's
    published floor (``base.py``) read it."""
    budget = {k: entries.get(k, v) for k, v in COUNT_ERROR_DEFAULTS.items()}
    return CountErrorModel(**{k: float(v) for k, v in budget.items()})


class ChargeCount:
    """Coulomb counting from an anchor, with the variance of :class:`CountErrorModel`."""

    def __init__(
        self, errors: CountErrorModel, capacity_ah: float, efficiency_charge: float
    ) -> None:
        self.errors = errors
        self.capacity_ah = capacity_ah
        self.efficiency_charge = efficiency_charge
        self.anchor(0.5, 1.0)

    def anchor(self, soc: float, soc_var: float) -> None:
        """Start counting again from ``soc`` (clipped to [0, 1]) with variance ``soc_var``."""
        self.soc = self.soc_anchor = min(max(soc, 0.0), 1.0)
        self.var_anchor = soc_var
        self.elapsed_s = 0.0

    def step(self, current_a: float, dt_s: float) -> None:
        """Count ``current_a`` (positive = discharge) held over ``dt_s``."""
        soc = coulomb_step(self.soc, current_a, dt_s, self.capacity_ah, self.efficiency_charge)
        self.soc = min(max(soc, 0.0), 1.0)
        # As the estimators' clipping does (base.py): the clipped amount becomes variance.
        self.var_anchor = min(self.var_anchor + (soc - self.soc) ** 2, MAX_SOC_VAR)
        self.elapsed_s += dt_s

    @property
    def var(self) -> float:
        """``P_c`` (module docstring): the anchor's variance plus the sensor's and capacity's."""
        e = self.errors
        offset = e.current_offset_std_a * self.elapsed_s / (SECONDS_PER_HOUR * self.capacity_ah)
        moved = self.soc - self.soc_anchor
        scale_var = e.current_gain_std**2 + e.capacity_std_frac**2
        return self.var_anchor + offset * offset + scale_var * moved * moved

    def inflate(self, var: float) -> None:
        """Grow the variance by ``var`` (a gap, a consistency inflation)."""
        self.var_anchor += var

    def fuse(
        self, innovation: float, h: float, r: float, var_floor: float = 0.0, reanchor: bool = True
    ) -> None:
        """Scalar Kalman update with a reading ``y = h SoC + noise(r)`` whose innovation (reading
        minus ``h`` times the count) is ``innovation``, its variance no smaller than
        ``var_floor`` (a reading whose error is not white cannot make the count surer than
        that), nor larger than before: an update never makes the count less sure, so a count
        already surer than the floor keeps its variance. The result is the new anchor
        (``reanchor``: a reading of the SoC itself, the rest's OCV), or (``reanchor=False``: the
        filter's SoC, whose error persists) the count moves and the reduction comes off the
        anchor's variance while the growth since the anchor goes on; a reduction larger than
        the anchor's variance re-anchors."""
        p = self.var
        k = p * h / (h * h * p + r)
        soc, var = self.soc + k * innovation, max((1.0 - k * h) * p, min(p, var_floor))
        growth = p - self.var_anchor
        if reanchor or var < growth:
            self.anchor(soc, var)
            return
        moved = self.soc - self.soc_anchor
        self.soc = min(max(soc, 0.0), 1.0)
        self.soc_anchor = self.soc - moved  # the charge moved since the anchor stays
        self.var_anchor = var - growth


@dataclass(frozen=True)
class Guarded:
    """The guard's output: the published SoC and variance, and the model's weight ``w``."""

    soc: float
    soc_var: float
    model_weight: float


def guard(u: float, u_var: float, c: float, c_var: float, prior: float) -> Guarded:
    """The two-hypothesis mixture of the module docstring (``prior`` = p, the model holds)."""
    v = max(u_var + c_var, 1e-12)
    d = u - c
    right = prior * math.exp(-0.5 * d * d / v) / math.sqrt(2.0 * math.pi * v)
    wrong = (1.0 - prior) * _WRONG_MODEL_DENSITY
    w = right / (right + wrong) if right + wrong > 0.0 else 0.0
    a = c_var / v  # the filter's share of the fusion
    f_var = ((1.0 - a) * math.sqrt(c_var) + a * math.sqrt(u_var)) ** 2
    e = a * d  # the fusion less the count
    soc = c + w * e
    var = w * f_var + (1.0 - w) * c_var + w * (1.0 - w) * e * e
    return Guarded(soc, var, w)
