"""Open-circuit voltage as a function of SoC: OCV(SoC), its slope and its inverse.

The curve is a table of points (SoC in [0, 1], OCV in volts, strictly increasing) interpolated by
PCHIP (Fritsch-Carlson monotone cubic, ``scipy.interpolate.PchipInterpolator``). PCHIP keeps the
interpolant monotone between strictly increasing points, so OCV(SoC) has a unique inverse; a
cubic spline would overshoot around LFP's plateau knees and make the inverse multivalued.

The piecewise cubic is stored as plain coefficients and evaluated with ``bisect`` and Horner's
rule, because the filters call it for every sigma point at every sample: a scalar call costs
about a microsecond instead of the tens of microseconds of a scipy call.

Outside the table the curve is extended linearly with the end slopes (no extrapolation of the
cubic), so a filter that wanders past 0 or 1 sees a finite, monotone OCV and its covariance, not
a clamp, tells that it wandered.

The inverse on flat plateaus
----------------------------
On LFP the OCV moves a few tens of millivolts between 30 % and 70 % SoC (pack level): the
inverse exists but is ill-conditioned, dSoC/dOCV = 1/slope is huge. :meth:`OcvCurve.soc_at`
returns the exact inverse of the interpolant (unique, because the interpolant is strictly
increasing), clipped to [0, 1]; :meth:`OcvCurve.soc_at_with_std` also returns the standard
deviation the inverse carries for a given voltage uncertainty, ``sigma_v / slope``, capped at
the standard deviation of a uniform SoC on [0, 1] (0.289): on a plateau the answer is
"somewhere on the plateau", and callers (the RC+KF SoC readout, OCV recalibration at rest) must
weigh it by that standard deviation instead of trusting the point value.
"""

from __future__ import annotations

import math
from bisect import bisect_right
from collections.abc import Sequence

import numpy as np
from scipy.interpolate import PchipInterpolator

from .tables import fast_interp

#: Standard deviation of a SoC uniformly distributed on [0, 1]: the "no information" bound.
UNINFORMATIVE_SOC_STD = 1.0 / math.sqrt(12.0)


class OcvCurve:
    """Monotone OCV(SoC) curve of one battery (pack level, volts).

    Args:
        soc: SoC breakpoints, strictly increasing, within [0, 1].
        ocv_v: OCV at each breakpoint in volts, strictly increasing.
    """

    def __init__(
        self, soc: Sequence[float] | np.ndarray, ocv_v: Sequence[float] | np.ndarray
    ) -> None:
        soc_arr = np.asarray(soc, dtype=float)
        ocv_arr = np.asarray(ocv_v, dtype=float)
        if soc_arr.ndim != 1 or soc_arr.shape != ocv_arr.shape or soc_arr.size < 2:
            raise ValueError("OCV table needs two 1-D sequences of equal length >= 2")
        if not (np.all(np.isfinite(soc_arr)) and np.all(np.isfinite(ocv_arr))):
            raise ValueError("OCV table holds a non-finite value")
        if np.any(np.diff(soc_arr) <= 0.0):
            raise ValueError("OCV table SoC points must be strictly increasing")
        if np.any(np.diff(ocv_arr) <= 0.0):
            raise ValueError("OCV table voltages must be strictly increasing with SoC")
        if soc_arr[0] < 0.0 or soc_arr[-1] > 1.0:
            raise ValueError("OCV table SoC points must lie within [0, 1]")
        self.soc_points = soc_arr
        self.ocv_points_v = ocv_arr
        pchip = PchipInterpolator(soc_arr, ocv_arr, extrapolate=False)
        # ppoly coefficients c[k, i]: value = sum_k c[k, i] * (x - x_i)**(3 - k)
        coeffs = np.asarray(pchip.c, dtype=float)
        self._x = [float(v) for v in soc_arr]
        self._y = [float(v) for v in ocv_arr]
        self._c3 = [float(v) for v in coeffs[0]]
        self._c2 = [float(v) for v in coeffs[1]]
        self._c1 = [float(v) for v in coeffs[2]]
        deriv = pchip.derivative()
        self._slope_lo = float(deriv(soc_arr[0]))
        self._slope_hi = float(deriv(soc_arr[-1]))
        # Guard the linear extensions: PCHIP may put a zero slope at an end point.
        min_slope = float(np.min(np.diff(ocv_arr) / np.diff(soc_arr)))
        self._ext_lo = max(self._slope_lo, min_slope)
        self._ext_hi = max(self._slope_hi, min_slope)
        self._n = len(self._x)
        fine = np.linspace(soc_arr[0], soc_arr[-1], 4001)
        far = 10.0  # SoC units beyond the table: further than any filter excursion
        self._fine_soc = np.concatenate([[soc_arr[0] - far], fine, [soc_arr[-1] + far]])
        self._fine_v = np.array(
            [self._y[0] - self._ext_lo * far]
            + [self.ocv(float(v)) for v in fine]
            + [self._y[-1] + self._ext_hi * far]
        )

    # -- forward -----------------------------------------------------------------------------
    def ocv(self, soc: float) -> float:
        """OCV in volts at ``soc`` (scalar; linear extension outside the table)."""
        x = self._x
        if soc <= x[0]:
            return self._y[0] + self._ext_lo * (soc - x[0])
        if soc >= x[-1]:
            return self._y[-1] + self._ext_hi * (soc - x[-1])
        i = bisect_right(x, soc) - 1
        h = soc - x[i]
        return ((self._c3[i] * h + self._c2[i]) * h + self._c1[i]) * h + self._y[i]

    def ocv_each(self, soc: np.ndarray) -> np.ndarray:
        """:meth:`ocv` at every element of ``soc``, the same operations element by element
        (each value equal to :meth:`ocv`'s to the last bit; :meth:`ocv_array` is the faster
        chord approximation)."""
        soc = np.asarray(soc, dtype=float)
        x = np.array(self._x)
        i = np.clip(np.searchsorted(x, soc, side="right") - 1, 0, self._n - 2)
        h = soc - x[i]
        c3, c2, c1, y = (np.array(c)[i] for c in (self._c3, self._c2, self._c1, self._y))
        inside = ((c3 * h + c2) * h + c1) * h + y
        low = self._y[0] + self._ext_lo * (soc - self._x[0])
        high = self._y[-1] + self._ext_hi * (soc - self._x[-1])
        return np.where(soc <= self._x[0], low, np.where(soc >= self._x[-1], high, inside))

    def slope(self, soc: float) -> float:
        """dOCV/dSoC in volts per unit SoC at ``soc`` (scalar)."""
        x = self._x
        if soc <= x[0]:
            return self._ext_lo if soc < x[0] else self._slope_lo
        if soc >= x[-1]:
            return self._ext_hi if soc > x[-1] else self._slope_hi
        i = bisect_right(x, soc) - 1
        h = soc - x[i]
        return (3.0 * self._c3[i] * h + 2.0 * self._c2[i]) * h + self._c1[i]

    def ocv_array(self, soc: np.ndarray) -> np.ndarray:
        """Vectorized :meth:`ocv` for arrays of SoC (the UKF's sigma points).

        One ``np.interp`` over the cubic sampled every 1/4000 of the table span: the chord
        error is at most max|OCV''| h^2 / 8, below 10 microvolts even on LFP's knees (test).
        The grid's two far end points lie on the linear extensions, so outside the table the
        result is the same straight line as :meth:`ocv`.
        """
        return fast_interp(soc, self._fine_soc, self._fine_v, None, None)

    # -- inverse -----------------------------------------------------------------------------
    def soc_at(self, ocv_v: float) -> float:
        """SoC whose OCV is ``ocv_v``: the exact inverse of the interpolant, clipped to [0, 1].

        Unique because the interpolant is strictly increasing; see the module docstring for
        what it means on a plateau.
        """
        x, y = self._x, self._y
        if ocv_v <= y[0]:
            return min(max(x[0] + (ocv_v - y[0]) / self._ext_lo, 0.0), 1.0)
        if ocv_v >= y[-1]:
            return min(max(x[-1] + (ocv_v - y[-1]) / self._ext_hi, 0.0), 1.0)
        i = bisect_right(y, ocv_v) - 1
        lo, hi = 0.0, x[i + 1] - x[i]
        c3, c2, c1, c0 = self._c3[i], self._c2[i], self._c1[i], y[i]
        # Safeguarded Newton on the monotone cubic of segment i.
        h = hi * (ocv_v - c0) / (y[i + 1] - c0)
        for _ in range(60):
            f = ((c3 * h + c2) * h + c1) * h + c0 - ocv_v
            if f > 0.0:
                hi = h
            else:
                lo = h
            d = (3.0 * c3 * h + 2.0 * c2) * h + c1
            step_ok = d > 0.0
            h_new = h - f / d if step_ok else 0.5 * (lo + hi)
            if not (lo < h_new < hi):
                h_new = 0.5 * (lo + hi)
            if abs(h_new - h) < 1e-13:
                h = h_new
                break
            h = h_new
        return min(max(x[i] + h, 0.0), 1.0)

    def soc_at_with_std(self, ocv_v: float, ocv_std_v: float) -> tuple[float, float]:
        """Inverse OCV and the SoC standard deviation implied by an OCV uncertainty.

        ``std = ocv_std_v / slope(soc)``, capped at :data:`UNINFORMATIVE_SOC_STD`.
        """
        soc = self.soc_at(ocv_v)
        slope = self.slope(soc)
        if slope <= 0.0:
            return soc, UNINFORMATIVE_SOC_STD
        return soc, min(ocv_std_v / slope, UNINFORMATIVE_SOC_STD)

    def soc_at_with_interval_std(self, ocv_v: float, ocv_std_v: float) -> tuple[float, float]:
        """Inverse OCV and a SoC standard deviation read across the whole interval
        ``OCV^-1([ocv_v - ocv_std_v, ocv_v + ocv_std_v])``: the larger of its two sides, capped
        at :data:`UNINFORMATIVE_SOC_STD`.

        :meth:`soc_at_with_std` linearizes at the reading, which is right for a filter's
        small steps but not for one reading on a curve that bends within its own
        uncertainty: on LFP's plateau a reading lands where the table happens to rise a
        little (slope 0.6 V per unit of SoC at 49 %: std 3 points for 20 mV) while 20 mV
        either way spans 44-68 % (half-width 12 points). Such a reading is a point anywhere
        in that interval.
        """
        soc = self.soc_at(ocv_v)
        lo = self.soc_at(ocv_v - ocv_std_v)
        hi = self.soc_at(ocv_v + ocv_std_v)
        return soc, min(max(soc - lo, hi - soc), UNINFORMATIVE_SOC_STD)

    @property
    def ocv_min_v(self) -> float:
        """OCV at the lowest table point (volts)."""
        return self._y[0]

    @property
    def ocv_max_v(self) -> float:
        """OCV at the highest table point (volts)."""
        return self._y[-1]
