"""Expose a filterpy filter's ``x`` and ``P`` as the estimator's ``x`` and ``p``."""

from __future__ import annotations

from typing import Any

import numpy as np


class FilterpyState:
    """Mixin: ``self.kf`` is a filterpy filter; ``x``/``p`` read and write its state."""

    kf: Any

    @property
    def x(self) -> np.ndarray:
        return self.kf.x

    @x.setter
    def x(self, value: np.ndarray) -> None:
        self.kf.x = value

    @property
    def p(self) -> np.ndarray:
        return self.kf.P

    @p.setter
    def p(self, value: np.ndarray) -> None:
        self.kf.P = value
