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
    linear in the SoC on the two temperature rows around the lane's temperature, held at the
    grid's edges, then ``v0 + w (v1 - v0)`` (NaN: 25 degC), as :meth:`ParamTable.at` does.
    Tables sharing a SoC grid and a temperature axis share the bracket; each reads its
    segment's value and slope, ``v = r_j + d_j (s - s_j)`` (one ``np.take`` each from a row
    of a few values). The interpolant is :meth:`ParamTable.at_array`'s (which blends the rows
    first, then interpolates) in another rounding order: a few ulp apart, not bit for bit.
    Measured faster than a shared-hinge product (``np.einsum``, or BLAS, whose threads cost
    100x the arithmetic on a loaded machine) for the files' 5 to 40 segments.
    """

    #: Grids of up to this many segments find an element's segment by comparing it with each
    #: breakpoint (faster than ``np.searchsorted``'s binary search on unsorted elements).
    MAX_COMPARED: ClassVar[int] = 12

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
            m = len(members)
            # per table, (temperature row, segment) flattened row-major: t * n_seg + j
            value = np.ascontiguousarray(vals[:, :, :-1].reshape(m, -1))
            slope = np.ascontiguousarray(slope.reshape(m, -1))
            self._groups.append(
                (members, grid, np.array(temps, dtype=float), value, slope, grid.size - 1)
            )

    def at(self, soc: np.ndarray, temperature_c: np.ndarray) -> np.ndarray:
        soc = np.asarray(soc, dtype=float)
        temps = np.asarray(temperature_c, dtype=float)
        out = np.empty((self.n_tables, *soc.shape))
        t = np.where(np.isnan(temps), 25.0, temps)
        brackets: dict[bytes, tuple[np.ndarray, np.ndarray]] = {}  # per temperature axis
        for members, grid, taxis, value, slope, n_seg in self._groups:
            s = np.clip(soc, grid[0], grid[-1])
            if n_seg <= self.MAX_COMPARED:  # the segment: the inner breakpoints at or below s
                j = np.zeros(s.shape, dtype=np.intp)
                for g in grid[1:-1].tolist():
                    j += s >= g
            else:
                j = np.searchsorted(grid, s, side="right") - 1
                np.minimum(j, n_seg - 1, out=j)
            h = s - grid[j]
            if taxis.size == 1:
                for row, k in enumerate(members):
                    out[k] = value[row].take(j) + slope[row].take(j) * h
                continue
            key = taxis.tobytes()
            if key not in brackets:
                brackets[key] = _bracket_each(taxis, t)
            it, wt = brackets[key]
            lo = j + it * n_seg
            hi = lo + n_seg
            for row, k in enumerate(members):
                v, d = value[row], slope[row]
                v0 = v.take(lo) + d.take(lo) * h
                v1 = v.take(hi) + d.take(hi) * h
                out[k] = v0 + wt * (v1 - v0)
        return out
