"""The one interface every estimator shares, and the time and covariance handling they share.

``step(t_s, current_a, voltage_v, temperature_c=None) -> Estimate`` with the core's conventions
(current positive on discharge, SoC as a fraction). Time handling, common to all estimators:

* the first sample initializes the time base (and, for filters, runs a measurement update);
* ``dt <= 0`` (a duplicate or out-of-order stamp) is **rejected**: the state is not touched and
  the returned estimate has status ``REJECTED_DT``; the caller counts it;
* ``0 < dt <= max_step_s`` is a normal step; the current of the previous sample is held over the
  interval (zero-order hold: a sample reports the current from its stamp on);
* ``dt > max_step_s`` is a **gap**: samples were lost, so the current over the gap is unknown.
  It is bridged with the mean of the currents at both ends, and the SoC variance grows by
  ``(gap_current_std_a * dt / 3600 / Q)^2`` so the covariance says how little is known;
  the estimate has status ``GAP``.

Covariance hygiene (after Plett's SPKF notes): after every predict and update the covariance is
symmetrized and, if a Cholesky factorization fails, its eigenvalues are floored; the SoC state
is clipped to [0, 1] and the clipped amount is added to its variance, so a divergence shows in
the covariance and the ``clip_count`` instead of being hidden.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from enum import Enum
from typing import Any, ClassVar

import numpy as np
from scipy.linalg.lapack import dpotrf

from ..models.thevenin import TheveninModel
from ..params import BatteryParams
from ..units import MAX_SOC_VAR, SECONDS_PER_HOUR
from .guard import ChargeCount, count_errors


class StepStatus(str, Enum):
    """What an estimator did with one sample."""

    INITIALIZED = "initialized"
    OK = "ok"
    GAP = "gap"
    REJECTED_DT = "rejected_dt"


@dataclass(frozen=True)
class Estimate:
    """An estimator's output for one sample.

    Attributes:
        t_s: the sample's time in seconds.
        soc: SoC estimate as a fraction in [0, 1].
        soc_var: its variance (fraction^2).
        x: the full state vector; names in ``state_names``.
        p: the full state covariance.
        voltage_pred_v: the terminal voltage the model predicted for this sample before the
            measurement update (NaN for estimators without a voltage model).
        innovation_v: measured minus predicted voltage (NaN when no update ran).
        nis: normalized innovation squared, innovation^2 / S (NaN when no update ran).
        status: what happened to the sample (see :class:`StepStatus`).
        updated: whether a voltage measurement update ran on this sample.
    """

    t_s: float
    soc: float
    soc_var: float
    x: np.ndarray
    p: np.ndarray
    state_names: tuple[str, ...]
    voltage_pred_v: float
    innovation_v: float
    nis: float
    status: StepStatus
    updated: bool

    @property
    def soc_std(self) -> float:
        """Standard deviation of the SoC estimate."""
        return math.sqrt(max(self.soc_var, 0.0))


def cholesky_lower(a: np.ndarray) -> np.ndarray:
    """``np.linalg.cholesky(a)``: the lower factor, by LAPACK's ``dpotrf`` called directly.

    The same LAPACK routine numpy calls, without numpy's per-call wrapping (type checks and an
    ``errstate`` context: about 8 of its 10 microseconds on a 3x3). When the factorization
    fails, numpy's own call decides (and raises ``LinAlgError`` as before).
    """
    c, info = dpotrf(a, lower=1, clean=1)
    if info != 0:
        return np.linalg.cholesky(a)
    return c


def condition_covariance(p: np.ndarray, floor: float = 1e-15) -> np.ndarray:
    """Symmetrize ``p`` and make it positive definite (eigenvalue floor) if it is not."""
    p = 0.5 * (p + p.T)
    if dpotrf(p, lower=1, clean=0)[1] == 0:  # positive definite: LAPACK's Cholesky succeeds
        return p
    try:
        np.linalg.cholesky(p)
        return p
    except np.linalg.LinAlgError:
        w, v = np.linalg.eigh(p)
        w = np.maximum(w, floor)
        p = (v * w) @ v.T
        return 0.5 * (p + p.T)


@dataclass(frozen=True)
class TimePolicy:
    """How an estimator treats time steps (seconds)."""

    max_step_s: float = 5.0
    gap_current_std_a: float = 1.0

    def held_current_a(self, last_a: float, current_a: float, dt_s: float) -> float:
        """The current counted over a step of ``dt_s`` from a sample of ``last_a`` to one of
        ``current_a`` (A): the last sample's, held; across a gap (``dt_s > max_step_s``) the
        mean of the two ends (module docstring). The tracker moves the OCV's hysteresis by
        the same charge."""
        return 0.5 * (last_a + current_a) if dt_s > self.max_step_s else last_a


class Estimator(ABC):
    """Base class: time handling, SoC clipping, handover; subclasses do the filtering.

    Subclasses set ``name``, ``state_names``, keep their state in ``self.x`` and covariance in
    ``self.p`` (SoC at index ``soc_index``), and implement :meth:`_predict` and :meth:`_update`.
    An estimator whose state has no SoC entry (the RC model's) overrides :attr:`soc`,
    :attr:`soc_var`, :meth:`_clip_soc` and :meth:`_inflate_soc_variance`.
    """

    name: ClassVar[str] = ""
    state_names: tuple[str, ...] = ("soc",)
    soc_index: int = 0
    #: Publish a variance no smaller than the squared distance from a charge count from the
    #: same start plus the count's own variance (:meth:`_published`): set by the filters that
    #: read the voltage and carry no guard of their own (issue 24 item 5).
    count_floor: ClassVar[bool] = False
    #: Tuning entries and their defaults; a battery file's ``filters.<name>`` overrides them.
    default_tuning: ClassVar[Mapping[str, Any]] = {}
    #: Entries that must be > 0 (:meth:`merged_tuning`): a time constant or a gate the filter
    #: divides by, a state's std that sets its variance (0 left the hybrid's covariance
    #: singular). Every other number must be >= 0 but those in :attr:`signed_tuning`.
    positive_tuning: ClassVar[frozenset[str]] = frozenset()
    #: Entries of either sign (the UKF's ``kappa``).
    signed_tuning: ClassVar[frozenset[str]] = frozenset()
    #: Entries with a smallest value above 0, and why: ``{name: (least, reason)}``.
    tuning_least: ClassVar[Mapping[str, tuple[float, str]]] = {}
    # Set by _init_state (FilterpyState makes them properties over a filterpy filter).
    x: np.ndarray
    p: np.ndarray

    def __init__(
        self,
        battery: BatteryParams,
        initial_soc: float,
        initial_soc_std: float = 0.05,
        tuning: Mapping[str, Any] | None = None,
        time_policy: TimePolicy | None = None,
    ) -> None:
        if not (0.0 <= initial_soc <= 1.0):
            raise ValueError(f"initial_soc must be within [0, 1], got {initial_soc}")
        if not initial_soc_std > 0.0:
            raise ValueError(f"initial_soc_std must be > 0, got {initial_soc_std}")
        self.battery = battery
        self.tuning = self.merged_tuning(tuning)
        policy = time_policy or TimePolicy(
            gap_current_std_a=0.1 * battery.capacity_ah  # 0.1 C of unknown current in a gap
        )
        self.time_policy = policy
        self.capacity_ah = battery.capacity_ah
        self.t_last_s: float | None = None
        self.current_last_a = 0.0
        self.clip_count = 0
        self.last: Estimate | None = None
        #: The variance (V^2) of an offset the caller took out of the voltages it passes: the
        #: OCV hysteresis' ``gap_v^2 var(b)`` (``tracking/tracker.py``), 0 for a known one. The
        #: voltage-reading filters (t2rc_ukf, the hybrid) add it to their measurement noise;
        #: the others read the voltage with their own noise only.
        self.voltage_offset_var_v2 = 0.0
        #: The charge count behind the published variance's floor (``count_floor``), else None.
        self.floor_count: ChargeCount | None = self._new_floor_count() if self.count_floor else None
        self._start(initial_soc, initial_soc_std**2)

    # -- configuration -----------------------------------------------------------------------
    @classmethod
    def merged_tuning(cls, tuning: Mapping[str, Any] | None) -> dict[str, Any]:
        """The tuning an estimator of this class runs with: ``default_tuning`` under the
        entries of ``tuning`` (a battery file's ``filters.<name>`` block), tuples as floats;
        an unknown entry, a list where a number belongs or the reverse, a tuple of the wrong
        length, or a number out of its entry's domain (:attr:`positive_tuning`,
        :attr:`signed_tuning`, else >= 0; :attr:`tuning_least`; NaN never) is a
        ``ValueError``."""
        merged = dict(cls.default_tuning)
        for key, value in (tuning or {}).items():
            if key not in merged:
                raise ValueError(
                    f"{cls.name}: unknown tuning entry {key!r}; known: {sorted(merged)}"
                )
            default = merged[key]
            listed = isinstance(value, (Sequence, np.ndarray)) and not isinstance(value, str)
            if isinstance(default, tuple):
                if not listed or len(value) != len(default):
                    raise ValueError(
                        f"{cls.name}: tuning {key!r} needs {len(default)} values, got {value!r}"
                    )
                value = tuple(float(v) for v in value)
            elif listed:
                raise ValueError(f"{cls.name}: tuning {key!r} needs one number, got {value!r}")
            merged[key] = value
            cls._check_domain(key, value)
        return merged

    @classmethod
    def _check_domain(cls, key: str, value: Any) -> None:
        """``value`` (a number, or each of a tuple's) is in the domain of entry ``key``."""
        for v in value if isinstance(value, tuple) else (value,):
            if isinstance(v, bool) or not isinstance(v, (int, float, np.floating, np.integer)):
                raise ValueError(f"{cls.name}: tuning {key!r} needs a number, got {v!r}")
            if v != v:
                raise ValueError(f"{cls.name}: tuning {key!r} is NaN")
            if key in cls.positive_tuning and not v > 0.0:
                raise ValueError(f"{cls.name}: tuning {key!r} must be > 0, got {v!r}")
            if key not in cls.signed_tuning and not v >= 0.0:
                raise ValueError(f"{cls.name}: tuning {key!r} must be >= 0, got {v!r}")
            if key in cls.tuning_least and v < cls.tuning_least[key][0]:
                least, why = cls.tuning_least[key]
                raise ValueError(
                    f"{cls.name}: tuning {key!r} needs >= {least:g} ({why}), got {v!r}"
                )

    def _new_floor_count(self) -> ChargeCount:
        """The count of :attr:`count_floor`, with the file's count error budget (the guard's:
        ``guard.count_errors``)."""
        b = self.battery
        errors = count_errors(b.filters.get("hybrid", {}))
        return ChargeCount(errors, b.capacity_ah, b.coulomb_efficiency_charge)

    def _start(self, soc: float, soc_var: float) -> None:
        """``_init_state``, the floor's count anchored at the same start."""
        self._init_state(soc, soc_var)
        if self.floor_count is not None:
            self.floor_count.anchor(soc, soc_var)

    # -- subclass hooks ----------------------------------------------------------------------
    @abstractmethod
    def _init_state(self, soc: float, soc_var: float) -> None:
        """Set ``self.x`` and ``self.p`` for a pack at rest at ``soc``."""

    @abstractmethod
    def _predict(self, dt_s: float, current_a: float, next_current_a: float, temp_c) -> None:
        """Propagate over ``dt_s`` with ``current_a`` held, the current then becoming ``next``."""

    @abstractmethod
    def _update(self, current_a: float, voltage_v: float, temp_c) -> tuple[float, float, float]:
        """Measurement update; return (predicted voltage, innovation, NIS), NaNs if none."""

    def _inflate_soc_variance(self, var: float) -> None:
        i = self.soc_index
        self.p[i, i] += var

    # -- public API --------------------------------------------------------------------------
    @property
    def soc(self) -> float:
        """Current SoC estimate."""
        return float(self.x[self.soc_index])

    @property
    def soc_var(self) -> float:
        """Current SoC variance."""
        i = self.soc_index
        return float(self.p[i, i])

    def step(
        self,
        t_s: float,
        current_a: float,
        voltage_v: float,
        temperature_c: float | None = None,
        held_current_a: float | None = None,
    ) -> Estimate:
        """Process one sample; see the module docstring for the time rules.

        ``held_current_a``: the current to hold over the interval since the last step instead
        of the last step's (A); a caller that steps the filter on every n-th sample
        (``tracking/decimation.py``) passes the counted charge over the interval's length, so
        the SoC moves by exactly the charge every sample counted.
        """
        if self.t_last_s is None:
            status = StepStatus.INITIALIZED
        else:
            dt = t_s - self.t_last_s
            if not dt > 0.0:
                return self._estimate(t_s, StepStatus.REJECTED_DT, math.nan, math.nan, math.nan)
            held = (
                self.time_policy.held_current_a(self.current_last_a, current_a, dt)
                if held_current_a is None
                else held_current_a
            )
            self._predict(dt, held, current_a, temperature_c)
            if self.floor_count is not None:
                self.floor_count.step(held, dt)
            if dt > self.time_policy.max_step_s:
                status = StepStatus.GAP
                q = self.time_policy.gap_current_std_a * dt / (SECONDS_PER_HOUR * self.capacity_ah)
                self._inflate_soc_variance(q * q)
                if self.floor_count is not None:
                    self.floor_count.inflate(q * q)
            else:
                status = StepStatus.OK
            self.p = condition_covariance(self.p)
        v_pred, innov, nis = self._update(current_a, voltage_v, temperature_c)
        self._clip_soc()
        self.p = condition_covariance(self.p)
        self.t_last_s = t_s
        self.current_last_a = current_a
        self.last = self._estimate(t_s, status, v_pred, innov, nis)
        return self.last

    def _clip_soc(self) -> None:
        i = self.soc_index
        s = float(self.x[i])
        clipped = min(max(s, 0.0), 1.0)
        if clipped != s:
            self.clip_count += 1
            self.x[i] = clipped
            # Grow the variance by the clipped amount, up to MAX_SOC_VAR ("no information").
            self.p[i, i] += min((s - clipped) ** 2, max(MAX_SOC_VAR - self.p[i, i], 0.0))

    def _published(self) -> tuple[float, float]:
        """The SoC and variance an estimate carries: :attr:`soc` and :attr:`soc_var`, the
        variance, with :attr:`count_floor`, no smaller than ``(soc - c)^2 + P_c`` for the
        count ``c`` from the same start and its variance ``P_c`` (``guard.ChargeCount``).

        The filter's error is its distance from the count plus the count's error, so where a
        wrong model drags the filter (seed 001's EKF reads the voltage at a tight ``R``), the
        disagreement shows in the variance instead of hiding behind the filter's own ``P``,
        which assumes the model right. The SoC is the filter's: only its sigma changes. The
        count is the guard's, without its readings (the hybrid's mixture also re-anchors it
        at rests and follows a trusted filter, ``guard.py``)."""
        soc, var = self.soc, self.soc_var
        c = self.floor_count
        if c is not None:
            var = max(var, (soc - c.soc) ** 2 + c.var)
        return soc, var

    @property
    def published_soc_var(self) -> float:
        """The variance an estimate carries now (:meth:`_published`): what a saved state and a
        handover keep."""
        return self._published()[1]

    def _estimate(
        self, t_s: float, status: StepStatus, v_pred: float, innov: float, nis: float
    ) -> Estimate:
        soc, soc_var = self._published()
        return Estimate(
            t_s=t_s,
            soc=soc,
            soc_var=soc_var,
            x=np.array(self.x, dtype=float),
            p=np.array(self.p, dtype=float),
            state_names=self.state_names,
            voltage_pred_v=v_pred,
            innovation_v=innov,
            nis=nis,
            status=status,
            updated=not math.isnan(innov),
        )

    # -- what the health estimator (``health/``) learns and reads ------------------------------
    def set_health(self, capacity_ah: float, r0_factor: float) -> None:
        """Use a learned full capacity (Ah) and factor on ``R_0`` from now on (the SoC stays:
        it is what the voltage and the count anchor; the charge behind it is rescaled).

        Every estimator counts charge over ``capacity_ah``; those with a Thevenin model
        (``self.model``) also take the factor. The RC model's bulk capacitor stays the file's.
        """
        if not (capacity_ah > 0.0 and r0_factor > 0.0):
            raise ValueError(
                f"set_health needs capacity and factor > 0, got {capacity_ah}, {r0_factor}"
            )
        self.capacity_ah = capacity_ah
        if self.floor_count is not None:
            self.floor_count.capacity_ah = capacity_ah
        model = getattr(self, "model", None)
        if isinstance(model, TheveninModel):
            model.capacity_ah = capacity_ah
            model.r0_factor = r0_factor

    def reset_soc(self, soc: float, soc_std: float) -> None:
        """Re-initialize to a pack at rest at ``soc`` (keeps the time base)."""
        if not (0.0 <= soc <= 1.0) or not soc_std > 0.0:
            raise ValueError(f"reset_soc needs soc in [0, 1] and std > 0, got {soc}, {soc_std}")
        self._start(soc, soc_std**2)

    def start_from(self, t_s: float | None, soc: float, soc_var: float, current_a: float) -> None:
        """Continue another estimator's run: its last stamp, SoC, variance and current."""
        self._start(min(max(soc, 0.0), 1.0), max(soc_var, 1e-12))
        self.t_last_s = t_s
        self.current_last_a = current_a
