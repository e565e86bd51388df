"""What ``soc_tune`` searches: a box of tuning entries, and its candidates.

A dimension is a tuning entry (``r``) or one element of a tuple entry (``q_diag.0``) between two
bounds, searched uniformly or, with ``log``, log-uniformly (noise variances span decades).
The candidates are the file's own tuning first (no change: the baseline every tuning must beat)
and then ``n`` random draws from the box, the same for a seed (random search: Bergstra &
Bengio, "Random search for hyper-parameter optimization", JMLR 13, 2012, which finds it no
worse than a grid for a few effective dimensions, and it needs no model of the objective).
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


def candidates(space: Sequence[Dimension], n: int, seed: int) -> list[dict[str, float]]:
    """The file's tuning (``{}``: nothing changed) and ``n`` draws, by label."""
    rng = np.random.default_rng(seed)
    return [{}] + [{d.label: d.draw(rng) for d in space} for _ in range(n)]
