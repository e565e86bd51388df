"""Plett's "bar-delta" filter for the cells of a series pack, vectorized over the cells.

After Plett, *Battery Management Systems* vol. II, ch. 4 ("bar-delta" filtering): the pack's
own estimator runs on the pack as one lumped battery; its SoC ``s_bar`` is taken as the average
cell's. Each cell ``i`` then needs only its deviation from that average, which moves slowly and
is estimated by a small Kalman filter of its own. The N filters are independent, so they run as
one set of plain numpy arrays (no Python loop over the cells).

State of cell ``i``: ``x_i = [d_i, e_i, r_i]``:

* ``d_i``: its SoC minus the pack's (fraction);
* ``e_i``: its capacity's deviation from the pack's, as a fraction (``Q_i = Q (1 + e_i)``),
  estimated only by a reading that tells the cell's SoC finer than its OCV curve's own offset
  (``sqrt(sigma_v^2 + (k I)^2) <= sigma_ocv |dOCV_c/dSoC|``: Li-ion's slope, LFP's knees);
  elsewhere a *considered* parameter (Schmidt-Kalman, Simon *Optimal State Estimation* 7.5):
  its gain is held at zero, so its prior std stays and keeps ``d``'s covariance honest; a
  capacity learned from a few millivolts of a flat curve would be a guess (a free ``e``
  wandered to 9 of its prior std on the simulated LFP pack; gated, on the 4S Li-ion missions
  100-123 the usable SoC's mean MAE fell 1.25 -> 1.07 % from a sure start, docs/cells.md);
* ``r_i``: its resistance's deviation from the pack's share (ohm).

Prediction over ``dt`` with the held current ``I`` (discharge positive; charge counted with the
efficiency ``eta``), ``u = eta I dt / (3600 Q)`` the SoC the average cell moves::

    SoC_i' = SoC_i - u / (1 + e_i) ~= SoC_i - u (1 - e_i)   =>   d_i' = d_i + u e_i     (1)

so ``F = [[1, u, 0], [0, 1, 0], [0, 0, 1]]``, ``P' = F P F^T + Q_w`` with random walks on
``d`` (``soc_walk_per_hour``) and none on ``e`` or ``r``. Through (1) the capacity's prior
std (never shrunk, see ``e_i``) makes ``d``'s variance grow with the charge moved
(``sigma_d ~ sigma_e |sum u|``): on LFP's flat plateau, where no voltage tells the cells apart,
the deviation's std grows honestly instead of collapsing.

Measurement: the cell's voltage minus the mean of the cells' (the pack's common polarization,
temperature and sensor gain cancel), linearized about the pack's SoC on the cell OCV (the
pack's table over ``N``)::

    y_i = v_i - mean(v) ~= OCV_c(s_bar + d_i) - OCV_c(s_bar) - I r_i                  (2)
    H_i = [dOCV_c/dSoC (s_bar + d_i), 0, -I]

with noise ``sigma_v^2 + (k |I|)^2 + (slope sigma_ocv)^2`` (reading noise; ``k``: the cells'
unequal polarization beyond ``r``; ``sigma_ocv``: how far a cell's own OCV curve may sit from
the table, in SoC, so a steep end of the curve does not pin ``d`` to a millivolt) times
``(1 - 1/n)`` (the mean holds ``1/n`` of the cell's own
reading) and by ``max(1, tau / dt)``: the errors are not white (a cell relaxing from its own
polarization, its own OCV curve), they last ``tau`` (``error_corr_s``); read as white, 1200
readings of a 20-min rest on the plateau pulled the weakest cell 3.7 points off while its
deviation's std said 0.3. A cell whose reading is missing this sample is only predicted.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from ..models.ocv import OcvCurve
from ..units import SECONDS_PER_HOUR

#: Half-width of the central difference for the cell OCV slope (SoC).
SLOPE_STEP_SOC = 1e-3
#: An innovation beyond this many of its std is not used (a reading the model cannot explain,
#: e.g. one cell's contactor bouncing); the prediction stands.
INNOVATION_GATE_STD = 8.0
#: Which covariance entries a Schmidt update changes (all but the considered capacity's).
_SCHMIDT_W = np.ones((3, 3))
_SCHMIDT_W[1, 1] = 0.0


@dataclass(frozen=True)
class CellFilterConfig:
    """The cell filter's noise and priors (battery file ``cells:``, ``params.CellSettings``).

    Attributes:
        cells: number of cells in series.
        capacity_ah: the pack's capacity (Ah; every cell's nominal one in a series pack).
        eta_charge: charge efficiency.
        soc_std: prior std of ``d`` (fraction).
        capacity_std: prior std of ``e`` (fraction).
        resistance_std_ohm: prior std of ``r`` (ohm).
        voltage_std_v: cell reading noise at rest (V).
        voltage_std_per_a: its growth with the current (V/A).
        soc_walk_per_hour: random walk of ``d`` (fraction per sqrt(hour)).
        ocv_soc_std: a cell's OCV curve's offset from the table, in SoC (fraction).
        error_corr_s: how long a reading's error lasts (s): the noise of one reading is
            scaled by ``error_corr_s / dt`` so that a correlation time of readings carries
            the information of one.
    """

    cells: int
    capacity_ah: float
    eta_charge: float = 1.0
    soc_std: float = 0.05
    capacity_std: float = 0.03
    resistance_std_ohm: float = 0.002
    voltage_std_v: float = 0.003
    voltage_std_per_a: float = 0.0005
    soc_walk_per_hour: float = 0.002
    ocv_soc_std: float = 0.01
    error_corr_s: float = 300.0


class CellDeltaFilter:
    """The N bar-delta filters (module docstring), state ``x`` (N, 3), covariance ``p`` (N, 3, 3).

    Args:
        config: noise and priors.
        cell_ocv: the cell's OCV curve (the pack's table over the cell count).
    """

    STATE_NAMES = ("d_soc", "d_capacity", "d_r_ohm")

    def __init__(self, config: CellFilterConfig, cell_ocv: OcvCurve) -> None:
        self.config = config
        self.ocv = cell_ocv
        n = config.cells
        self.x = np.zeros((n, 3))
        p0 = np.diag([config.soc_std**2, config.capacity_std**2, config.resistance_std_ohm**2])
        self.p = np.repeat(p0[None, :, :], n, axis=0)
        self.innovation_v = np.full(n, np.nan)
        self.gated = np.zeros(n, dtype=np.int64)
        self._pts = np.empty(3 * n + 1)
        self._r_const = config.voltage_std_v**2

    def start_from(self, x: ArrayLike, p: ArrayLike, elapsed_s: float) -> None:
        """Resume from a saved state ``x`` (N, 3) and covariance ``p`` (N, 3, 3), ``elapsed_s``
        after it: ``d``'s random walk over that time is added to its variance (no current is
        known to have flowed; the pack's own SoC carries what did)."""
        self.x = np.array(x, dtype=float)
        self.p = np.array(p, dtype=float)
        walk = self.config.soc_walk_per_hour**2 * max(elapsed_s, 0.0) / SECONDS_PER_HOUR
        self.p[:, 0, 0] += walk

    def predict(self, current_a: float, dt_s: float) -> None:
        """Eq. (1) over ``dt_s`` with the held ``current_a`` (discharge positive)."""
        if dt_s <= 0.0:
            return
        c = self.config
        eta = c.eta_charge if current_a < 0.0 else 1.0
        u = eta * current_a * dt_s / (SECONDS_PER_HOUR * c.capacity_ah)
        x, p = self.x, self.p
        x[:, 0] += u * x[:, 1]
        # P' = F P F^T, F = I + u E01, written out: row/column 0 gain u times row/column 1.
        p[:, 0, :] += u * p[:, 1, :]
        p[:, :, 0] += u * p[:, :, 1]
        p[:, 0, 0] += c.soc_walk_per_hour**2 * dt_s / SECONDS_PER_HOUR

    def update(
        self,
        soc_bar: float,
        current_a: float,
        cell_voltage_v: np.ndarray,
        valid: np.ndarray,
        dt_s: float = 0.0,
    ) -> None:
        """Eq. (2) for every ``valid`` cell (at least two are needed for a mean); ``dt_s`` the
        time since the previous reading (the noise is correlated over ``error_corr_s``)."""
        self.innovation_v[:] = np.nan
        n_valid = int(valid.sum())
        if n_valid < 2:
            return
        c = self.config
        n = c.cells
        v = np.where(valid, cell_voltage_v, 0.0)
        y = v - v.sum() / n_valid
        x = self.x
        pts = self._pts  # [s_bar, s_i, s_i + h, s_i - h]: one interpolation for all
        pts[0] = soc_bar
        np.add(x[:, 0], soc_bar, out=pts[1 : n + 1])
        np.add(pts[1 : n + 1], SLOPE_STEP_SOC, out=pts[n + 1 : 2 * n + 1])
        np.subtract(pts[1 : n + 1], SLOPE_STEP_SOC, out=pts[2 * n + 1 :])
        o = self.ocv.ocv_array(pts)
        h = o[1 : n + 1] - o[0] - current_a * x[:, 2]
        slope = (o[n + 1 : 2 * n + 1] - o[2 * n + 1 :]) * (0.5 / SLOPE_STEP_SOC)
        scale = (1.0 - 1.0 / n_valid) * max(1.0, c.error_corr_s / dt_s if dt_s > 0.0 else 1.0)
        r = self._r_const + (c.ocv_soc_std * slope) ** 2 + (c.voltage_std_per_a * current_a) ** 2
        r *= scale
        p = self.p
        # H = [slope, 0, -I]: P H^T and H P H^T without forming H.
        ph = p[:, :, 0] * slope[:, None] - p[:, :, 2] * current_a
        s = ph[:, 0] * slope - ph[:, 2] * current_a + r
        innov = y - h
        ok = valid & (innov * innov <= INNOVATION_GATE_STD**2 * s)
        self.gated += valid & ~ok
        g = np.where(ok, 1.0 / s, 0.0)
        k = ph * g[:, None]
        # The capacity deviation is estimated where the reading tells the cell's SoC finer
        # than its OCV's own offset (the millivolts over the slope within ocv_soc_std: Li-ion,
        # LFP's knees), considered (Schmidt) elsewhere: on a flat stretch it would be a guess.
        resolved = (
            self._r_const + (c.voltage_std_per_a * current_a) ** 2 <= (c.ocv_soc_std * slope) ** 2
        )
        k[:, 1] = np.where(resolved, k[:, 1], 0.0)
        x += k * innov[:, None]
        # Joseph form for the Schmidt gain K = M P H^T / S (M masks the capacity out), written
        # out: (I - KH) P (I - KH)^T + K R K^T = P - (P H^T H P / S) (*) W, with W all ones
        # but 0 at (capacity, capacity): the considered variance stays, P stays symmetric; W
        # all ones where the capacity is estimated (the optimal gain's P - P H^T H P / S).
        w = np.where(resolved[:, None, None], 1.0, _SCHMIDT_W)
        p -= (ph[:, :, None] * ph[:, None, :]) * (g[:, None, None] * w)
        self.innovation_v = np.where(valid, innov, np.nan)

    def skip(self, cell_voltage_v: np.ndarray, valid: np.ndarray) -> None:
        """No update this sample (the caller's gate): only the innovation is reported."""
        del cell_voltage_v, valid
        self.innovation_v[:] = np.nan

    @property
    def soc_offset(self) -> np.ndarray:
        """``d`` of every cell (fraction)."""
        return self.x[:, 0]

    @property
    def soc_offset_var(self) -> np.ndarray:
        """Its variance."""
        return self.p[:, 0, 0]

    @property
    def capacity_factor(self) -> np.ndarray:
        """``1 + e`` of every cell."""
        return 1.0 + self.x[:, 1]
