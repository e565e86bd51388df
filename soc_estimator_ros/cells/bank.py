"""The cells of a series pack beside the pack's estimator: gate each cell's reading, run the
bar-delta filters (``filter.py``), and make what the node publishes (``CellEstimate``).

Cell ``i``'s SoC is the pack's plus its deviation, ``SoC_i = s_bar + d_i``, with variance
``var(s_bar) + var(d_i)`` (Plett vol. II, eq. 4.1: the two errors taken independent).

Usable pack SoC (a series pack carries one current, so it stops when its first cell does):

* discharge: the weakest cell's remaining charge over the pack's capacity,
  ``min_i SoC_i (1 + e_i)``: it reaches 0 when that cell is empty;
* charge: ``1 - min_i (1 - SoC_i)(1 + e_i)``: it reaches 1 when the strongest (fullest) cell
  is full.

The voltage update runs only after ``rest_min_s`` at no more than ``rest_current_c_rate``
(the robot stopped): under load and for a minute after it, the cells' voltages differ by their
unequal polarization (the weaker cell carries a higher current density) more than by their
SoC, and a filter reading that as SoC pulled the weakest cell 5 points low on the simulated
pack's lower knee.

A cell reading at or below the cell's under-voltage limit for ``cutoff_hold_s`` (1 s of
sample time: one glitching reading is not a cut-off, as a BMS's under-voltage delay) is the
pack's cut-off (a BMS stops the pack there; seed 001's protects every cell against deep
discharge): the usable discharge SoC is then 0, and stays 0 under load until the robot stops
(|I| at most the rest current) with every cell above its limit. The charge the estimate still
counts in that cell (5-9 % of its C/20 charge on the simulated 4S missions at 4 A, 25 % under a
17.6-A peak at 0.5 degC) is what the load's polarization withholds: there for a lighter load,
not for this one.

A cell reading that is not finite or lies more than ``absurd_margin_v`` outside the cell
limits is rejected for that cell alone (counted per cell): the others are still updated.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..models.ocv import OcvCurve
from ..params import BatteryParams
from .filter import CellDeltaFilter, CellFilterConfig

#: What the estimate vector carries after the cells' SoC and std (``cell.<name>``).
CELL_SUMMARY_FIELDS = (
    "usable_soc",
    "usable_soc_std",
    "usable_charge_soc",
    "weakest",
    "imbalance_soc",
    "spread_v",
)


@dataclass(frozen=True)
class CellEstimate:
    """The cells after one sample.

    Attributes:
        soc: every cell's SoC (fraction), series order.
        soc_std: its std.
        voltage_v: the readings (NaN where rejected).
        accepted: which readings were used.
        usable_soc, usable_soc_std: the usable discharge SoC (module docstring) and its std
            (the weakest cell's).
        usable_charge_soc: the usable charge SoC.
        weakest: index (0-based) of the cell with the least remaining charge.
        strongest: index of the cell closest to full.
        imbalance_soc: max - min cell SoC.
        spread_v: max - min accepted cell voltage (V; NaN with fewer than two).
        under_voltage, over_voltage: per cell, the reading beyond the cell limits.
    """

    soc: np.ndarray
    soc_std: np.ndarray
    voltage_v: np.ndarray
    accepted: np.ndarray
    usable_soc: float
    usable_soc_std: float
    usable_charge_soc: float
    weakest: int
    strongest: int
    imbalance_soc: float
    spread_v: float
    under_voltage: np.ndarray
    over_voltage: np.ndarray

    @property
    def cells(self) -> int:
        return int(self.soc.size)

    def fields(self) -> dict[str, float]:
        """The estimate vector's ``cell.*`` values by name (``weakest`` 1-based)."""
        out: dict[str, float] = {}
        for k in range(self.cells):
            out[f"soc_{k + 1}"] = float(self.soc[k])
        for k in range(self.cells):
            out[f"soc_std_{k + 1}"] = float(self.soc_std[k])
        out.update(
            usable_soc=self.usable_soc,
            usable_soc_std=self.usable_soc_std,
            usable_charge_soc=self.usable_charge_soc,
            weakest=float(self.weakest + 1),
            imbalance_soc=self.imbalance_soc,
            spread_v=self.spread_v,
        )
        return out


def cell_field_names(cells: int) -> list[str]:
    """Names of :meth:`CellEstimate.fields` for ``cells`` cells, in order."""
    return [
        *(f"soc_{k + 1}" for k in range(cells)),
        *(f"soc_std_{k + 1}" for k in range(cells)),
        *CELL_SUMMARY_FIELDS,
    ]


def cell_limits_v(battery: BatteryParams, cells: int) -> tuple[float, float]:
    """A cell's under- and over-voltage limits (V): the file's ``cells:`` entries, else the
    pack's limits over the cell count."""
    c = battery.cells
    lo = c.cell_voltage_min_v or battery.limits.voltage_min_v / cells
    hi = c.cell_voltage_max_v or battery.limits.voltage_max_v / cells
    return lo, hi


def cell_filter_config(battery: BatteryParams, cells: int) -> CellFilterConfig:
    """The filter's settings from the battery file (``cells:``; the pack's per cell)."""
    c = battery.cells
    r_std = c.resistance_spread_std_ohm
    if r_std <= 0.0:  # 20 % of the 1-C instantaneous drop per ampere, per cell
        i_1c = battery.nominal_capacity_ah
        drop = battery.thevenin_model().series_drop_v(0.5, i_1c, 25.0)
        r_std = 0.2 * drop / i_1c / cells
    return CellFilterConfig(
        cells=cells,
        capacity_ah=battery.capacity_ah,
        eta_charge=battery.coulomb_efficiency_charge,
        soc_std=c.soc_spread_std,
        capacity_std=c.capacity_spread_std,
        resistance_std_ohm=r_std,
        voltage_std_v=c.voltage_std_v,
        voltage_std_per_a=c.voltage_std_per_a,
        soc_walk_per_hour=c.soc_walk_per_hour,
        ocv_soc_std=c.ocv_soc_std,
        error_corr_s=c.error_corr_s,
    )


class CellBank:
    """Every cell of a series pack of ``cells`` cells (module docstring)."""

    def __init__(self, battery: BatteryParams, cells: int) -> None:
        if cells < 2:
            raise ValueError(f"cells = {cells}: a series pack of at least 2 cells")
        self.cells = cells
        pack_ocv = battery.ocv
        self._ocv = OcvCurve(pack_ocv.soc, np.asarray(pack_ocv.voltage_v) / cells)
        self.config = cell_filter_config(battery, cells)
        self.filter = CellDeltaFilter(self.config, self._ocv)
        self.v_min, self.v_max = cell_limits_v(battery, cells)
        margin = battery.cells.absurd_margin_v
        self._absurd_lo = max(0.0, self.v_min - margin)
        self._absurd_hi = self.v_max + margin
        #: Readings rejected, per cell.
        self.rejected = np.zeros(cells, dtype=np.int64)
        self._t_s: float | None = None
        self._i_prev_a = 0.0
        self._rest_a = battery.cells.rest_current_c_rate * battery.nominal_capacity_ah
        self._rest_min_s = battery.cells.rest_min_s
        self._rest_since_s: float | None = None
        #: A cell read at or below its limit for ``cutoff_hold_s``, and the load has not
        #: stopped since; and since when a cell has been at or below it.
        self._at_cutoff = False
        self._cutoff_hold_s = battery.cells.cutoff_hold_s
        self._under_since_s: float | None = None
        self.last: CellEstimate | None = None

    def reset(self) -> None:
        """Forget the cells (another pack): the priors again."""
        self.filter = CellDeltaFilter(self.config, self._ocv)
        self._t_s = None
        self._rest_since_s = None
        self._at_cutoff = False
        self._under_since_s = None
        self.last = None

    def accept(self, cell_voltage_v: np.ndarray) -> np.ndarray:
        """Which readings are usable (finite, not absurd; a NaN compares False)."""
        v = cell_voltage_v
        return (v >= self._absurd_lo) & (v <= self._absurd_hi)

    def step(
        self,
        t_s: float,
        current_a: float,
        cell_voltage_v: np.ndarray,
        pack_soc: float,
        pack_soc_var: float,
        held_current_a: float | None = None,
    ) -> CellEstimate:
        """One sample: predict from the last one with its current, update with these readings
        about the pack's SoC (already updated by the pack's estimator on this sample).
        ``held_current_a``: the current held since the last step instead of its current, as
        in ``Estimator.step`` (a filter rate below the input rate, ``tracking/decimation.py``)."""
        v = np.asarray(cell_voltage_v, dtype=float)
        ok = self.accept(v)
        self.rejected += ~ok
        f = self.filter
        dt_s = 0.0 if self._t_s is None else t_s - self._t_s
        if self._t_s is not None:
            f.predict(self._i_prev_a if held_current_a is None else held_current_a, dt_s)
        self._t_s = t_s
        self._i_prev_a = current_a
        if abs(current_a) > self._rest_a:
            self._rest_since_s = None
        elif self._rest_since_s is None:
            self._rest_since_s = t_s
        if self._rest_since_s is not None and t_s - self._rest_since_s >= self._rest_min_s:
            f.update(pack_soc, current_a, v, ok, dt_s)
        else:
            f.skip(v, ok)
        under = ok & (v <= self.v_min)
        if not under.any():
            self._under_since_s = None
            if abs(current_a) <= self._rest_a:
                self._at_cutoff = False
        else:
            if self._under_since_s is None:
                self._under_since_s = t_s
            if t_s - self._under_since_s >= self._cutoff_hold_s:
                self._at_cutoff = True
        self.last = self._estimate(v, ok, under, pack_soc, pack_soc_var)
        return self.last

    def _estimate(
        self, v: np.ndarray, ok: np.ndarray, under: np.ndarray, pack_soc: float, pack_soc_var: float
    ) -> CellEstimate:
        f = self.filter
        soc = pack_soc + f.x[:, 0]
        var = pack_soc_var + f.p[:, 0, 0]
        q = 1.0 + f.x[:, 1]
        remaining = soc * q
        room = (1.0 - soc) * q
        # The weakest: the least remaining charge, or at the pack's cut-off the lowest cell at
        # its limit (not on one glitching reading: the same hold).
        if self._at_cutoff and under.any():
            weakest = int(np.argmin(np.where(under, v, np.inf)))
        else:
            weakest = int(remaining.argmin())
        strongest = int(room.argmin())
        shown = np.where(ok, v, np.nan)
        good = v[ok]
        spread = float(good.max() - good.min()) if good.size >= 2 else math.nan
        return CellEstimate(
            soc=soc,
            soc_std=np.sqrt(np.maximum(var, 0.0)),
            voltage_v=shown,
            accepted=ok,
            usable_soc=0.0 if self._at_cutoff else min(max(float(remaining[weakest]), 0.0), 1.0),
            usable_soc_std=math.sqrt(max(float(var[weakest]), 0.0)),
            usable_charge_soc=min(max(1.0 - float(room[strongest]), 0.0), 1.0),
            weakest=weakest,
            strongest=strongest,
            imbalance_soc=float(soc.max() - soc.min()),
            spread_v=spread,
            under_voltage=under,
            over_voltage=ok & (v > self.v_max),
        )
