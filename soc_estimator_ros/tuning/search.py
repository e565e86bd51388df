"""What ``soc_tune`` searches: a box of tuning entries, and its candidates.

A dimension is a tuning entry (``r``) or one element of a tuple entry (``q_diag.0``) between two
bounds, searched uniformly or, with ``log``, log-uniformly (noise variances span decades).
The candidates are the file's own tuning first (no change: the baseline every tuning must beat)
and then either ``n`` random draws from the box, the same for a seed (random search: Bergstra &
Bengio, "Random search for hyper-parameter optimization", JMLR 13, 2012, which finds it no
worse than a grid for a few effective dimensions, and it needs no model of the objective), or
the file's tuning moved one dimension at a time by ``step`` of that dimension's range either
way (local search: one step of a compass search, Kolda, Lewis & Torczon, "Optimization by
direct search", SIAM Review 45, 2003, section 3; log dimensions move in log space, so a step
of 0.15 over ``r``'s three decades is a factor of 2.8). Random draws over a wide box choose
harmful tunings as readily as good ones on a few recordings (docs/tuning.md); the local
candidates stay next to a tuning that was identified, so a fold can only move it a step.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np


@dataclass(frozen=True)
class Dimension:
    """One searched entry: ``key`` (``index`` an element of a tuple entry) in [lo, hi]."""

    key: str
    lo: float
    hi: float
    log: bool = False
    index: int | None = None

    def __post_init__(self) -> None:
        if not (math.isfinite(self.lo) and math.isfinite(self.hi) and self.lo < self.hi):
            raise ValueError(f"{self.label}: bounds must be finite with lo < hi")
        if self.log and self.lo <= 0.0:
            raise ValueError(f"{self.label}: a log dimension needs lo > 0")

    @property
    def label(self) -> str:
        return self.key if self.index is None else f"{self.key}.{self.index}"

    def position(self, value: float) -> float:
        """Where ``value`` lies in the box, 0 at ``lo`` and 1 at ``hi`` (log dimensions in log
        space); outside the box below 0 or above 1."""
        if self.log:
            return math.log(value / self.lo) / math.log(self.hi / self.lo)
        return (value - self.lo) / (self.hi - self.lo)

    def at(self, position: float) -> float:
        """The value at ``position`` (the inverse of :meth:`position`)."""
        if self.log:
            return float(self.lo * (self.hi / self.lo) ** position)
        return float(self.lo + (self.hi - self.lo) * position)

    def draw(self, rng: np.random.Generator) -> float:
        if self.log:
            return float(math.exp(rng.uniform(math.log(self.lo), math.log(self.hi))))
        return float(rng.uniform(self.lo, self.hi))


def parse_dimension(text: str) -> Dimension:
    """``KEY=LO:HI`` or ``KEY=LO:HI:log``; ``KEY`` may be ``name.index`` for a tuple entry."""
    try:
        key, spec = text.split("=", 1)
        parts = spec.split(":")
        if len(parts) not in (2, 3) or (len(parts) == 3 and parts[2] != "log"):
            raise ValueError
        name, _, index = key.partition(".")
        return Dimension(
            name, float(parts[0]), float(parts[1]), len(parts) == 3, int(index) if index else None
        )
    except ValueError as exc:
        detail = f": {exc}" if str(exc) else ""
        raise ValueError(f"--space {text!r}: expected KEY=LO:HI[:log]{detail}") from None


#: The searched entries when ``--space`` is not given, per estimator: the measurement noise
#: (light load and per ampere), the model-error state's size, the rest reading's std and the
#: SoC process noise, each over the range a filter of that kind is tuned in (docs/accuracy.md).
DEFAULT_SPACES: dict[str, tuple[Dimension, ...]] = {
    "hybrid": (
        Dimension("r", 1e-3, 1.0, log=True),
        Dimension("r_per_a", 1e-4, 2e-2, log=True),
        Dimension("bias_std_v", 3e-3, 0.1, log=True),
        Dimension("ocv_std_v", 5e-3, 5e-2, log=True),
        Dimension("q_diag", 1e-12, 1e-8, log=True, index=0),
    ),
    "t2rc_ukf": (
        Dimension("r", 1e-3, 10.0, log=True),
        Dimension("q_diag", 1e-12, 1e-8, log=True, index=0),
    ),
}


def apply(base: Mapping[str, Any], values: Mapping[str, float]) -> dict[str, Any]:
    """``base`` (a full tuning) with ``values`` by :attr:`Dimension.label` put in."""
    out = dict(base)
    for label, value in values.items():
        name, _, index = label.partition(".")
        if index:
            entry = list(out[name])
            entry[int(index)] = value
            out[name] = tuple(entry)
        else:
            out[name] = value
    return out


def describe(values: Mapping[str, float]) -> str:
    """A candidate as printed: ``r 0.05, q_diag.0 3.981e-10``, or "the file's" for ``{}``."""
    return ", ".join(f"{k} {v:.4g}" for k, v in values.items()) or "the file's"


def candidates(space: Sequence[Dimension], n: int, seed: int) -> list[dict[str, float]]:
    """The file's tuning (``{}``: nothing changed) and ``n`` draws, by label."""
    rng = np.random.default_rng(seed)
    return [{}] + [{d.label: d.draw(rng) for d in space} for _ in range(n)]


def value_of(base: Mapping[str, Any], d: Dimension) -> float:
    """The entry ``d`` searches, as ``base`` (a full tuning) holds it."""
    entry = base[d.key]
    return float(entry if d.index is None else entry[d.index])


def local_candidates(
    space: Sequence[Dimension], base: Mapping[str, Any], step: float
) -> list[dict[str, float]]:
    """The file's tuning (``{}``) and, for each dimension, the file's value moved by ``step``
    of the box down and up (within the box; a move that changes nothing is left out), by
    label: at most ``2 len(space)`` candidates, the same for every seed. A file's value
    outside the box moves a step toward it and not beyond the value (the LFP file's
    ``r_per_a`` of 0.1 V/A lies above the default box): a local search never jumps."""
    if not 0.0 < step <= 1.0:
        raise ValueError(f"--step {step}: expected a fraction of each range in (0, 1]")
    out: list[dict[str, float]] = [{}]
    for d in space:
        v0 = value_of(base, d)
        if d.log and v0 <= 0.0:
            raise ValueError(f"{d.label}: the file's value {v0} cannot move on a log range")
        u0 = d.position(v0)
        lo, hi = min(u0, 0.0), max(u0, 1.0)
        for u in (u0 - step, u0 + step):
            v = d.at(min(max(u, lo), hi))
            if not math.isclose(v, v0, rel_tol=1e-9, abs_tol=0.0):
                out.append({d.label: v})
    return out
