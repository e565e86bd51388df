"""The full capacity from pairs of well-known SoC points: a weighted total-least-squares fit.

Between two moments where the SoC is well known (a rest long enough to read the OCV where the
curve is steep, a CC-CV charge's end at full), the charge counted ``dq`` (Ah, discharge
positive) and the SoC change ``ds`` (the earlier SoC less the later one) satisfy ``dq = Q ds``,
with errors in both: ``dq`` carries the current sensor's offset and gain errors, ``ds`` the two
readings' errors. Ordinary least squares of one on the other is biased when the other is noisy
(the "errors in variables" problem); Plett's weighted total least squares weighs each pair by
both (G. L. Plett, "Recursive approximate weighted total least squares estimation of battery
cell total capacity", J. Power Sources 196 (2011) 2319-2331, his WTLS cost):

    J(Q) = sum_i (dq_i - Q ds_i)^2 / (var_dq_i + Q^2 var_ds_i)  +  (Q - Q_p)^2 / var_p

with the prior ``(Q_p, var_p)`` (the battery file's capacity for a pack of unknown age, or what
an earlier run learned). Plett approximates ``J`` by a quartic in ``Q`` so that it can be
updated recursively from running sums (AWTLS); here a run keeps its few pairs (a rest or a
charge each, a handful per mission; at most :data:`MAX_PAIRS`) and minimizes the exact ``J``,
which is cheap at that size. The variance of the estimate is the inverse of half the
curvature of ``J`` at its minimum (``J`` is a chi-square: ``var = 2 / J''``), the Laplace
approximation; across runs only ``(Q, var)`` is kept and becomes the next run's prior, so the
learning is recursive across restarts without the quartic's approximation inside a run.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from scipy.optimize import minimize_scalar

#: Pairs kept in one run (the oldest are folded into the prior beyond it).
MAX_PAIRS = 64
#: The fit searches ``Q`` within these multiples of the prior (a pack with a third of its
#: rating, or double: beyond either, the file is for another pack).
Q_RANGE = (0.3, 2.0)


@dataclass(frozen=True)
class CapacityPair:
    """The charge counted between two SoC readings and the SoC change, with their variances.

    Attributes:
        charge_ah: charge counted from the first reading to the second (Ah, discharge +).
        charge_var_ah2: its variance (Ah^2).
        soc_drop: the first reading's SoC less the second's.
        soc_drop_var: its variance (the two readings' variances summed).
    """

    charge_ah: float
    charge_var_ah2: float
    soc_drop: float
    soc_drop_var: float

    @property
    def capacity_ah(self) -> float:
        """The pair's own capacity, ``dq / ds`` (inf when ``ds`` is 0)."""
        return self.charge_ah / self.soc_drop if self.soc_drop != 0.0 else math.inf


def wtls_cost(q_ah: float, pairs: list[CapacityPair], prior_ah: float, prior_var: float) -> float:
    """``J(Q)`` of the module docstring."""
    j = (q_ah - prior_ah) ** 2 / prior_var
    for p in pairs:
        j += (p.charge_ah - q_ah * p.soc_drop) ** 2 / (
            p.charge_var_ah2 + q_ah * q_ah * p.soc_drop_var
        )
    return j


def fit_capacity(
    pairs: list[CapacityPair], prior_ah: float, prior_var: float
) -> tuple[float, float]:
    """The capacity minimizing :func:`wtls_cost` and its variance ``2 / J''`` (Ah, Ah^2)."""
    if not pairs:
        return prior_ah, prior_var
    lo, hi = Q_RANGE[0] * prior_ah, Q_RANGE[1] * prior_ah
    res = minimize_scalar(
        wtls_cost,
        bounds=(lo, hi),
        args=(pairs, prior_ah, prior_var),
        method="bounded",
        options={"xatol": 1e-6 * prior_ah},
    )
    q = float(res.x)
    h = 1e-4 * q  # central second difference; J is smooth and its scale is ~1/var
    curvature = (
        wtls_cost(q + h, pairs, prior_ah, prior_var)
        - 2.0 * wtls_cost(q, pairs, prior_ah, prior_var)
        + wtls_cost(q - h, pairs, prior_ah, prior_var)
    ) / (h * h)
    var = 2.0 / curvature if curvature > 0.0 else prior_var
    return q, min(var, prior_var)


class CapacityEstimator:
    """The prior, the run's pairs and the fit (module docstring)."""

    def __init__(self, prior_ah: float, prior_var: float) -> None:
        if not (prior_ah > 0.0 and prior_var > 0.0):
            raise ValueError(f"capacity prior needs Q > 0 and var > 0, got {prior_ah}, {prior_var}")
        self.prior_ah = prior_ah
        self.prior_var = prior_var
        self.pairs: list[CapacityPair] = []
        self.capacity_ah, self.capacity_var = prior_ah, prior_var

    def grow_prior(self, var: float) -> None:
        """Widen the prior by ``var`` (Ah^2): the capacity drifts as the pack ages."""
        self.prior_var += var
        self.capacity_ah, self.capacity_var = fit_capacity(
            self.pairs, self.prior_ah, self.prior_var
        )

    def add(self, pair: CapacityPair) -> None:
        """Take one pair and fit again."""
        if len(self.pairs) >= MAX_PAIRS:
            # Fold the oldest pair into the prior (the fit with it alone, Laplace).
            self.prior_ah, self.prior_var = fit_capacity(
                self.pairs[:1], self.prior_ah, self.prior_var
            )
            self.pairs.pop(0)
        self.pairs.append(pair)
        self.capacity_ah, self.capacity_var = fit_capacity(
            self.pairs, self.prior_ah, self.prior_var
        )

    @property
    def capacity_std_ah(self) -> float:
        """The estimate's standard deviation (Ah)."""
        return math.sqrt(self.capacity_var)
