"""The battery's health over a sample stream: full capacity, ``R_0`` factor, state of health.

A :class:`HealthMonitor` runs beside the SoC estimator (the tracker feeds it every accepted
sample) and learns what the battery file cannot know of today's pack: how much charge it
holds (``capacity.py``) and how its series resistance has grown (``resistance.py``). What it
learns feeds the estimator (``Estimator.set_health``), is published (``BatteryState.capacity``,
``power_supply_health``, diagnostics, the estimate vector) and is saved with the SoC
(``tracking/persistence.py``), so it survives restarts and replays; a new pack starts again
from the file's values.

Well-known SoC points (the anchors of the capacity's pairs):

* **a rest** of at least ``rest_min_s`` (current low-passed over ``REST_FILTER_TAU_S`` within
  ``rest_current_c_rate``): the last sample of the rest is read as an OCV, less what the
  monitor's own copy of the Thevenin model says is left of the relaxation (its branches and
  surface lag stepped open-loop from the measured current), and turned into a SoC through the
  file's rested OCV (``BatteryParams.rest_ocv``: every long rest of the identification's
  tests, where the model's table holds the pulse test's alone), with the SoC std
  :meth:`OcvCurve.soc_at_with_interval_std` (how far ``ocv_std_v`` either way moves the SoC):
  a reading on LFP's plateau, or one whose uncertainty reaches it, is not taken; on a knee or
  on SLA's steep curve the std is a percent. The pair keeps the reading as read: the fit maps
  it through the file's law of the OCV's ageing at each capacity it tries
  (``capacity.OcvAgeing``), since an aged pack's rests do not sit on the fresh pack's OCV;
* **a CC-CV charge's end** (``runtime/charging.py``'s FULL): SoC 1 with ``full_soc_std``;
* **a start after a known rest**: when the saved state says the last sample was at rest and
  at least ``rest_min_s`` before the first one, the first sample is a rest's last.

Between consecutive anchors of one run (the count is continuous there) the charge counted and
the SoC change make a pair; its charge variance is the current sensor's offset over the time
and its gain error over the charge moved (``(s_b t / 3600)^2 + (s_g q_moved)^2``, the guard's
error model, ``estimators/guard.py``). A pair that moved less than ``pair_min_soc_drop`` of the
capacity adds nothing (the better-known of its two anchors is kept), and one whose own capacity
is outside the fit's range (``capacity.Q_RANGE``) is rejected and counted. The prior widens as
the pack cycles: ``(capacity_drift_per_cycle Q)^2`` per equivalent full cycle.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from ..models.coulomb import coulomb_efficiency
from ..params import BatteryParams
from ..units import SECONDS_PER_HOUR
from .capacity import Q_RANGE, CapacityEstimator, CapacityPair, OcvAgeing
from .resistance import ResistanceFactor, step_observation

#: Low-pass time constant on the current before the rest test (s), as the hybrid's.
REST_FILTER_TAU_S = 5.0
#: A rest, once begun (low-passed current within ``rest_current_c_rate``), ends only beyond
#: this many times that current. Without the hysteresis a bridge's idle draw near the
#: threshold ended the rest whenever the sensor's noise crossed it: on ``sla_aged86_tuning``
#: (50 mA idle + 24 mA offset, the low-passed noise about 9 mA, threshold 99 mA) not one of
#: six 38-59 min rests reached the 30 minutes of a reading.
REST_END_FACTOR = 2.0
#: A learned value is applied once it is this many of its std away from the file's.
APPLY_SIGMA = 2.0
#: An anchor whose SoC std is at least this tells nothing (on a plateau): it is not taken.
ANCHOR_MAX_SOC_STD = 0.1
#: What :meth:`HealthMonitor.fields` reports (diagnostics, the estimate vector), in order.
HEALTH_FIELDS = ("capacity_ah", "capacity_std_ah", "soh", "r0_factor", "r0_factor_std")


@dataclass(frozen=True)
class HealthState:
    """What is learned and saved: capacity and ``R_0`` factor with their variances, the pack it
    belongs to, and the last sample (for a start after a known rest).

    Attributes:
        capacity_ah, capacity_var_ah2: full capacity (Ah) and its variance.
        r0_factor, r0_factor_var: factor on the file's ``R_0`` and its variance.
        serial_number: the pack's serial number ("" if the source sends none).
        stamp_s: stamp of the last sample behind it (s; NaN if none).
        current_a: the current there, low-passed as the rest test's (A, discharge +; NaN if
            none): one sample's is noise (a 50 mA idle read 160 mA in 40-mA steps).
    """

    capacity_ah: float
    capacity_var_ah2: float
    r0_factor: float
    r0_factor_var: float
    serial_number: str = ""
    stamp_s: float = math.nan
    current_a: float = math.nan

    @classmethod
    def of_file(cls, battery: BatteryParams, serial_number: str = "") -> HealthState:
        """A new pack: the file's capacity and ``R_0``, with the file's prior spreads."""
        h = battery.health
        q = battery.capacity_ah
        return cls(q, (h.capacity_std_frac * q) ** 2, 1.0, h.r0_factor_std**2, serial_number)


def capacity_ageing(battery: BatteryParams) -> OcvAgeing | None:
    """The file's law of the OCV's ageing for the capacity's fit (None: the OCV does not age)."""
    h = battery.health
    if h.ocv_ageing_exponent == 0.0:
        return None
    return OcvAgeing(
        h.ocv_ageing_exponent, h.ocv_ageing_pivot_soc, h.ocv_ageing_below_soc, battery.capacity_ah
    )


@dataclass(frozen=True)
class _Anchor:
    charge_ah: float  # the run's counted charge at the anchor
    throughput_ah: float  # the run's |charge| moved at the anchor
    t_s: float
    soc: float
    soc_var: float


class HealthMonitor:
    """The learning of the module docstring, one sample at a time."""

    def __init__(self, battery: BatteryParams, state: HealthState | None = None) -> None:
        self.battery = battery
        self.settings = battery.health
        self.model = battery.thevenin_model()
        self._ocv = battery.ocv_curve()
        self._rest_ocv = battery.rest_ocv_curve()
        self.start_from(state or HealthState.of_file(battery))

    def start_from(self, state: HealthState) -> None:
        """Continue from ``state`` (a saved one, or :meth:`HealthState.of_file`)."""
        h = self.settings
        self.serial_number = state.serial_number
        self.capacity = CapacityEstimator(
            state.capacity_ah, state.capacity_var_ah2, capacity_ageing(self.battery)
        )
        self.resistance = ResistanceFactor(
            state.r0_factor, state.r0_factor_var, h.r0_drift_per_hour
        )
        self.model.r0_factor = state.r0_factor
        self._resumed_stamp_s = state.stamp_s
        self._resumed_current_a = state.current_a
        self.pairs_rejected = 0
        self._drift_var = 0.0
        self._ref: _Anchor | None = None
        self._pending: _Anchor | None = None
        self._t_s: float | None = None
        self._stamp_s = state.stamp_s
        self._current_a = 0.0
        self._voltage_v = math.nan
        self._charge_ah = 0.0
        self._throughput_ah = 0.0
        self._current_lp_a = 0.0
        self._rest_s = 0.0
        self._x = self.model.rested_state(0.5)
        self._z_modes = self.model.surface_rest()

    def reset(self, serial_number: str = "") -> None:
        """A new pack: start again from the file's values."""
        self.start_from(HealthState.of_file(self.battery, serial_number))

    # -- results ------------------------------------------------------------------------------
    @property
    def capacity_ah(self) -> float:
        return self.capacity.capacity_ah

    @property
    def capacity_std_ah(self) -> float:
        return math.sqrt(self.capacity.capacity_var + self._drift_var)

    @property
    def soh(self) -> float:
        """State of health: the learned capacity over the file's (the pack when identified)."""
        return self.capacity.capacity_ah / self.battery.capacity_ah

    @property
    def applied_capacity_ah(self) -> float:
        """The capacity the estimator computes with (:meth:`learned`'s): what
        ``BatteryState.capacity`` publishes; :attr:`capacity_ah` is the raw estimate."""
        return self.learned()[0]

    @property
    def applied_soh(self) -> float:
        """The SOH of :attr:`applied_capacity_ah`: what ``power_supply_health`` and the SOH
        warnings read, so a change within the evidence's noise neither trips nor publishes."""
        return self.applied_capacity_ah / self.battery.capacity_ah

    @property
    def r0_factor(self) -> float:
        return self.resistance.factor

    @property
    def r0_factor_std(self) -> float:
        return self.resistance.std

    @property
    def pairs_used(self) -> int:
        return len(self.capacity.pairs)

    def fields(self) -> dict[str, float]:
        """The learned values now, by :data:`HEALTH_FIELDS` (SOH: capacity over the file's)."""
        return {
            "capacity_ah": self.capacity_ah,
            "capacity_std_ah": self.capacity_std_ah,
            "soh": self.soh,
            "r0_factor": self.r0_factor,
            "r0_factor_std": self.r0_factor_std,
        }

    def state(self) -> HealthState:
        """What to save now."""
        return HealthState(
            self.capacity.capacity_ah,
            self.capacity.capacity_var + self._drift_var,
            self.resistance.factor,
            self.resistance.var,
            self.serial_number,
            self._stamp_s,
            self._current_lp_a if self._t_s is not None else self._resumed_current_a,
        )

    # -- the stream ---------------------------------------------------------------------------
    def update(
        self,
        t_s: float,
        stamp_s: float,
        current_a: float,
        voltage_v: float,
        temperature_c: float | None,
        soc: float,
    ) -> bool:
        """One accepted sample (``soc`` the estimator's, for the tables); True when the
        capacity or the factor changed (the estimator should take them)."""
        h = self.settings
        q_file = self.battery.capacity_ah
        rest_a = h.rest_current_c_rate * q_file
        changed = False
        if self._t_s is None:
            self._t_s, self._stamp_s = t_s, stamp_s
            self._x = self.model.rested_state(soc)
            gap_s = stamp_s - self._resumed_stamp_s
            rested_before = (
                math.isfinite(gap_s)
                and gap_s >= h.rest_min_s
                and abs(self._resumed_current_a) <= REST_END_FACTOR * rest_a  # a rest going on
                and abs(current_a) <= 2.0 * rest_a
            )
            if rested_before:
                self._ref = self._rest_anchor(t_s, current_a, voltage_v, temperature_c, soc)
            self._current_a, self._voltage_v = current_a, voltage_v
            return False
        dt = t_s - self._t_s
        if not dt > 0.0:
            return False
        i_prev = self._current_a
        # The count: the previous sample's current held over dt (estimators/base.py).
        moved_ah = coulomb_efficiency(i_prev, self.battery.coulomb_efficiency_charge) * i_prev * dt
        moved_ah /= SECONDS_PER_HOUR
        self._charge_ah += moved_ah
        self._throughput_ah += abs(i_prev) * dt / SECONDS_PER_HOUR
        q = self.capacity.capacity_ah
        self._drift_var += (h.capacity_drift_per_cycle * q) ** 2 * abs(moved_ah) / (2.0 * q)
        # The model's branches and lag, open loop from the current (its SoC: the estimator's).
        x_before = self._x
        x_before[0] = soc
        z_before = sum(self._z_modes)
        x_after = self.model.step(x_before, i_prev, dt, temperature_c)
        x_after[0] = soc
        self._z_modes = self.model.surface_step(self._z_modes, i_prev, dt, soc)
        self._x = x_after
        # The factor (resistance.py): a step of the current within one short sample, the
        # model's answer to it from its state before, at the present factor.
        self.resistance.predict(dt)
        di = current_a - i_prev
        if abs(di) >= h.step_min_c_rate * q_file and dt <= h.step_max_dt_s:
            v_before = self.model.terminal_voltage(x_before, i_prev, temperature_c, z_before)
            z_after = sum(self._z_modes)
            v_after = self.model.terminal_voltage(x_after, current_a, temperature_c, z_after)
            r0 = self.model.r0_ohm(soc, temperature_c) / self.model.r0_factor
            obs, var = step_observation(
                self.resistance.factor,
                v_after - v_before,
                voltage_v - self._voltage_v,
                di,
                r0,
                h.voltage_noise_std_v,
                h.current_noise_std_a,
                h.step_model_frac,
            )
            if self.resistance.update(obs, var):
                self.model.r0_factor = self.resistance.factor
                changed = True
        # Rests: the anchor is the rest's last sample, committed when the rest ends.
        w = 1.0 - math.exp(-dt / REST_FILTER_TAU_S)
        self._current_lp_a += w * (current_a - self._current_lp_a)
        # A rest starts within rest_a and ends beyond REST_END_FACTOR times it (hysteresis).
        limit = REST_END_FACTOR * rest_a if self._rest_s > 0.0 else rest_a
        resting = abs(self._current_lp_a) <= limit
        self._rest_s = self._rest_s + dt if resting else 0.0
        if resting and self._rest_s >= h.rest_min_s and abs(current_a) <= 2.0 * rest_a:
            self._pending = self._rest_anchor(t_s, current_a, voltage_v, temperature_c, soc)
        elif self._pending is not None and not resting:
            changed |= self._commit(self._pending)
            self._pending = None
        self._t_s, self._stamp_s = t_s, stamp_s
        self._current_a, self._voltage_v = current_a, voltage_v
        return changed

    def full(self) -> bool:
        """A CC-CV charge ended at this sample: SoC 1 is an anchor. True if the capacity moved."""
        if self._t_s is None:
            return False
        self._pending = None
        anchor = _Anchor(
            self._charge_ah, self._throughput_ah, self._t_s, 1.0, self.settings.full_soc_std**2
        )
        return self._commit(anchor)

    def finish(self) -> bool:
        """The run ends (a replay's last sample, a shutdown): a rest still going is an anchor."""
        changed = False
        if self._pending is not None:
            changed = self._commit(self._pending)
            self._pending = None
        return changed

    # -- anchors and pairs --------------------------------------------------------------------
    def _rest_anchor(
        self,
        t_s: float,
        current_a: float,
        voltage_v: float,
        temperature_c: float | None,
        soc: float,
    ) -> _Anchor | None:
        """The OCV reading of a rest's sample, or None where the curve is too flat to tell.

        The std is the interval's, not the slope's: on the fresh LFP pack the plateau's
        readings at 60 % read 49 % with a slope std of 3 points (3.5 std off), which moved the
        learned capacity by both signs (docs/architecture.md#health)."""
        x = self._x.copy()
        x[0] = soc
        z = sum(self._z_modes)
        v_model = self.model.terminal_voltage(x, current_a, temperature_c, z)
        ocv_v = voltage_v - (v_model - self._ocv.ocv(soc))
        s, std = self._rest_ocv.soc_at_with_interval_std(ocv_v, self.settings.ocv_std_v)
        if std >= ANCHOR_MAX_SOC_STD:
            return None
        return _Anchor(self._charge_ah, self._throughput_ah, t_s, min(max(s, 0.0), 1.0), std * std)

    def _commit(self, anchor: _Anchor | None) -> bool:
        """Pair ``anchor`` with the previous one; True when the capacity estimate moved."""
        if anchor is None:
            return False
        ref, self._ref = self._ref, anchor
        if ref is None:
            return False
        h = self.settings
        prior = self.capacity.prior_ah
        dq = anchor.charge_ah - ref.charge_ah
        if abs(dq) < h.pair_min_soc_drop * prior:
            self._ref = ref if ref.soc_var <= anchor.soc_var else anchor
            return False
        moved = anchor.throughput_ah - ref.throughput_ah
        pair = CapacityPair(
            charge_ah=dq,
            charge_var_ah2=(h.current_offset_std_a * (anchor.t_s - ref.t_s) / SECONDS_PER_HOUR) ** 2
            + (h.current_gain_std * moved) ** 2,
            soc_from=ref.soc,
            soc_from_var=ref.soc_var,
            soc_to=anchor.soc,
            soc_to_var=anchor.soc_var,
            t_from_s=ref.t_s,
            t_to_s=anchor.t_s,
        )
        q_pair = pair.capacity_ah
        if not (Q_RANGE[0] * prior <= q_pair <= Q_RANGE[1] * prior):
            self.pairs_rejected += 1
            return False
        self.capacity.grow_prior(self._drift_var)
        self._drift_var = 0.0
        self.capacity.add(pair)
        return True

    # -- what the estimator takes -------------------------------------------------------------
    def learned(self) -> tuple[float, float]:
        """(capacity in Ah, ``R_0`` factor) for ``Estimator.set_health``: each the learned
        value once it differs from the file's by at least ``APPLY_SIGMA`` of its std, else the
        file's. A change the evidence cannot tell from the readings' own errors is not applied
        (on the fresh LFP pack the rest readings' bias moved the capacity 2 sigma, and the
        hybrid fed with it went from 0.2 % to 2.3 % MAE: docs/architecture.md#health)."""
        q, f = self.capacity.capacity_ah, self.resistance.factor
        q_file = self.battery.capacity_ah
        if abs(q - q_file) < APPLY_SIGMA * self.capacity_std_ah:
            q = q_file
        if abs(f - 1.0) < APPLY_SIGMA * self.resistance.std:
            f = 1.0
        return q, f
