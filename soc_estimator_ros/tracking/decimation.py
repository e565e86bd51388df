"""A filter rate below the input rate: samples between filter steps counted as charge.

At 100 Hz input a filter step (a UKF's sigma points, the runtime monitor, the health monitor)
costs several times what receiving and republishing a message does; the battery's dynamics
(time constants of seconds to hours) need nothing near 100 Hz. With ``filter_period_s`` > 0
the tracker steps the estimator once per period on the interval's summary:

* **charge, exactly**: every sample's current is integrated as the estimator integrates it
  (held from one sample to the next), ``q = sum_j i_(j-1) * dt_j``, and the filter step holds
  ``q / T`` over the interval's length ``T`` (``Estimator.step``'s ``held_current_a``): the SoC
  moves by the same counted charge as with a step on every sample;
* **voltage, averaged**: the update reads the interval's mean voltage with its mean current
  (so the ``R_0`` drop stays paired with the current that caused it; the RC voltages lag the
  mean by ``T / 2``, a fraction of a per cent of their shortest time constant at ``T`` = 0.1 s)
  and the mean cell voltages; the cells' filters hold the same counted charge;
* **charge efficiency**: applied to the interval's net charge (the held current's sign), so an
  interval holding both signs of current differs from per-sample counting by the efficiency's
  share of its charging part;
* **between steps**: every sample still gets an estimate, the last step's SoC moved by the
  charge counted since (the filter's own prediction of the SoC), with the step's variance.

``filter_period_s`` = 0 steps on every sample (the default: bit for bit as before).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: Slack on the period (s): 10 samples of 0.01 s add up to 0.09999999999999999.
PERIOD_SLACK_S = 1e-6


def filter_period_s(rate_hz: float) -> float:
    """``TrackerConfig.filter_period_s`` of a filter rate (the node's ``filter_rate_hz``,
    ``soc_replay --filter-rate-hz``): 0 Hz is 0 s, a step on every sample."""
    return 1.0 / rate_hz if rate_hz > 0.0 else 0.0


@dataclass(frozen=True)
class Interval:
    """The samples since the last filter step, summarized for the next one.

    Attributes:
        held_current_a: the counted charge over the interval's length (A, discharge +).
        mean_current_a: the samples' mean current (A), paired with ``mean_voltage_v``.
        mean_voltage_v: the samples' mean voltage (V).
        mean_cell_voltage_v: the samples' mean cell voltages (V; empty unless every sample of
            the interval carried the same number of them).
    """

    held_current_a: float
    mean_current_a: float
    mean_voltage_v: float
    mean_cell_voltage_v: tuple[float, ...]


class Decimator:
    """Accumulates samples between filter steps (module docstring)."""

    def __init__(self, period_s: float) -> None:
        if not period_s > 0.0:
            raise ValueError(f"filter period must be > 0 s, got {period_s}")
        self.period_s = period_s
        self._t_step_s: float | None = None
        self._t_prev_s = 0.0
        self._i_prev_a = 0.0
        self._reset_sums()

    def _reset_sums(self) -> None:
        self._charge_as = 0.0
        self._sum_i_a = 0.0
        self._sum_v_v = 0.0
        self._n = 0
        self._sum_cells_v: np.ndarray | None = None
        self._cells_ok = True

    @property
    def charge_since_step_as(self) -> float:
        """Charge counted since the last filter step (A s, discharge +)."""
        return self._charge_as

    def add(
        self, t_s: float, current_a: float, voltage_v: float, cell_voltage_v: tuple[float, ...]
    ) -> Interval | None:
        """One accepted sample; the interval to step the filter on when one is due, else None.

        The first sample is always a step. A SoC reset between steps keeps the pending charge:
        the reset applies at the last step's time, at most one period earlier.
        """
        if self._t_step_s is None:
            self._start(t_s, current_a)
            return Interval(current_a, current_a, voltage_v, cell_voltage_v)
        self._charge_as += self._i_prev_a * (t_s - self._t_prev_s)
        self._t_prev_s, self._i_prev_a = t_s, current_a
        self._sum_i_a += current_a
        self._sum_v_v += voltage_v
        self._n += 1
        self._add_cells(cell_voltage_v)
        length_s = t_s - self._t_step_s
        if length_s + PERIOD_SLACK_S < self.period_s:
            return None
        n = self._n
        cells: tuple[float, ...] = ()
        if self._cells_ok and self._sum_cells_v is not None:
            cells = tuple(float(v) for v in self._sum_cells_v / n)
        interval = Interval(
            held_current_a=self._charge_as / length_s if length_s > 0.0 else current_a,
            mean_current_a=self._sum_i_a / n,
            mean_voltage_v=self._sum_v_v / n,
            mean_cell_voltage_v=cells,
        )
        self._start(t_s, current_a)
        return interval

    def _add_cells(self, cell_voltage_v: tuple[float, ...]) -> None:
        if not cell_voltage_v:
            self._cells_ok = False
            return
        v = np.asarray(cell_voltage_v, dtype=float)
        if self._sum_cells_v is None:
            self._sum_cells_v = v.copy()
        elif self._sum_cells_v.shape == v.shape:
            self._sum_cells_v += v  # a NaN (a rejected cell) stays NaN: rejected again
        else:
            self._cells_ok = False

    def _start(self, t_s: float, current_a: float) -> None:
        self._t_step_s = self._t_prev_s = t_s
        self._i_prev_a = current_a
        self._reset_sums()
