"""The filter tunings ``soc_identify`` writes: from the tests, the code default or the template.

A battery file's ``filters`` block holds two kinds of entry. Some describe the identified model:
how large its voltage error is and up to which load it holds. Those belong to the model these
tests identified, never to the template's (another pack's model, or one fitted on other tests):
a file identified from a pulse test alone (a linear 2RC fitted at 0.2 C) that kept the bundled
template's 6 C voltage-update gate had the hybrid read 10-20 A bursts through a model that is
volts wrong there (SLA field run: 12.7 % MAE). The others describe the sensor, the pack's scale,
the chemistry's relaxation or the filter's mechanics, and stay as the template has them. Per
entry (the table in docs/identification.md, "Filter tunings"):

* ``hybrid.update_c_rate_max`` (**derived**): the highest C-rate the model was fitted at
  (written as well, given or not, as the model's ``thevenin.fitted_c_rate_max``: the current
  envelope of these tests, which the state of power does not go beyond; the gate is a filter
  tuning that may be moved, the envelope is what the tests covered). With
  rate tests, their highest step (the kinetic fit's range). From the pulses (groups of fitted
  pulses whose rates are within ``RATE_GROUP_RATIO`` of the group's lowest, at SoC >=
  ``limits.soc_min``), the highest rate up to which every group's RMS voltage error, the SoC
  imposed, stays within ``GATE_ERROR_FACTOR`` times ``bias_std_v`` (the model-error state the
  hybrid carries); the lowest group's rate when even it does not (nothing lower was fitted);
  with tests at several temperatures, the lowest of their gates (one gate serves them all:
  the NCR18650PF's 2RC holds to 2 C at 25.8 degC, to 0.5 C at 0.6 degC). The higher of the
  pulses' and the rate tests', floored to two significant digits (within the fitted range;
  the current sensor's gain error makes a third digit noise).
* ``hybrid.update_charge_c_rate_max`` (**derived**): the same for charge currents. The
  identification fits discharges; a charge is only checked: the model's RMS error over the
  charging samples of the reference temperature's tests, the SoC imposed, in the C-rate bins
  of ``r_per_a`` below; the highest bin's mean rate up to which every bin stays within
  ``GATE_ERROR_FACTOR`` times ``bias_std_v``, floored to two digits (0: no voltage read while
  charging beyond the rest band); the code default (the discharge gate serves both) when the
  tests hold no charge, as the bundled packs' do not.
* ``hybrid.r_per_a`` (**derived**, else the code default): under load the hybrid assumes an
  error of variance ``r + bias_std_v^2 + (r_per_a I)^2``. The model's RMS error ``e`` is taken in
  octave bins of the C-rate (edges ``BIN_LOW_C`` 2^k; the bins up to the gate's, each with
  ``MIN_BIN_S`` or more) over the reference temperature's tests, the SoC imposed; ``r_per_a``
  is the smallest value that covers every bin, the largest ``sqrt(e^2 - r - bias^2) / I``.
  Where ``r`` and the bias state already cover every bin (the bundled packs: ``r`` is (224 mV)^2
  against errors of 8-81 mV), the code default stays.
* ``hybrid.bias_std_v`` (**measured**: ``model_error.py``); ``hybrid.bias_tau_s`` (the code
  default: not identified); ``hybrid.update_soc_min`` (the code default, no gate: whether the
  model holds below its lowest pulse level under load is a choice on recordings of the pack,
  as the bundled LFP file's is, not something the pulses show).
* ``hybrid.ocv_axis_std_frac`` (**derived**, else the code default): the OCV table's SoC axis
  is the charge from full over the file's capacity, so where that capacity was not measured on
  this pack (given: a rating; or the template's) the axis is off by as much as a pack differs
  from its kind: the guard's ``capacity_std_frac``; the code default, 0, where it was measured
  (a slow discharge, the test's own charge to the cut-off).
* every other entry (``r`` of every filter, the rest detection, ``ocv_std_v``, the NIS gate,
  process noises, initial variances, sigma points, the papers' presets): the **template's**.

An entry given as ``--tuning BLOCK.KEY=VALUE`` (**given**: measured elsewhere, e.g. on field
runs, as the bundled LFP file's ``r_per_a``) is written as given, whatever its kind; the report
says what the tests alone give for it.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from ..estimators import ESTIMATORS, PRESETS
from ..estimators.hybrid import Hybrid
from ..params import BatteryParams
from ..series import BatterySeries
from .identify import IdentificationResult, model_error, simulate_open_loop
from .segment import IdentificationError, Pulse
from .surface import GRID_S

#: A rate is within the model's range while its RMS error stays within this many ``bias_std_v``.
GATE_ERROR_FACTOR = 2.0
#: Fitted pulses within this ratio of a group's lowest rate are one rate.
RATE_GROUP_RATIO = 1.25
#: Lowest edge of the C-rate bins for ``r_per_a`` (octaves from it: 0.0375, 0.075, 0.15, ... C,
#: so that 0.1, 0.2, 0.5, 1, 2, 3-4 and 6 C pulses each sit inside one); below it, a rest.
BIN_LOW_C = 0.0375
#: A bin with fewer seconds than this is not judged.
MIN_BIN_S = 10.0

#: The entries that describe the identified model (block -> key -> how it is set); every other
#: entry of the template is kept.
MODEL_SPECIFIC: Mapping[str, Mapping[str, str]] = {
    "hybrid": {
        "update_c_rate_max": "derived",
        "update_charge_c_rate_max": "derived",
        "update_soc_min": "default",
        "r_per_a": "derived",
        "bias_std_v": "measured",
        "bias_tau_s": "default",
        "ocv_axis_std_frac": "derived",
    },
}
_MODEL_KEYS = frozenset(k for block in MODEL_SPECIFIC.values() for k in block)


@dataclass(frozen=True)
class TuningSource:
    """Where one filter entry comes from: ``measured``, ``derived``, ``default`` (not written:
    the estimator's code default), ``template`` or ``given`` (``--tuning``)."""

    block: str
    key: str
    value: Any  # as written; the code default for ``default``
    source: str
    why: str


@dataclass(frozen=True)
class RateError:
    """The model's RMS voltage error (V) over the samples at one C-rate: a group of fitted
    pulses or a bin of the current."""

    rate_c: float  # the group's highest pulse rate, or the bin's mean |I| over the capacity
    current_a: float  # mean |I| over the samples
    rms_v: float
    seconds: float


@dataclass(frozen=True)
class Simulated:
    """One test at the reference temperature (from full), its counted SoC and the model's
    voltage with that SoC imposed at every sample."""

    test: BatterySeries
    soc: np.ndarray
    v_model: np.ndarray

    @property
    def residual_v(self) -> np.ndarray:
        return self.test.voltage_v - self.v_model

    @property
    def weight_s(self) -> np.ndarray:
        """Each sample's time, up to a second (as the 1-s grid of ``model_error.py`` weighs: a
        sample logged after a minute's gap counts once, not sixty times)."""
        return np.append(np.minimum(np.diff(self.test.t_s), GRID_S), 0.0)


def simulate(
    battery: BatteryParams, tests: Sequence[tuple[BatterySeries, np.ndarray]]
) -> list[Simulated]:
    """:class:`Simulated` per test (``identify.simulate_open_loop``, the SoC imposed)."""
    out = []
    for test, soc in tests:
        v_model, _ = simulate_open_loop(battery, test, float(soc[0]), soc, gap_s=0.0)
        out.append(Simulated(test, soc, v_model))
    return out


def _rate_error(
    sims_idx: Sequence[tuple[Simulated, np.ndarray]], soc_min: float, rate_c: float
) -> RateError | None:
    """:class:`RateError` over the samples ``idx`` of each simulated test (at SoC >=
    ``soc_min``); None without any."""
    w_all, r_all, i_all = [], [], []
    for sim, idx in sims_idx:
        keep = idx[sim.soc[idx] >= soc_min]
        w_all.append(sim.weight_s[keep])
        r_all.append(sim.residual_v[keep])
        i_all.append(np.abs(sim.test.current_a[keep]))
    w, r, i = (np.concatenate(a) for a in (w_all, r_all, i_all))
    seconds = float(np.sum(w))
    if seconds <= 0.0:
        return None
    rms = math.sqrt(float(np.sum(w * r**2)) / seconds)
    return RateError(rate_c, float(np.sum(w * i)) / seconds, rms, seconds)


def pulse_rate_errors(
    sim: Simulated, pulses: Sequence[Pulse], capacity_ah: float, soc_min: float
) -> list[RateError]:
    """The model's error per group of fitted pulses of one rate (``RATE_GROUP_RATIO``), over
    their excitations (first to last loaded sample), in increasing rate."""
    groups: list[list[Pulse]] = []
    for p in sorted(pulses, key=lambda p: p.current_a):
        if groups and p.current_a <= RATE_GROUP_RATIO * groups[-1][0].current_a:
            groups[-1].append(p)
        else:
            groups.append([p])
    out = []
    for g in groups:
        idx = np.concatenate([np.arange(p.start, p.end + 1) for p in g])
        err = _rate_error([(sim, idx)], soc_min, max(p.current_a for p in g) / capacity_ah)
        if err is not None:
            out.append(err)
    return out


def kinetic_top_c(results: Sequence[IdentificationResult], capacity_ah: float) -> float | None:
    """The highest C-rate of the steps the rate tests' kinetic fits were fitted on (None
    without rate tests): the range the current-dependent drop covers."""
    steps = [abs(s.current_a) for res in results for fit in res.kinetic for s in fit.steps]
    return max(steps) / capacity_ah if steps else None


def floor_2_digits(x: float) -> float:
    """``x`` > 0 floored to two significant digits (6.044 -> 6.0, 0.2086 -> 0.2)."""
    e = math.floor(math.log10(x)) - 1
    n = math.floor(x / 10.0**e * (1.0 + 1e-12))  # 0.2 stays 0.2 (x / 0.01 = 19.999...)
    return n / 10.0**-e if e < 0 else n * 10.0**e


def pulse_gate(groups: Sequence[RateError], limit_v: float) -> tuple[float | None, str]:
    """The highest rate of ``groups`` (one test's, in increasing rate) up to which every
    group's error stays within ``limit_v``; the lowest group's when even it does not."""
    if not groups:
        return None, "no fitted pulse at SoC >= limits.soc_min"
    rates = ", ".join(f"{g.rate_c:.3g} C {1000 * g.rms_v:.1f} mV" for g in groups)
    top = highest_within(groups, limit_v)
    if top is not None:
        return top, f"{rates}: up to {top:.3g} C"
    return groups[0].rate_c, f"{rates}: none, the lowest rate {groups[0].rate_c:.3g} C used"


def highest_within(groups: Sequence[RateError], limit_v: float) -> float | None:
    """The highest rate of ``groups`` (in increasing rate) up to which every group's RMS error
    stays within ``limit_v``; None when the lowest does not."""
    passing = list(itertools.takewhile(lambda g: g.rms_v <= limit_v, groups))
    return passing[-1].rate_c if passing else None


def update_gate(
    groups_by_test: Sequence[tuple[str, Sequence[RateError]]],
    kinetic_c: float | None,
    bias_std_v: float,
) -> tuple[float | None, str]:
    """``update_c_rate_max`` and why (module docstring): from each pulse test's groups (with
    its label: the model must hold at every temperature it was identified at, so the lowest
    of their gates) and the rate tests' top step; None without either."""
    limit_v = GATE_ERROR_FACTOR * bias_std_v
    why = []
    gates = []
    for label, groups in groups_by_test:
        gate_c, text = pulse_gate(groups, limit_v)
        if gate_c is not None:
            gates.append(gate_c)
        why.append(f"{label}: {text}")
    pulse_c = min(gates) if gates else None
    reasons = (
        f"RMS error per pulse rate, the SoC imposed, within {GATE_ERROR_FACTOR:g} x bias_std_v "
        f"= {1000 * limit_v:.1f} mV: " + "; ".join(why)
    )
    if kinetic_c is not None:
        reasons += f"; the rate tests' kinetic fits cover steps up to {kinetic_c:.4g} C"
    top = max((c for c in (pulse_c, kinetic_c) if c is not None), default=None)
    if top is None:
        return None, "no fitted pulse at SoC >= limits.soc_min and no rate test"
    gate = floor_2_digits(top)
    return gate, reasons + f": {top:.4g} C, floored to {gate:g} C"


def current_bin_errors(
    sims: Sequence[Simulated],
    capacity_ah: float,
    soc_min: float,
    gate_c: float,
    charge_only: bool = False,
) -> list[RateError]:
    """The model's error per octave bin of the C-rate (``BIN_LOW_C`` 2^k), over every test,
    for the bins up to the one holding ``gate_c``, with ``MIN_BIN_S`` or more; of the charging
    samples alone with ``charge_only``."""
    top = math.floor(math.log2(gate_c / BIN_LOW_C)) if gate_c >= BIN_LOW_C else -1
    out = []
    for k in range(top + 1):
        lo, hi = BIN_LOW_C * 2.0**k, BIN_LOW_C * 2.0 ** (k + 1)
        parts = []
        for sim in sims:
            current = -sim.test.current_a if charge_only else np.abs(sim.test.current_a)
            c = current / capacity_ah
            parts.append((sim, np.flatnonzero((c >= lo) & (c < hi))))
        err = _rate_error(parts, soc_min, math.nan)
        if err is not None and err.seconds >= MIN_BIN_S:
            out.append(replace(err, rate_c=err.current_a / capacity_ah))
    return out


def charge_gate(
    sims: Sequence[Simulated], capacity_ah: float, soc_min: float, bias_std_v: float
) -> tuple[float | None, str]:
    """``update_charge_c_rate_max`` and why (module docstring): the charging samples' model
    error in the C-rate bins of ``r_per_a``; the highest bin's mean rate up to which every
    bin stays within ``GATE_ERROR_FACTOR`` times ``bias_std_v``, floored to two digits; 0 when
    even the lowest bin misses; None (the code default) when the tests hold no charge."""
    top_c = max(float(np.max(-s.test.current_a, initial=0.0)) for s in sims) / capacity_ah
    bins = current_bin_errors(sims, capacity_ah, soc_min, top_c, charge_only=True)
    if not bins:
        return None, f"no charge of {MIN_BIN_S:g} s or more above {BIN_LOW_C:g} C in the tests"
    limit_v = GATE_ERROR_FACTOR * bias_std_v
    table = ", ".join(f"{b.rate_c:.3g} C {1000 * b.rms_v:.1f} mV" for b in bins)
    top = highest_within(bins, limit_v)
    why = f"charging samples, RMS error per C-rate bin within {1000 * limit_v:.1f} mV: {table}"
    if top is None:
        return 0.0, why + ": none"
    return floor_2_digits(top), why + f": up to {top:.3g} C"


def current_dependent_error(
    bins: Sequence[RateError], r_v2: float, bias_std_v: float
) -> tuple[float | None, str]:
    """``r_per_a`` (V/A) and why (module docstring): the smallest value for which the error
    the hybrid assumes at each bin's mean current ``I``, ``r + bias_std_v^2 + (r_per_a I)^2``,
    covers the model's RMS error ``e`` there: the largest ``sqrt(e^2 - r - bias^2) / I``; None
    where ``r`` and the bias state cover every bin."""
    table = ", ".join(f"{b.rate_c:.3g} C {1000 * b.rms_v:.1f} mV" for b in bins)
    floor_v2 = r_v2 + bias_std_v**2
    excess = [
        (math.sqrt(b.rms_v**2 - floor_v2) / b.current_a, b) for b in bins if b.rms_v**2 > floor_v2
    ]
    covered = f"sqrt(r + bias_std_v^2) = {1000 * math.sqrt(floor_v2):.0f} mV"
    if not bins:
        return None, "no C-rate bin of the tests' loads up to the gate"
    if not excess:
        return None, f"the error per C-rate ({table}) stays within {covered}"
    value, at = max(excess, key=lambda e: e[0])
    return value, f"the error per C-rate ({table}) above {covered}, at worst at {at.rate_c:.3g} C"


def parse_given(items: Sequence[str]) -> dict[tuple[str, str], float | tuple[float, ...]]:
    """``BLOCK.KEY=VALUE`` entries (``--tuning``): a known estimator's (or preset's) entry and
    a number or a list of numbers (YAML)."""
    import yaml

    out: dict[tuple[str, str], float | tuple[float, ...]] = {}
    for item in items:
        name, sep, text = item.partition("=")
        block, dot, key = name.partition(".")
        if not sep or not dot or not block or not key:
            raise IdentificationError(f"--tuning {item!r}: expected BLOCK.KEY=VALUE")
        est = PRESETS.get(block, block)
        if est not in ESTIMATORS:
            known = ", ".join(sorted([*ESTIMATORS, *PRESETS]))
            raise IdentificationError(f"--tuning {item!r}: no estimator {block!r} ({known})")
        if key not in ESTIMATORS[est].default_tuning:
            known = ", ".join(sorted(ESTIMATORS[est].default_tuning))
            raise IdentificationError(f"--tuning {item!r}: {block} has no {key!r} ({known})")
        try:
            value = yaml.safe_load(text)
            if isinstance(value, list):
                out[(block, key)] = tuple(_number(v) for v in value)
            else:
                out[(block, key)] = _number(value)
        except (ValueError, yaml.YAMLError):
            raise IdentificationError(f"--tuning {item!r}: the value is not a number") from None
    return out


def _number(value: Any) -> float:
    """A YAML scalar as a float (YAML 1.1 reads ``1e-10`` as a string); ValueError if none."""
    if isinstance(value, bool) or not isinstance(value, int | float | str):
        raise ValueError(value)
    number = float(value)
    if not math.isfinite(number):
        raise ValueError(value)
    return number


def identified_tunings(
    battery: BatteryParams,
    reference: IdentificationResult,
    results: Sequence[IdentificationResult],
    tests: Sequence[tuple[BatterySeries, np.ndarray]],
    given: Mapping[tuple[str, str], float | tuple[float, ...]] | None = None,
) -> tuple[BatteryParams, list[TuningSource]]:
    """``battery`` (its ``filters`` the template's) with the filters this identification writes
    (module docstring) and where each entry comes from; noted on ``reference``.

    ``tests``: the reference temperature's tests, each from full with its counted SoC, the
    pulse test as fitted first (``reference.test``, whose ``reference.fitted`` windows the
    pulse groups are); ``results``: every temperature's (their rate tests' kinetic fits).
    """
    given = dict(given or {})
    notes = reference.notes
    sims = simulate(battery, tests)
    error = model_error(battery, list(tests), notes, [s.v_model for s in sims])
    default = Hybrid.default_tuning
    # The values the file will have (given, else measured or the template's, else the default).
    hybrid = {**default, **battery.filters.get("hybrid", {})}
    if error is not None:
        hybrid["bias_std_v"] = error.rms_v
    hybrid.update({key: value for (block, key), value in given.items() if block == "hybrid"})
    bias_v = float(hybrid["bias_std_v"])
    capacity = battery.capacity_ah
    soc_min = battery.limits.soc_min

    groups = [
        (
            _label(res),
            pulse_rate_errors(sim, res.fitted, capacity, soc_min),
        )
        for res, sim in _pulse_tests(battery, reference, sims[0], results)
    ]
    gate, gate_why = update_gate(groups, kinetic_top_c(results, capacity), bias_v)
    r_per_a, r_why = None, "no update gate derived"
    if gate is not None:
        bins = current_bin_errors(sims, capacity, soc_min, gate)
        r_per_a, r_why = current_dependent_error(bins, float(hybrid["r"]), bias_v)

    charge_c, charge_why = charge_gate(sims, capacity, soc_min, bias_v)
    derived: list[tuple[str, Any, str, str]] = [
        ("update_c_rate_max", gate, "derived", gate_why),
        ("update_charge_c_rate_max", charge_c, "derived", charge_why),
        ("r_per_a", r_per_a, "derived", r_why),
        (
            "bias_std_v",
            None if error is None else error.rms_v,
            "measured",
            "the model's RMS error from a load to the hybrid's rest (model_error.py)",
        ),
        ("bias_tau_s", None, "default", "not identified"),
        ("ocv_axis_std_frac", *ocv_axis_std(reference, float(hybrid["capacity_std_frac"]))),
        ("update_soc_min", None, "default", "a choice on recordings of the pack, not identified"),
    ]
    sources: list[TuningSource] = []
    written: dict[tuple[str, str], Any] = {}
    for block, entries in battery.filters.items():
        for key, value in entries.items():
            if key not in _MODEL_KEYS and (block, key) not in given:
                written[(block, key)] = value
                sources.append(TuningSource(block, key, value, "template", "model-independent"))
    for key, value, kind, why in derived:
        if ("hybrid", key) in given:
            continue
        if value is None:
            sources.append(TuningSource("hybrid", key, default[key], "default", why))
        else:
            written[("hybrid", key)] = value
            sources.append(TuningSource("hybrid", key, value, kind, why))
    from_tests = {("hybrid", key): (value, why) for key, value, _, why in derived}
    for (block, key), value in given.items():
        written[(block, key)] = value
        why = "--tuning"
        if (block, key) in from_tests:
            would, would_why = from_tests[(block, key)]
            shown = "the code default" if would is None else f"{would:.4g}"
            why += f" (from the tests: {shown}; {would_why})"
        sources.append(TuningSource(block, key, value, "given", why))
    kept = [f"{s.block}.{s.key}" for s in sources if s.source == "template"]
    if kept:
        notes.append(f"filters from the template (model-independent): {', '.join(kept)}")
    for s in sources:
        if s.source != "template":
            notes.append(f"filters.{s.block}.{s.key} = {_shown(s.value)} ({s.source}): {s.why}")
    # The gate's value from the tests is also the model's current envelope (a fact of these
    # tests, kept when the gate is given: the state of power reads it).
    thevenin = replace(battery.thevenin, fitted_c_rate_max=gate)
    filters = _in_template_order(battery.filters, written)
    return replace(battery, thevenin=thevenin, filters=filters), sources


def ocv_axis_std(
    reference: IdentificationResult, capacity_std_frac: float
) -> tuple[float | None, str, str]:
    """``hybrid.ocv_axis_std_frac``, its source and why: the OCV table's SoC axis is the
    charge from full over the file's capacity, so it is the identified pack's own only where
    that capacity was measured on it (None: the code default, 0); a given capacity (a
    rating) or the template's (another pack's) is off by as much as a pack differs from its
    kind, the guard's ``capacity_std_frac``."""
    if reference.capacity_measured:
        return None, "default", f"the capacity measured on this pack ({reference.capacity_source})"
    return (
        capacity_std_frac,
        "derived",
        f"the capacity ({reference.capacity_source}) not measured on this pack: the OCV's SoC "
        "axis within the pack-to-pack spread (capacity_std_frac)",
    )


def _label(res: IdentificationResult) -> str:
    temp = res.temperature_c
    return "the pulse test" if math.isnan(temp) else f"the {temp:.1f} degC pulse test"


def _pulse_tests(
    battery: BatteryParams,
    reference: IdentificationResult,
    reference_sim: Simulated,
    results: Sequence[IdentificationResult],
) -> list[tuple[IdentificationResult, Simulated]]:
    """Each temperature's pulse test (as fitted) with the model over it, the SoC imposed; the
    reference's already simulated. A test without a temperature sensor runs at its given
    temperature (``--temperature-c``)."""
    out = []
    for res in results:
        if res is reference:
            out.append((res, reference_sim))
            continue
        assert res.test is not None and res.soc_track is not None  # identify() sets both
        test = res.test
        if not math.isnan(res.temperature_c):
            temps = np.where(np.isnan(test.temperature_c), res.temperature_c, test.temperature_c)
            test = replace(test, temperature_c=temps)
        out.extend((res, sim) for sim in simulate(battery, [(test, res.soc_track)]))
    return out


def _shown(value: Any) -> str:
    if isinstance(value, tuple | list):
        return "[" + ", ".join(f"{v:.4g}" for v in value) + "]"
    return f"{value:.4g}"


def _in_template_order(
    template: Mapping[str, Mapping[str, Any]], written: Mapping[tuple[str, str], Any]
) -> dict[str, dict[str, Any]]:
    """The ``written`` entries as filter blocks: the template's blocks and keys in its order,
    new ones after them."""
    order = [(b, k) for b, entries in template.items() for k in entries]
    order += [bk for bk in written if bk not in order]
    filters: dict[str, dict[str, Any]] = {}
    for block, key in order:
        if (block, key) in written:
            filters.setdefault(block, {})[key] = written[(block, key)]
    return filters
