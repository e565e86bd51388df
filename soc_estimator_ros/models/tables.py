"""Parameter tables over SoC, with temperature as an optional second axis.

Equivalent-circuit parameters (resistances, capacitances) vary with SoC and temperature; the
pulse tests give them at a few SoC points (seed 000 Fig. 7) and, for real cells, a few
temperatures. A :class:`ParamTable` holds ``values[temperature, soc]`` and interpolates linearly
on both axes, holding the end values outside the grid (never extrapolating a resistance to a
negative value). Scalar evaluation uses ``bisect`` so a filter can call it per sigma point.
"""

from __future__ import annotations

from bisect import bisect_right
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np

try:  # the compiled core of np.interp, without its Python wrapper (same result, ~1 us less)
    from numpy._core.multiarray import interp as fast_interp
except ImportError:  # pragma: no cover - another numpy layout

    def fast_interp(x, xp, fp, left, right):  # type: ignore[no-redef]  # the import's fallback
        return np.interp(x, xp, fp, left, right)


def _bracket(axis: list[float], x: float) -> tuple[int, float]:
    """Index i and weight w so that x ~ (1 - w) * axis[i] + w * axis[i + 1], clamped."""
    if len(axis) == 1 or x <= axis[0]:
        return 0, 0.0
    if x >= axis[-1]:
        return len(axis) - 2, 1.0
    i = bisect_right(axis, x) - 1
    return i, (x - axis[i]) / (axis[i + 1] - axis[i])


def _bracket_each(axis: np.ndarray, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`_bracket` at every element of ``x`` (``axis`` of two points or more)."""
    i = np.clip(np.searchsorted(axis, x, side="right") - 1, 0, axis.size - 2)
    w = (x - axis[i]) / (axis[i + 1] - axis[i])
    low, high = x <= axis[0], x >= axis[-1]
    i = np.where(low, 0, np.where(high, axis.size - 2, i))
    w = np.where(low, 0.0, np.where(high, 1.0, w))
    return i, w


@dataclass(frozen=True)
class ParamTable:
    """Values of one parameter on a (temperature x SoC) grid.

    Args:
        soc: SoC breakpoints, strictly increasing.
        values: shape ``(len(temperature_c), len(soc))``; a 1-D sequence means one temperature.
        temperature_c: temperature breakpoints in degC, strictly increasing; ``(25.0,)`` when the
            table has no temperature dependence.
    """

    #: How many temperature-blended rows :meth:`at_array` keeps (a few hundred bytes each).
    MAX_BLENDED_ROWS: ClassVar[int] = 1024

    soc: tuple[float, ...]
    values: tuple[tuple[float, ...], ...]
    temperature_c: tuple[float, ...] = (25.0,)
    _soc_list: list[float] = field(init=False, repr=False, compare=False)
    _t_list: list[float] = field(init=False, repr=False, compare=False)
    # The same grid and rows as float arrays, for :meth:`at_array` (built once, not per call).
    _soc_arr: np.ndarray = field(init=False, repr=False, compare=False)
    _rows_arr: tuple[np.ndarray, ...] = field(init=False, repr=False, compare=False)
    _blended: dict[float, np.ndarray] = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        soc = [float(s) for s in self.soc]
        temps = [float(t) for t in self.temperature_c]
        rows = [tuple(float(v) for v in row) for row in self.values]
        if len(rows) != len(temps) or any(len(r) != len(soc) for r in rows):
            raise ValueError(
                f"table shape {len(rows)}x{[len(r) for r in rows]} does not match "
                f"{len(temps)} temperatures x {len(soc)} SoC points"
            )
        object.__setattr__(self, "soc", tuple(soc))
        object.__setattr__(self, "temperature_c", tuple(temps))
        object.__setattr__(self, "values", tuple(rows))
        object.__setattr__(self, "_soc_list", soc)
        object.__setattr__(self, "_t_list", temps)
        object.__setattr__(self, "_soc_arr", np.array(soc, dtype=float))
        object.__setattr__(self, "_rows_arr", tuple(np.array(r, dtype=float) for r in rows))
        object.__setattr__(self, "_blended", {})

    @classmethod
    def constant(cls, value: float) -> ParamTable:
        """A table that returns ``value`` everywhere."""
        return cls(soc=(0.0, 1.0), values=((value, value),))

    @classmethod
    def from_arrays(
        cls,
        soc: Sequence[float] | np.ndarray,
        values: Sequence[float] | Sequence[Sequence[float]] | np.ndarray,
        temperature_c: Sequence[float] | None = None,
    ) -> ParamTable:
        """Build from a 1-D (SoC only) or 2-D (temperature x SoC) array."""
        arr = np.asarray(values, dtype=float)
        if arr.ndim == 1:
            arr = arr[np.newaxis, :]
        temps = (25.0,) if temperature_c is None else tuple(float(t) for t in temperature_c)
        return cls(
            soc=tuple(float(s) for s in soc),
            values=tuple(tuple(row) for row in arr.tolist()),
            temperature_c=temps,
        )

    def at(self, soc: float, temperature_c: float | None = None) -> float:
        """Bilinear interpolation at (``temperature_c``, ``soc``), held at the grid's edges.

        ``temperature_c=None`` (or NaN) uses the first temperature row's neighbourhood of
        25 degC: the row nearest 25 degC.
        """
        j, ws = _bracket(self._soc_list, soc)
        rows = self.values
        if len(rows) == 1:
            row = rows[0]
            return row[j] if ws == 0.0 else row[j] + ws * (row[j + 1] - row[j])
        if temperature_c is None or temperature_c != temperature_c:  # None or NaN
            temperature_c = 25.0
        i, wt = _bracket(self._t_list, temperature_c)
        r0, r1 = rows[i], rows[i + 1]
        v0 = r0[j] + ws * (r0[j + 1] - r0[j]) if ws else r0[j]
        v1 = r1[j] + ws * (r1[j + 1] - r1[j]) if ws else r1[j]
        return v0 + wt * (v1 - v0)

    def at_array(self, soc: np.ndarray, temperature_c: float | None = None) -> np.ndarray:
        """Vectorized :meth:`at` over an array of SoC at one temperature.

        ``np.interp``'s compiled routine on arrays built once at construction: the same
        arithmetic as ``np.interp(soc, self.soc, row)``, without converting the tuples and
        without the wrapper's checks on every call (the UKF calls this per sample).
        """
        grid = self._soc_arr
        rows = self._rows_arr
        if len(rows) == 1:
            return fast_interp(soc, grid, rows[0], None, None)
        if temperature_c is None or temperature_c != temperature_c:
            temperature_c = 25.0
        # The row blended at each temperature seen, kept: a temperature sensor reports few
        # distinct values (0.1 degC steps) but changes on most samples (SLA field run 1: on 91 %
        # of them, 26 values), so one kept row would be blended again nearly every sample.
        row = self._blended.get(temperature_c)
        if row is None:
            if len(self._blended) >= self.MAX_BLENDED_ROWS:
                self._blended.clear()  # bounded: a temperature that never repeats costs a blend
            i, wt = _bracket(self._t_list, temperature_c)
            row = rows[i] + wt * (rows[i + 1] - rows[i])
            self._blended[temperature_c] = row
        return fast_interp(soc, grid, row, None, None)

    def at_each(self, soc: np.ndarray, temperature_c: np.ndarray) -> np.ndarray:
        """:meth:`at` at every (``temperature_c[k]``, ``soc[k]``) pair, a NaN temperature as
        ``None``: the same operations element by element (bracket, then ``v0 + w (v1 - v0)``
        on each axis), so each value equals :meth:`at`'s to the last bit (a simulation over a
        whole recording, ``identify.simulate_open_loop``, without a call per sample)."""
        soc = np.asarray(soc, dtype=float)
        grid = self._soc_arr
        rows = np.asarray(self.values, dtype=float)  # (temperature, SoC)
        if grid.size == 1:
            j = np.zeros(soc.shape, dtype=np.intp)
            if len(rows) == 1:
                return rows[0][j]
            return self._blend(rows[:, 0][:, None], j, temperature_c)
        j, ws = _bracket_each(grid, soc)
        if len(rows) == 1:
            row = rows[0]
            return np.where(ws == 0.0, row[j], row[j] + ws * (row[j + 1] - row[j]))
        lo = rows[:, j]  # (temperature, k): each row at its SoC bracket
        hi = rows[:, j + 1]
        at_soc = np.where(ws == 0.0, lo, lo + ws * (hi - lo))
        return self._blend(at_soc, np.arange(soc.size), temperature_c)

    def _blend(self, at_soc: np.ndarray, k: np.ndarray, temperature_c: np.ndarray) -> np.ndarray:
        """``at_soc[:, k]`` (every temperature row, already at its SoC) blended at each
        sample's temperature as :meth:`at` does (NaN: 25 degC)."""
        temps = np.asarray(temperature_c, dtype=float)
        temps = np.where(np.isnan(temps), 25.0, temps)
        i, wt = _bracket_each(np.array(self._t_list), temps)
        v0 = at_soc[i, k]
        v1 = at_soc[i + 1, k]
        return v0 + wt * (v1 - v0)

    def as_array(self) -> np.ndarray:
        """The values as a ``(n_temperature, n_soc)`` array."""
        return np.asarray(self.values, dtype=float)


class LaneTables:
    """Several :class:`ParamTable` read at once for K independent lanes (the batch engine's
    filters, ``batch/``): each lane has its own temperature, each element its own SoC.

    ``at(soc, temperature_c)`` with ``soc`` of shape ``(..., K)`` and ``temperature_c`` of
    shape ``(K,)`` returns ``(n_tables, ..., K)``: :meth:`ParamTable.at` at every element,
    linear in the SoC on each temperature row, held at the grid's edges, then blended at the
    lane's temperature (``v0 + w (v1 - v0)``; NaN: 25 degC), as :meth:`ParamTable.at` does.

    A row, linear between its breakpoints ``s_0 < ... < s_J``, is written as hinges::

        v(s) = v_0 + d_0 (s - s_0) + sum_{j >= 1} (d_j - d_{j-1}) max(s - s_j, 0)

    (``d_j`` the slope of segment j, ``s`` clipped to ``[s_0, s_J]``), so every table on a
    grid is one product of its coefficients with the hinges, which the tables sharing that SoC
    grid and temperature axis share: no per-element gather. The product is ``np.einsum``'s
    own loop, not BLAS: OpenBLAS threads a product this wide, and on a loaded machine its
    threads cost 100x the arithmetic (measured: 13.6 ms against 0.09 ms single-threaded for
    10 x 8 by 8 x 9000). A grid of more than :attr:`MAX_HINGES` segments (the OCV offset's 40)
    is read row by row with ``np.interp`` instead. Either way the value is the interpolant of
    :meth:`ParamTable.at_array` in another rounding order (a few ulp apart).
    """

    #: Grids with more segments than this are read by ``np.interp`` (module docstring).
    MAX_HINGES: ClassVar[int] = 16

    def __init__(self, tables: Sequence[ParamTable]) -> None:
        self.n_tables = len(tables)
        groups: dict[tuple[tuple[float, ...], tuple[float, ...]], list[int]] = {}
        for k, t in enumerate(tables):
            groups.setdefault((t.soc, t.temperature_c), []).append(k)
        self._groups = []
        for (soc, temps), members in groups.items():
            grid = np.array(soc, dtype=float)
            vals = np.array([tables[k].as_array() for k in members])  # (m, n_t, n_soc)
            if grid.size == 1:  # one SoC point: one constant segment
                grid = np.array([soc[0], soc[0] + 1.0])
                vals = np.concatenate([vals, vals], axis=2)
            slope = np.diff(vals, axis=2) / np.diff(grid)  # (m, n_t, n_seg)
            hinge = np.diff(slope, axis=2)  # (m, n_t, n_seg - 1): the kinks at s_1..s_{J-1}
            coef = np.concatenate([vals[:, :, :1], slope[:, :, :1], hinge], axis=2)
            n_t = vals.shape[1]
            # (n_t * m, n_seg + 1): temperature row major, then table
            coef = np.ascontiguousarray(coef.transpose(1, 0, 2).reshape(n_t * len(members), -1))
            if grid.size - 1 > self.MAX_HINGES:  # the rows themselves, for np.interp
                coef = np.ascontiguousarray(vals.transpose(1, 0, 2).reshape(n_t * len(members), -1))
            self._groups.append((np.array(members), grid, np.array(temps, dtype=float), coef))

    def _rows_at(self, soc: np.ndarray, grid: np.ndarray, coef: np.ndarray) -> np.ndarray:
        """Every row of a group at every element of ``soc``: ``(n_rows, soc.size)``."""
        s = np.clip(soc, grid[0], grid[-1]).reshape(1, -1)
        if grid.size - 1 > self.MAX_HINGES:
            return np.array([fast_interp(s[0], grid, row, None, None) for row in coef])
        basis = np.empty((grid.size, s.size))  # [1, s - s_0, max(s - s_j, 0) ...]
        basis[0] = 1.0
        np.subtract(s, grid[:-1, np.newaxis], out=basis[1:])
        np.maximum(basis[2:], 0.0, out=basis[2:])
        return np.einsum("ij,jk->ik", coef, basis)

    def at(self, soc: np.ndarray, temperature_c: np.ndarray) -> np.ndarray:
        soc = np.asarray(soc, dtype=float)
        temps = np.asarray(temperature_c, dtype=float)
        out = np.empty((self.n_tables, *soc.shape))
        t = np.where(np.isnan(temps), 25.0, temps)
        for members, grid, taxis, coef in self._groups:
            v = self._rows_at(soc, grid, coef).reshape(taxis.size, members.size, *soc.shape)
            if taxis.size == 1:
                out[members] = v[0]
                continue
            it, wt = _bracket_each(taxis, t)
            if taxis.size == 2:  # the bracket is rows 0 and 1 on every lane
                v0, v1 = v[0], v[1]
            else:
                lane = np.arange(t.size)
                v0 = v[it, ..., lane]
                v1 = v[it + 1, ..., lane]
                v0, v1 = np.moveaxis(v0, 0, -1), np.moveaxis(v1, 0, -1)
            out[members] = v0 + wt * (v1 - v0)
        return out
