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

A reading's SoC may depend on ``Q`` itself: an aged pack's OCV is not the fresh pack's the
file holds (:class:`OcvAgeing`), and how far it moved goes with how much capacity was lost.
The pair then keeps its two readings as read, and ``J`` maps them at each trial ``Q``
(``ds_i(Q)``, ``var_ds_i(Q)``), which stays exact where a correction made once with the
capacity known at the time would carry that capacity's error into every later fit.
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
class OcvAgeing:
    """How a rest reading of an aged pack, taken through the fresh pack's rested OCV, maps to
    the aged pack's SoC (each SoC a fraction of that pack's own capacity):

        s = p + (s_read - p) (Q_file / Q)^k      for s_read < below_soc, else s = s_read

    The pivot ``p`` is the end of the range where the aged and the fresh pack agree.

    * LFP/graphite (``p`` 0, below the plateau): the OCV there is the graphite's staging, and
      lithium lost shifts the graphite's window; at a given fraction of its own capacity an
      aged pack sits where the fresh one sits at a lower fraction (in the simulator the 75 %
      pack rests 72 mV below the fresh one at 30 %, 34 mV at 20 %), so its readings come out
      low. Were the graphite alone to set both the capacity and the knee, ``k`` would be 1;
      the active material lost beside the lithium makes it less. Above ``below_soc`` (the top
      knee, where the cathode sets full) a reading is taken as read.
    * Lead-acid (``p`` 1): the OCV is the acid's concentration, which falls with the charge
      drawn from full; with plate area lost, a fraction of the smaller capacity draws less of
      the acid, so the aged pack rests above the fresh one and reads high: the depth of
      discharge read, ``1 - s_read``, is short by a factor that grows with the loss.

    ``k`` is a measured property of the chemistry's ageing, chosen on tuning packs
    (docs/architecture.md#health; ``benchmarks/studies/health.py --readings``).

    Attributes:
        exponent: ``k`` (0: the OCV does not age).
        pivot_soc: ``p``.
        below_soc: readings below this are mapped.
        file_capacity_ah: ``Q_file``, the capacity the OCV tables were identified with.
    """

    exponent: float
    pivot_soc: float
    below_soc: float
    file_capacity_ah: float

    def soc(self, soc_read: float, q_ah: float) -> tuple[float, float]:
        """The reading's SoC at capacity ``q_ah`` and its derivative by ``soc_read``."""
        if soc_read >= self.below_soc:
            return soc_read, 1.0
        scale = (self.file_capacity_ah / q_ah) ** self.exponent
        return self.pivot_soc + (soc_read - self.pivot_soc) * scale, scale


@dataclass(frozen=True)
class CapacityPair:
    """The charge counted between two SoC readings and the readings, with their variances.

    Attributes:
        charge_ah: charge counted from the first reading to the second (Ah, discharge +).
        charge_var_ah2: its variance (Ah^2).
        soc_from, soc_from_var: the first reading's SoC (as read) and its variance.
        soc_to, soc_to_var: the second's.
        t_from_s, t_to_s: when the two readings were taken (the run's sample time, s).
    """

    charge_ah: float
    charge_var_ah2: float
    soc_from: float
    soc_from_var: float
    soc_to: float
    soc_to_var: float
    t_from_s: float = math.nan
    t_to_s: float = math.nan

    def soc_drop(self, q_ah: float, ageing: OcvAgeing | None = None) -> tuple[float, float]:
        """The SoC change (first less second) and its variance at capacity ``q_ah``."""
        if ageing is None:
            return self.soc_from - self.soc_to, self.soc_from_var + self.soc_to_var
        s_from, d_from = ageing.soc(self.soc_from, q_ah)
        s_to, d_to = ageing.soc(self.soc_to, q_ah)
        return s_from - s_to, d_from * d_from * self.soc_from_var + d_to * d_to * self.soc_to_var

    @property
    def capacity_ah(self) -> float:
        """The pair's own capacity as read, ``dq / ds`` (inf when ``ds`` is 0)."""
        ds = self.soc_from - self.soc_to
        return self.charge_ah / ds if ds != 0.0 else math.inf


def wtls_cost(
    q_ah: float,
    pairs: list[CapacityPair],
    prior_ah: float,
    prior_var: float,
    ageing: OcvAgeing | None = None,
) -> float:
    """``J(Q)`` of the module docstring."""
    j = (q_ah - prior_ah) ** 2 / prior_var
    for p in pairs:
        ds, ds_var = p.soc_drop(q_ah, ageing)
        j += (p.charge_ah - q_ah * ds) ** 2 / (p.charge_var_ah2 + q_ah * q_ah * ds_var)
    return j


def fit_capacity(
    pairs: list[CapacityPair],
    prior_ah: float,
    prior_var: float,
    ageing: OcvAgeing | None = None,
) -> tuple[float, float]:
    """The capacity minimizing :func:`wtls_cost` and its variance ``2 / J''`` (Ah, Ah^2)."""
    if not pairs:
        return prior_ah, prior_var
    lo, hi = Q_RANGE[0] * prior_ah, Q_RANGE[1] * prior_ah
    args = (pairs, prior_ah, prior_var, ageing)
    res = minimize_scalar(
        wtls_cost, bounds=(lo, hi), args=args, method="bounded", options={"xatol": 1e-6 * prior_ah}
    )
    q = float(res.x)
    h = 1e-4 * q  # central second difference; J is smooth and its scale is ~1/var
    curvature = (wtls_cost(q + h, *args) - 2.0 * wtls_cost(q, *args) + wtls_cost(q - h, *args)) / (
        h * h
    )
    var = 2.0 / curvature if curvature > 0.0 else prior_var
    return q, min(var, prior_var)


class CapacityEstimator:
    """The prior, the run's pairs and the fit (module docstring)."""

    def __init__(self, prior_ah: float, prior_var: float, ageing: OcvAgeing | None = None) -> None:
        if not (prior_ah > 0.0 and prior_var > 0.0):
            raise ValueError(f"capacity prior needs Q > 0 and var > 0, got {prior_ah}, {prior_var}")
        self.prior_ah = prior_ah
        self.prior_var = prior_var
        self.ageing = ageing
        self.pairs: list[CapacityPair] = []
        self.capacity_ah, self.capacity_var = prior_ah, prior_var

    def grow_prior(self, var: float) -> None:
        """Widen the prior by ``var`` (Ah^2): the capacity drifts as the pack ages."""
        self.prior_var += var
        self.capacity_ah, self.capacity_var = fit_capacity(
            self.pairs, self.prior_ah, self.prior_var, self.ageing
        )

    def add(self, pair: CapacityPair) -> None:
        """Take one pair and fit again."""
        if len(self.pairs) >= MAX_PAIRS:
            # Fold the oldest pair into the prior (the fit with it alone, Laplace).
            self.prior_ah, self.prior_var = fit_capacity(
                self.pairs[:1], self.prior_ah, self.prior_var, self.ageing
            )
            self.pairs.pop(0)
        self.pairs.append(pair)
        self.capacity_ah, self.capacity_var = fit_capacity(
            self.pairs, self.prior_ah, self.prior_var, self.ageing
        )

    @property
    def capacity_std_ah(self) -> float:
        """The estimate's standard deviation (Ah)."""
        return math.sqrt(self.capacity_var)
