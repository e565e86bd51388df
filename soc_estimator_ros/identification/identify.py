"""Whole-test identification: a pulse test (and optionally a slow discharge) -> BatteryParams."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np

from ..estimators.hybrid import Hybrid
from ..models.coulomb import coulomb_efficiency
from ..models.ocv import OcvCurve
from ..models.rc_saft import RcModelParams
from ..models.tables import ParamTable
from ..models.thevenin import RcBranch, TheveninParams
from ..params import BatteryParams, OcvTable
from ..series import BatterySeries
from ..units import SECONDS_PER_HOUR
from .fit import (
    ONSET_BEND_V,
    PulseFit,
    RcFit,
    charge_removed_ah,
    fit_pulse,
    fit_rc_pulse,
    monotone_ocv_table,
    ocv_bend_v,
    onset_soc,
)
from .kinetics import RATE_PULSE_S, KineticFit, fit_rate_test, fit_saturation, with_kinetics
from .model_error import ModelError, pooled_rms, residual_on_grid, with_bias_std
from .segment import (
    IdentificationError,
    Pulse,
    load_threshold_a,
    long_rests,
    segment_pulses,
    start_after_last_charge,
)
from .surface import MODE_GAIN, LagStage, LagWindow, fit_surface_lag


@dataclass
class IdentificationResult:
    """What :func:`identify` found, and the parameter set built from it."""

    battery: BatteryParams
    pulses: list[PulseFit]
    rc: list[RcFit]
    capacity_ah: float
    capacity_source: str
    ocv_rest_points: list[tuple[float, float]]
    notes: list[str] = field(default_factory=list)
    test: BatterySeries | None = None  # the test as fitted (from full, offset removed)
    soc_track: np.ndarray | None = None  # the SoC the fits used, per sample of ``test``
    levels: list[PulseFit] = field(default_factory=list)  # one fit per SoC level (the tables)
    temperature_c: float = math.nan  # the test's temperature (median of its sensor)
    kinetic: list[KineticFit] = field(default_factory=list)  # rate test fits, when given
    fitted: list[Pulse] = field(default_factory=list)  # the windows of ``pulses``, in order
    # Whether the capacity was measured on this pack (a slow discharge, the test's own charge
    # to the cut-off), so that the OCV table's SoC axis is this pack's; False for a given
    # capacity (a rating) or the template's (another pack's).
    capacity_measured: bool = False


def zero_current_offset(
    series: BatterySeries, rest_threshold_a: float = 0.15, min_rest_s: float = 60.0
) -> float:
    """The current sensor's offset, read where the pack rests.

    Rests are stretches of at least ``min_rest_s`` with |I| below the threshold (single loaded
    samples that dip below it through noise are not rests); the offset is the mean over them
    (the mean, because the noise dithers the 40 mA quantizer: a median snaps to a step). A Hall
    sensor's offset (tens of mA) is a tenth of a C/20 current: coulomb counting a slow
    discharge without this misstates the capacity by as much (measured on the bags).
    """
    quiet = np.abs(series.current_a) < rest_threshold_a
    edges = np.flatnonzero(np.diff(np.concatenate([[0], quiet.astype(int), [0]])))
    picked = []
    for start, stop in zip(edges[::2], edges[1::2], strict=True):
        if series.t_s[stop - 1] - series.t_s[start] >= min_rest_s:
            picked.append(series.current_a[start:stop])
    if not picked:
        return 0.0
    return float(np.mean(np.concatenate(picked)))


def rested_voltage(series: BatterySeries, k: int, window_s: float = 60.0) -> float:
    """Mean voltage over the ``window_s`` ending at sample ``k`` (a rest's end, seed 000 §2.3).

    One sample carries the ADC's quantization step (3.9 mV on a 12-bit, 16 V input) and its
    noise; the mean over a minute of rest dithers both away.
    """
    lo = int(np.searchsorted(series.t_s, series.t_s[k] - window_s))
    return float(np.mean(series.voltage_v[lo : k + 1]))


def offset_corrected(series: BatterySeries, notes: list[str], label: str) -> BatterySeries:
    """``series`` with its rest-measured current offset removed (the note says how much)."""
    offset = zero_current_offset(series)
    notes.append(f"{label}: current offset {1000 * offset:+.1f} mA measured at rest, removed")
    return replace(series, current_a=series.current_a - offset)


def _capacity(
    test, slow, capacity_ah, template, charge_ah, given_measured: bool = False
) -> tuple[float, str, bool]:
    """Given, else from a slow discharge, else the test's own charge when it ends at the
    cut-off (an HPPC that runs to the voltage limit), else the template's; with its source
    and whether it was measured on this pack (the last two; a given capacity only when
    ``given_measured`` says so)."""
    if capacity_ah is not None:
        source = "given, measured on this pack" if given_measured else "given"
        return capacity_ah, source, given_measured
    if slow is not None:
        return float(charge_removed_ah(slow)[-1]), "slow discharge, full to its end", True
    cutoff_v = template.limits.voltage_min_v
    if float(np.min(test.voltage_v)) <= cutoff_v * 1.01:
        return (
            float(np.max(charge_ah)),
            f"the test's charge from full to the {cutoff_v:g} V cut-off (at the test's rates)",
            True,
        )
    return (
        template.capacity_ah,
        "template (not measured: pass --capacity-ah or a slow discharge)",
        False,
    )


def group_by_soc(fits: list[PulseFit], width: float = 0.03) -> list[list[PulseFit]]:
    """Fits at one SoC level (within ``width`` of the level's first), in SoC order.

    An HPPC applies several rates at each SoC level; one table point per level keeps the
    tables free of near-duplicate SoC points with rate-dependent values (a steep kink).
    """
    groups: list[list[PulseFit]] = []
    for f in sorted(fits, key=lambda f: f.soc):
        if groups and f.soc - groups[-1][0].soc < width:
            groups[-1].append(f)
        else:
            groups.append([f])
    return groups


def level_fit(group: list[PulseFit]) -> PulseFit:
    """One fit for a SoC level: the median of each parameter over its pulses (the rates)."""
    if len(group) == 1:
        return group[0]
    med = {
        k: float(np.median([getattr(f, k) for f in group])) for k in PulseFit.__dataclass_fields__
    }
    return PulseFit(**med)


#: A rest of another test (rate, load) at least this long gives an OCV point: the simulated
#: LFP pack (PyBaMM, isothermal, 25 degC) rests to within 0.1 mV of its 8-h value 45 min after
#: 0.2 C and 0.5 C discharges to 18 %; the rate test's 40-s rests between pulses do not count.
OCV_REST_MIN_S = 2700.0


@dataclass(frozen=True)
class RestPoint:
    """An OCV point: the SoC at a rest's end, the voltage rested there, and the rest's length
    (of two points at one SoC level the longer-rested is kept)."""

    soc: float
    voltage_v: float
    rest_s: float


def pulse_rest_points(test: BatterySeries, pulses: list[Pulse], soc_at) -> list[RestPoint]:
    """The rests before each pulse and the one after the last (seed 000 §2.3)."""
    points = [
        RestPoint(
            float(soc_at[p.rest_before]), rested_voltage(test, p.rest_before), p.rest_before_s
        )
        for p in pulses
    ]
    end = pulses[-1].rest_end
    points.append(RestPoint(float(soc_at[end]), rested_voltage(test, end), math.inf))
    return points


def other_rest_points(other: BatterySeries, capacity_ah: float) -> list[RestPoint]:
    """The long rests (>= :data:`OCV_REST_MIN_S`) of another test of the same pack at the same
    temperature, starting full (a rate or load test), on its own charge count.

    The pulse test rests every 10 % of SoC; between its points the table follows the slow
    discharge shifted through them, and that shape is the C/20 discharge's, not the OCV's
    where the curve bends: on the simulated LFP pack the table so made was 17 mV above the
    pack's rested voltage at 23 % (between the pulse test's points at 28 % and 18 %) and
    157 mV below it at 10 % (below the last one), where the rate test rests.
    """
    other = from_full(other, [], "")
    soc = 1.0 - charge_removed_ah(other) / capacity_ah
    quiet = np.abs(other.current_a) < load_threshold_a(other.current_a)
    return [
        RestPoint(float(soc[last]), rested_voltage(other, last), rest_s)
        for _, last, rest_s in long_rests(other.t_s, quiet, OCV_REST_MIN_S)
    ]


def _ocv_table(
    points: list[RestPoint], slow: BatterySeries | None, capacity_ah: float, notes: list[str]
) -> tuple[np.ndarray, np.ndarray]:
    """Rest points (seed 000 §2.3), merged with a slow-discharge curve when given (Fig. 8).

    Of the rest points at one SoC level (an HPPC's pulse set, or another test's rest near a
    pulse test's), the one after the longest rest is used: the 20-min rests between an HPPC's
    pulses still relax by millivolts.
    """
    chosen: list[RestPoint] = []
    for pt in sorted(points, key=lambda pt: -pt.soc):
        if chosen and abs(pt.soc - chosen[-1].soc) < 0.02:
            if pt.rest_s > chosen[-1].rest_s:
                chosen[-1] = pt
            continue
        chosen.append(pt)
    if len(chosen) < len(points):
        notes.append(
            f"OCV: {len(chosen)} rest points of {len(points)} (one per SoC level, "
            "the longest-rested)"
        )
    rest_soc = np.array([pt.soc for pt in chosen])
    rest_v = np.array([pt.voltage_v for pt in chosen])
    if slow is None:
        soc, ocv = rest_soc, rest_v
    else:
        loaded = slow.current_a > 0.5 * np.median(slow.current_a[slow.current_a > 0.01])
        s_soc = 1.0 - charge_removed_ah(slow)[loaded] / capacity_ah
        s_v = slow.voltage_v[loaded]
        order = np.argsort(s_soc)
        s_soc, s_v = s_soc[order], s_v[order]
        # The slow discharge runs below the OCV by its IR drop and polarization; the offset
        # that puts it through each rest point is interpolated between them (held beyond).
        offset = rest_v - np.interp(rest_soc, s_soc, s_v)
        r_order = np.argsort(rest_soc)
        # Grid points closer than half a grid step to a rest point are dropped: a rest point
        # and a shifted-curve point 0.1 % apart would put a steep kink into the PCHIP table.
        base = np.linspace(max(s_soc[0], 0.0), 1.0, 41)
        half_step = 0.5 * (base[1] - base[0])
        far = np.min(np.abs(base[:, None] - rest_soc[None, :]), axis=1) > half_step
        grid = np.unique(np.concatenate([base[far], rest_soc]))
        ocv = np.interp(grid, s_soc, s_v) + np.interp(grid, rest_soc[r_order], offset[r_order])
        soc = grid
        notes.append(
            f"OCV: slow discharge shifted through {rest_soc.size} rest points (offset "
            f"{1000 * offset.min():.0f}..{1000 * offset.max():.0f} mV)"
        )
    soc, ocv, n_fixed = monotone_ocv_table(soc, ocv)
    if n_fixed:
        notes.append(f"OCV: {n_fixed} point(s) raised to keep the table strictly increasing")
    return soc, ocv


def rested_ocv(
    pulse_points: list[RestPoint],
    rate_test: BatterySeries | None,
    load_test: BatterySeries | None,
    slow: BatterySeries | None,
    capacity_ah: float,
    notes: list[str],
) -> OcvTable | None:
    """The rested OCV (``BatteryParams.rest_ocv``): the pulse test's rests and every long rest
    of the rate and load tests, through the same merge as the model's table; None when those
    tests add no point.

    Why a second table: the model's ``ocv`` is the pulse test's, and the branches, the lag
    and the model error are fitted with it; the other tests' rests put it right where it is
    wrong at rest (between the pulse test's points) but, put into the model's table, they
    made the open-loop model worse on every LFP recording tried (the rate test's own RMSE
    25 -> 43 mV, the load test's 46 -> 65 mV, the field runs' 36-42 -> 38-64 mV), so they
    stay out of it. The health monitor reads rests with this one.
    """
    extra: list[RestPoint] = []
    for other, label in ((rate_test, "rate test"), (load_test, "load test")):
        if other is not None:
            found = other_rest_points(other, capacity_ah)
            notes.append(f"rested OCV: {len(found)} rest point(s) of the {label} (>= 45 min)")
            extra += found
    if not extra:
        return None
    own: list[str] = []
    soc, volts = _ocv_table(pulse_points + extra, slow, capacity_ah, own)
    notes += [f"rested {note}" for note in own]
    return OcvTable(soc=tuple(float(x) for x in soc), voltage_v=tuple(float(v) for v in volts))


def _fit_pulses(
    test: BatterySeries,
    pulses: list[Pulse],
    soc_at: np.ndarray,
    shape_ocv: OcvCurve,
    min_tau_s: float,
    notes: list[str],
    progress: Callable[[str], None] | None,
) -> tuple[list[PulseFit], list[RcFit], list[Pulse]]:
    """Every pulse's 2-RC fit and seed 000's RC fit; a pulse whose fit fails is skipped and
    noted. A pulse whose onset crosses a bend of ``shape_ocv`` is fitted on its end."""
    fits: list[PulseFit] = []
    rcs: list[RcFit] = []
    fitted: list[Pulse] = []
    for n, p in enumerate(pulses, 1):
        if progress:
            progress(f"pulse {n}/{len(pulses)} at SoC {soc_at[p.start]:.2f}")
        bend_v = ocv_bend_v(shape_ocv, onset_soc(test, p, soc_at))
        anchor_end = bend_v > ONSET_BEND_V
        if anchor_end:
            notes.append(
                f"pulse at SoC {soc_at[p.start]:.2f}: the OCV bends {1000 * bend_v:.1f} mV "
                f"(> {1000 * ONSET_BEND_V:g}) over its onset: fitted on its end and the rest "
                f"after it, at SoC {soc_at[p.end]:.2f}"
            )
        try:
            fit = fit_pulse(test, p, soc_at, min_tau_s=min_tau_s, anchor_end=anchor_end)
            rc_fit = fit_rc_pulse(test, p)
        except (IdentificationError, RuntimeError, ValueError) as exc:
            notes.append(f"pulse at t = {test.t_s[p.start]:.0f} s skipped: {exc}")
            continue
        fits.append(fit)
        rcs.append(rc_fit)
        fitted.append(p)
    if not fits:
        raise IdentificationError(f"none of the {len(pulses)} pulse fits succeeded")
    return fits, rcs, fitted


def _rc_model(
    capacity_ah: float, ocv_soc: np.ndarray, ocv_v: np.ndarray, rcs: list[RcFit]
) -> RcModelParams:
    """Seed 000's RC model: the resistances and ``C_s`` the medians of the pulses' fits (its
    eqs. 6-10); the bulk capacitor, whose voltage is the OCV, holds the capacity over the
    OCV's span, ``C_b = 3600 Q dSoC / dV`` (the paper gives no rule for it)."""
    span_v = float(ocv_v[-1] - ocv_v[0])
    span_soc = float(ocv_soc[-1] - ocv_soc[0])
    return RcModelParams(
        c_b_f=3600.0 * capacity_ah * span_soc / span_v,
        c_s_f=float(np.median([r.c_s_f for r in rcs])),
        r_b_ohm=float(np.median([r.r_b_ohm for r in rcs])),
        r_s_ohm=float(np.median([r.r_s_ohm for r in rcs])),
        r_t_ohm=float(np.median([r.r_t_ohm for r in rcs])),
    )


def identify(
    test: BatterySeries,
    template: BatteryParams,
    capacity_ah: float | None = None,
    slow: BatterySeries | None = None,
    progress: Callable[[str], None] | None = None,
    rate_test: BatterySeries | None = None,
    shape_ocv: OcvCurve | None = None,
    load_test: BatterySeries | None = None,
    capacity_measured: bool = False,
) -> IdentificationResult:
    """Identify OCV, RC-model and 2-RC Thevenin parameters from a pulse test.

    The test starts full: at its first sample, or at the rest after its last recharge when it
    begins with one (reported). Every fit that fails is skipped and reported, never guessed.
    With ``rate_test`` (a rate test at the same temperature, starting full), R0 becomes the
    ohmic part of the drop and the Butler-Volmer overpotential is added (``kinetics.py``).
    The surface lag (``surface.py``) is fitted on the windows of the pulse test, the rate test
    and ``load_test`` (steps at a heavy load with long rests: the slow recovery the others do
    not excite), unless ``shape_ocv`` is given (another temperature's test).
    ``capacity_measured``: the given ``capacity_ah`` was measured on this pack (a C/20
    discharge to the cut-off), not a rating (the hybrid's ``ocv_axis_std_frac``, tuning.py).
    """
    notes: list[str] = []
    test = from_full(test, notes, "pulse test")
    if slow is not None:
        slow = offset_corrected(slow, notes, "slow discharge")
    charge_ah = charge_removed_ah(test, notes=notes)
    capacity, cap_source, cap_measured = _capacity(
        test, slow, capacity_ah, template, charge_ah, capacity_measured
    )
    if not capacity > 0:
        raise IdentificationError(f"capacity must be > 0 Ah, got {capacity}")
    pulses = segment_pulses(test, notes=notes)
    soc_at = 1.0 - charge_ah / capacity
    rest_points = pulse_rest_points(test, pulses, soc_at)
    ocv_soc, ocv_v = _ocv_table(rest_points, slow, float(capacity), notes)
    rest_ocv = None
    if shape_ocv is None:  # the reference temperature's test
        rest_ocv = rested_ocv(rest_points, rate_test, load_test, slow, float(capacity), notes)
    min_tau_s = 0.5  # what 10 Hz samples resolve
    if rate_test is not None:
        min_tau_s = RATE_PULSE_S
        notes.append(
            f"with a rate test: RC time constants >= {RATE_PULSE_S:g} s (the drop within its "
            "pulses is the rate test's; a faster branch would add, within a second of any "
            "load, the recovery a 30-min pulse builds over minutes)"
        )
    ocv_curve = OcvCurve(ocv_soc, ocv_v)
    fits, rcs, fitted = _fit_pulses(
        test, pulses, soc_at, shape_ocv or ocv_curve, min_tau_s, notes, progress
    )
    by_soc = [level_fit(g) for g in group_by_soc(fits)]
    if len(by_soc) < len(fits):
        notes.append(
            f"tables: {len(fits)} pulse fits at {len(by_soc)} SoC levels (median over the "
            "rates of each level)"
        )
    thevenin = thevenin_tables(by_soc)
    kinetic: list[KineticFit] = []
    if rate_test is not None:
        kinetic = rate_test_fits(rate_test, float(capacity), notes, thevenin, ocv_curve)
        thevenin = with_kinetics(thevenin, [kinetic])
    rc = _rc_model(float(capacity), ocv_soc, ocv_v, rcs)
    battery = replace(
        template,
        capacity_ah=float(capacity),
        ocv=OcvTable(
            soc=tuple(float(s) for s in ocv_soc), voltage_v=tuple(float(v) for v in ocv_v)
        ),
        rest_ocv=rest_ocv,
        rc_model=rc,
        thevenin=thevenin,
    )
    if shape_ocv is None:
        # Only where this test's OCV has the bends' shape (a slow discharge, or the rests
        # alone): another test's table is its rests, straight between them.
        if load_test is not None and rate_test is None:
            notes.append(
                "load test without a rate test: the 2RC without the rate test's kinetics misses "
                "its 3 C steps by tens of mV (LFP: 60 mV), more than any lag mode explains"
            )
        # The rate test's start is reported by rate_test_fits, the load test's here.
        extras = [(rate_test, "rate test", []), (load_test, "load test", notes)]
        battery = with_surface_lag(battery, test, pulses, soc_at, extras, notes)
    # The rests before each pulse (the last point is the rest after the last pulse).
    pulse_rests = [(pt.soc, pt.voltage_v) for pt in rest_points[:-1]]
    return IdentificationResult(
        battery,
        fits,
        rcs,
        float(capacity),
        cap_source,
        pulse_rests,
        notes,
        test,
        soc_at,
        by_soc,
        test_temperature_c(test),
        kinetic,
        fitted,
        cap_measured,
    )


#: A window of another test (rate, load) belongs below the knee if it starts within this of
#: the knee's end (SoC): their charge counts differ from the pulse test's by up to about 1 %.
KNEE_END_TOLERANCE = 0.02


def with_surface_lag(
    battery: BatteryParams,
    test: BatterySeries,
    pulses: list[Pulse],
    soc_at: np.ndarray,
    extras: list[tuple[BatterySeries | None, str, list[str]]],
    notes: list[str],
) -> BatteryParams:
    """``battery`` with the surface lag fitted (``surface.py``): a first mode on the pulses of
    ``test`` whose onset crosses a bend (the knee), a second on the windows below the knee of
    ``test`` and of each other test in ``extras`` ((test or None, its label, the list its
    from_full notes go to): a rate test, a load test, starting full like ``test``) that cross a
    bend, driven only below the knee's end."""
    ocv = battery.ocv_curve()
    knee = [p for p in pulses if ocv_bend_v(ocv, onset_soc(test, p, soc_at)) > ONSET_BEND_V]
    knee_end = min((float(soc_at[p.rest_end]) for p in knee), default=1.0)
    below = [(test, [p for p in pulses if p not in knee], soc_at)]
    for extra, label, extra_notes in extras:
        if extra is not None:
            extra, extra_soc = counted(extra, battery.capacity_ah, extra_notes, label)
            below.append((extra, segment_pulses(extra), extra_soc))
    below_windows = [
        w
        for series, ps, soc in below
        for w in lag_windows(
            battery,
            series,
            [p for p in ps if soc[p.rest_before] <= knee_end + KNEE_END_TOLERANCE],
            soc,
        )
    ]
    stages = (
        LagStage(lag_windows(battery, test, knee, soc_at)),
        LagStage(below_windows, soc_max=knee_end),
    )
    fit = fit_surface_lag(ocv, stages)
    names = ("the knee", f"below the knee (SoC <= {knee_end:.3f})")
    for name, stage, (without, with_mode), kept in zip(
        names, stages, fit.rmse_v, fit.kept, strict=True
    ):
        if not stage.windows:
            notes.append(f"surface lag, {name}: no window crosses a bend of the OCV")
            continue
        verdict = "kept" if kept else f"not kept (< {100 * MODE_GAIN:.0f} % off, or at a bound)"
        notes.append(
            f"surface lag, {name}: {len(stage.windows)} window(s) across a bend, "
            f"{1000 * without:.1f} -> {1000 * with_mode:.1f} mV RMSE with a mode: {verdict}"
        )
    if fit.lag is None:
        return battery
    modes = ", ".join(
        f"g {g:.4g} SoC/A tau {tau:.0f} s below SoC {soc_max:.3f}"
        for g, tau, soc_max in zip(
            fit.lag.gain_soc_per_a, fit.lag.tau_s, fit.lag.soc_max, strict=True
        )
    )
    notes.append(f"surface lag: {modes}")
    return replace(battery, thevenin=replace(battery.thevenin, surface_lag=fit.lag))


def lag_windows(
    battery: BatteryParams, test: BatterySeries, pulses: list[Pulse], soc_at: np.ndarray
) -> list[LagWindow]:
    """The windows (the rest before a pulse, the pulse, the rest after) whose SoC crosses a bend
    of ``battery``'s OCV (by more than ``ONSET_BEND_V``), with the open-loop voltage and SoC over
    each (from a pack at rest at the window's SoC): the surface lag's data (``surface.py``).
    Where the OCV is straight the pulse's own branch fit has already taken up what a lag does
    there, and such a window would pull the lag towards 0."""
    ocv = battery.ocv_curve()
    out = []
    for p in pulses:
        # Up to the pack's lowest SoC in use (limits.soc_min): below it the tables are held
        # and what a lag fitted there would absorb is their error, not the surface's.
        in_use = np.flatnonzero(soc_at[p.rest_before : p.rest_end + 1] < battery.limits.soc_min)
        end = p.rest_end + 1 if not in_use.size else p.rest_before + int(in_use[0])
        if end - p.rest_before < 3:
            continue
        if ocv_bend_v(ocv, soc_at[p.rest_before : end]) <= ONSET_BEND_V:
            continue
        window = test.window(p.rest_before, end)
        v0, soc = simulate_open_loop(battery, window, float(soc_at[p.rest_before]))
        out.append(LagWindow.on_grid(window, v0, soc))
    return out


def from_full(test: BatterySeries, notes: list[str], label: str) -> BatterySeries:
    """A test as the fits take it: from full (its first sample, or the rest after the last
    recharge it begins with), its current offset removed; each choice noted."""
    if test.repeated_stamps:
        notes.append(f"{label}: {test.repeated_stamps} rows repeating a time stamp dropped")
    first = start_after_last_charge(test)
    if first is not None:
        notes.append(
            f"{label} starts at t = {test.t_s[first]:.0f} s, at the rest after the last "
            f"recharge ({first} samples before it skipped); SoC 1 there"
        )
        test = test.window(first)
    return offset_corrected(test, notes, label)


def counted(
    test: BatterySeries, capacity_ah: float, notes: list[str], label: str
) -> tuple[BatterySeries, np.ndarray]:
    """A test from full (:func:`from_full`) and its SoC counted from there (1 at its start)."""
    test = from_full(test, notes, label)
    return test, 1.0 - charge_removed_ah(test) / capacity_ah


def model_error(
    battery: BatteryParams,
    tests: list[tuple[BatterySeries, np.ndarray]],
    notes: list[str],
    v_models: list[np.ndarray] | None = None,
) -> ModelError | None:
    """The model's own voltage error over ``tests`` (at the reference temperature, each from
    full with its counted SoC): ``model_error.py``; None (noted) when too few seconds of them
    run from a load to the hybrid's rest. ``v_models``: the model's voltage over each test with
    its SoC imposed (:func:`simulate_open_loop`, ``gap_s`` 0), when already simulated."""
    tuning = Hybrid.merged_tuning(battery.filters.get("hybrid"))
    residuals = []
    for n, (test, soc) in enumerate(tests):
        if v_models is None:
            v_model, _ = simulate_open_loop(battery, test, float(soc[0]), soc, gap_s=0.0)
        else:
            v_model = v_models[n]
        residuals.append(residual_on_grid(battery, test, soc, v_model, tuning))
    try:
        error = pooled_rms(residuals)
    except IdentificationError as exc:
        default_mv = 1000 * float(Hybrid.default_tuning["bias_std_v"])
        notes.append(
            f"{exc}: filters.hybrid.bias_std_v left at the code default ({default_mv:.0f} mV)"
        )
        return None
    notes.append(
        f"model error (the SoC imposed) over {len(tests)} test(s), {error.seconds} s from a "
        f"load to {tuning['rest_min_s']:.0f} s of rest: {1000 * error.rms_v:.1f} mV RMS "
        "(filters.hybrid.bias_std_v)"
    )
    return error


def with_model_error(
    battery: BatteryParams, tests: list[tuple[BatterySeries, np.ndarray]], notes: list[str]
) -> BatteryParams:
    """``battery`` with the hybrid's ``bias_std_v`` measured as its own model's voltage error
    over ``tests`` (:func:`model_error`); when it cannot be measured, without one (the code
    default; never another model's value)."""
    return with_bias_std(battery, model_error(battery, tests, notes))


def rate_test_fits(
    rate_test: BatterySeries,
    capacity_ah: float,
    notes: list[str],
    thevenin: TheveninParams | None = None,
    ocv: OcvCurve | None = None,
) -> list[KineticFit]:
    """The rate test's per-level kinetic fits; it starts full as the pulse test does. With the
    pulse test's ``thevenin`` tables and ``ocv`` curve, each level also gets the fastest
    branch's saturation current (``kinetics.fit_saturation``)."""
    rate_test = from_full(rate_test, notes, "rate test")
    soc = 1.0 - charge_removed_ah(rate_test, notes=notes) / capacity_ah
    fits = fit_rate_test(rate_test, soc, capacity_ah, notes)
    if thevenin is None or ocv is None:
        return fits
    fits = [fit_saturation(f, thevenin, ocv, capacity_ah) for f in fits]
    sats = [f.i_sat_a for f in fits if f.i_sat_a is not None]
    if sats:
        notes.append(
            f"rate test: fastest branch saturates at {min(sats):.2f}..{max(sats):.2f} A; pulse "
            f"ends fitted within {1000 * max(f.end_rmse_v for f in fits):.1f} mV RMSE"
        )
    return fits


def test_temperature_c(test: BatterySeries) -> float:
    """The test's temperature: the median of its sensor (NaN without one)."""
    temps = test.temperature_c[np.isfinite(test.temperature_c)]
    return float(np.median(temps)) if temps.size else math.nan


def over_temperature(results: list[IdentificationResult], reference: int) -> BatteryParams:
    """One parameter set with 2-RC tables over (temperature, SoC) from tests at several
    temperatures (each result's ``temperature_c`` must be set and distinct).

    ``results[reference]`` (the test nearest 25 degC) gives the OCV curve, capacity and RC
    model; the other tests give the OCV's shift with temperature (``ocv.offset_v``: their own
    rested voltages minus the reference curve). Every test's per-level fits are interpolated
    onto the reference's SoC grid (held at their ends) so that the tables are bilinear on one
    grid.
    """
    ref = results[reference]
    temps = [r.temperature_c for r in results]
    if any(math.isnan(t) for t in temps) or len(set(temps)) != len(temps):
        raise IdentificationError(f"each test needs its own temperature, got {temps}")
    order = np.argsort(temps)
    grid = np.array([f.soc for f in ref.levels])

    def table(get) -> ParamTable:
        rows = []
        for n in order:
            lv = results[n].levels
            rows.append(np.interp(grid, [f.soc for f in lv], [get(f) for f in lv]))
        return ParamTable.from_arrays(grid, np.array(rows), [temps[n] for n in order])

    thevenin = TheveninParams(
        r0_ohm=table(lambda f: f.r0_ohm),
        branches=(
            RcBranch(table(lambda f: f.r1_ohm), table(lambda f: f.tau1_s / f.r1_ohm)),
            RcBranch(table(lambda f: f.r2_ohm), table(lambda f: f.tau2_s / f.r2_ohm)),
        ),
        # No temperature axis: the simulated packs' particle diffusivities do not depend on
        # temperature (fitted on the 5 degC LFP pulse test alone, g comes out the same).
        surface_lag=ref.battery.thevenin.surface_lag,
    )
    zero = tuple(0.0 for _ in ref.battery.ocv.soc)
    offsets = [
        zero if n == reference else ocv_shift_v(ref.battery.ocv, results[n].battery.ocv)
        for n in order
    ]
    ocv = replace(
        ref.battery.ocv, temperature_c=tuple(temps[n] for n in order), offset_v=tuple(offsets)
    )
    if all(r.kinetic for r in results):
        thevenin = with_kinetics(thevenin, [results[n].kinetic for n in order])
    elif any(r.kinetic for r in results):
        raise IdentificationError("a rate test for some temperatures only: give one per test")
    return replace(ref.battery, thevenin=thevenin, ocv=ocv)


def ocv_shift_v(reference: OcvTable, own: OcvTable) -> tuple[float, ...]:
    """The OCV's shift at another temperature, on the reference's SoC grid (volts).

    Measured where the other test rested: at each of its own OCV points (its rest points; it
    has no slow discharge of its own) the difference from the reference curve, interpolated
    linearly between them and held beyond. Not the difference of the two curves at every grid
    point: between sparse rest points the other test's curve is an interpolation, not a
    measurement, and across LFP's knee near full (rests at 1.0 and 0.87) it ran 0.4-0.6 V
    above the reference's measured shape, which put the 5 degC LFP model 360 mV high at
    SoC 0.95 (the cold field run's first 15 minutes).
    """
    own_soc = np.asarray(own.soc, dtype=float)
    diff = np.asarray(own.voltage_v, dtype=float) - reference.curve().ocv_array(own_soc)
    return tuple(float(v) for v in np.interp(reference.soc, own_soc, diff))


def thevenin_tables(by_soc: list[PulseFit]) -> TheveninParams:
    """2-RC tables over SoC from per-level fits (C = tau / R)."""
    soc = [f.soc for f in by_soc]

    def table(values: list[float]) -> ParamTable:
        return ParamTable.from_arrays(soc, values)

    return TheveninParams(
        r0_ohm=table([f.r0_ohm for f in by_soc]),
        branches=(
            RcBranch(
                table([f.r1_ohm for f in by_soc]), table([f.tau1_s / f.r1_ohm for f in by_soc])
            ),
            RcBranch(
                table([f.r2_ohm for f in by_soc]), table([f.tau2_s / f.r2_ohm for f in by_soc])
            ),
        ),
    )


def simulate_voltage(
    battery: BatteryParams,
    series: BatterySeries,
    soc0: float,
    soc_track: np.ndarray | None = None,
    gap_s: float = 10.0,
) -> np.ndarray:
    """Open-loop 2-RC model voltage over a recording, from ``soc0`` with the measured current.

    Across a logging gap (a step over ``gap_s``) the held current does not describe the
    charge moved; with ``soc_track`` (the SoC the identification counted, e.g. from a tester's
    reference) the model's SoC is set from it after each gap, its branch states kept.
    """
    return simulate_open_loop(battery, series, soc0, soc_track, gap_s)[0]


def simulate_open_loop(
    battery: BatteryParams,
    series: BatterySeries,
    soc0: float,
    soc_track: np.ndarray | None = None,
    gap_s: float = 10.0,
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`simulate_voltage`'s voltage (V) and the model's SoC at every sample.

    The SoC is counted sample by sample (``TheveninModel.step``'s coulomb count, set from
    ``soc_track`` after each gap); the voltage along it in one pass
    (``TheveninModel.voltage_along``: every value that of the per-sample step / surface_step /
    terminal_voltage loop, to the last bit, at a fraction of its cost).
    """
    model = battery.thevenin_model()
    if not series.t_s.size:
        return np.empty(0), np.empty(0)
    dt = np.diff(series.t_s, prepend=series.t_s[:1])  # dt[0] = 0: no step into sample 0
    soc = np.empty(series.t_s.size)
    soc[0] = soc0
    per_ah = SECONDS_PER_HOUR * model.capacity_ah
    ce = model.coulomb_efficiency_charge
    amps, dts = series.current_a.tolist(), dt.tolist()
    track = None if soc_track is None else np.asarray(soc_track, dtype=float).tolist()
    s = float(soc[0])
    for k in range(1, soc.size):
        s = s - coulomb_efficiency(amps[k - 1], ce) * amps[k - 1] * dts[k] / per_ah
        if track is not None and dts[k] > gap_s:
            s = track[k]
        soc[k] = s
    return model.voltage_along(soc, series.current_a, dt, series.temperature_c), soc


def voltage_rmse(
    battery: BatteryParams,
    series: BatterySeries,
    soc0: float,
    soc_track: np.ndarray | None = None,
) -> float:
    """RMSE (V) of :func:`simulate_voltage` against the recorded voltage."""
    v = simulate_voltage(battery, series, soc0, soc_track)
    return float(np.sqrt(np.mean((v - series.voltage_v) ** 2)))
