"""``soc_identify``: identify a battery parameter file from pulse-discharge tests.

    soc_identify INPUT [INPUT ...] --chemistry {li_ion,lfp,sla} [--capacity-ah X
                 [--capacity-measured]] [--slow-discharge INPUT2] [--temperature-c T [T ...]]
                 [--reference-capacity-ah Q] [--rate-test RATE [RATE ...]] [--load-test LOAD]
                 [--hysteresis-test HYST]
                 [--template FILE] [--tuning BLOCK.KEY=VALUE ...]
                 [--current-sign ...] [--topic T] --output params.yaml [--plot fit.png]

INPUT is a rosbag2 bag (the bridge's BatteryState topic) or a CSV
``time_s,current_a,voltage_v[,temperature_c][,soc_ref]``: a seed-000 pulse test, an HPPC or
pulse blocks with regen (see ``segment.py``). A test starts full, or at the rest after a
recharge it begins with. Several INPUTs are the same test at several temperatures (from each
test's temperature sensor, or ``--temperature-c`` in the same order): the 2-RC tables get a
temperature axis; the test nearest 25 degC gives the OCV, the capacity and the RC model.
With ``--rate-test`` (one rate test per INPUT, in the same order: steps from rest to several
currents at each SoC level), R0 becomes the ohmic part and the current-dependent overpotential
is added (``kinetics.py``). With ``--load-test`` (one, at the reference temperature: 10 % steps
at the robot's heavy load with long rests), its windows join the surface lag's fit (``surface.py``).
With ``--hysteresis-test`` (one, from full, with long rests after charges and after discharges)
the OCV's charge/discharge hysteresis is fitted (``hysteresis.py``); without it the file has
none, whatever the template holds.
Everything not identified (name, limits) comes from ``--template`` (default: the bundled file
of the chemistry), and so do the filter tunings that do not describe the model. Those that do
never come from the template (``tuning.py``): the hybrid's ``bias_std_v`` is the identified
model's own voltage error on the reference temperature's tests (``model_error.py``), its
voltage-update gate ``update_c_rate_max`` the highest C-rate the model was fitted at and its
``r_per_a`` what the model's error per current bin needs (else the code default). An entry
measured elsewhere (on field runs) is given with ``--tuning BLOCK.KEY=VALUE``; the report says
where each entry comes from.
"""

from __future__ import annotations

import argparse
import math
import shlex
import sys
from collections.abc import Mapping, Sequence
from dataclasses import replace
from pathlib import Path

import numpy as np

from ..errors import SocEstimatorError
from ..params import (
    BatteryParams,
    battery_params_to_dict,
    load_battery_params,
    output_dir_error,
    write_battery_file,
)
from ..recordings import add_recording_arguments, read_recording
from ..resources import BUNDLED_FILES, bundled_file
from ..series import BatterySeries
from ..units import CurrentSign
from .hysteresis import HysteresisFit, fit_hysteresis
from .identify import (
    IdentificationResult,
    counted,
    identify,
    over_temperature,
    test_temperature_c,
)
from .segment import IdentificationError
from .tuning import identified_tunings, parse_given


def load_test(
    path: Path, topic: str, sign: CurrentSign, reference_capacity_ah: float | None = None
) -> BatterySeries:
    """A pulse test or slow discharge: a bag (no reference topic needed) or a CSV file.

    ``reference_capacity_ah``: the capacity behind a CSV's ``soc_ref`` column (a tester's
    amp-hour counter); with it the charge is counted from the reference (logging gaps).
    A sample whose current or voltage is not a finite number is an error: the fits and the
    charge count need every one (the node and ``soc_replay`` reject and count such samples;
    a lab test is repaired or run again).
    """
    if not path.exists():
        raise IdentificationError(f"{path}: no such file or bag")
    series = read_recording(path, topic, sign, reference_topic=None)
    bad = ~(np.isfinite(series.current_a) & np.isfinite(series.voltage_v))
    if np.any(bad):
        first = int(np.argmax(bad))
        raise IdentificationError(
            f"{path}: {int(np.count_nonzero(bad))} sample(s) with a current or voltage that is "
            f"not a finite number, the first at t = {series.t_s[first]:g} s: the fits need "
            "every sample (repair the test or cut it there)"
        )
    if reference_capacity_ah is not None and series.soc_ref is not None:
        series = replace(series, reference_capacity_ah=reference_capacity_ah)
    return series


def identify_tests(
    tests: list[BatterySeries],
    temperatures_c: list[float] | None,
    template: BatteryParams,
    capacity_ah: float | None,
    slow: BatterySeries | None,
    progress,
    rate_tests: list[BatterySeries] | None = None,
    load_test: BatterySeries | None = None,
    tuning: Mapping[tuple[str, str], float | tuple[float, ...]] | None = None,
    capacity_measured: bool = False,
) -> tuple[BatteryParams, list[IdentificationResult]]:
    """One test, or one per temperature (see the module docstring); ``tuning``: filter entries
    given (``--tuning``), written as given; ``capacity_measured``: ``capacity_ah`` was measured
    on the pack, not a rating."""
    if temperatures_c is not None and len(temperatures_c) != len(tests):
        raise IdentificationError(
            f"--temperature-c gives {len(temperatures_c)} temperature(s) for {len(tests)} tests"
        )
    if rate_tests is not None and len(rate_tests) != len(tests):
        raise IdentificationError(
            f"--rate-test gives {len(rate_tests)} rate test(s) for {len(tests)} tests"
        )
    rates: Sequence[BatterySeries | None] = rate_tests or [None] * len(tests)
    temps: list[float] = []
    ref = 0  # the reference test: the one, or the one nearest 25 degC
    if len(tests) > 1:
        temps = temperatures_c or [test_temperature_c(t) for t in tests]
        if any(math.isnan(t) for t in temps):
            raise IdentificationError(
                "a test has no temperature sensor: give every test's temperature (--temperature-c)"
            )
        ref = int(np.argmin([abs(t - 25.0) for t in temps]))
    first = identify(
        tests[ref],
        template,
        capacity_ah,
        slow,
        progress,
        rates[ref],
        load_test=load_test,
        capacity_measured=capacity_measured,
    )
    if len(tests) == 1:
        if temperatures_c is not None:
            first.temperature_c = temperatures_c[0]
        battery = _with_tunings(
            first.battery, first, [first], rates[0], load_test, tuning, progress
        )
        return battery, [first]
    results: list[IdentificationResult] = []
    for n, test in enumerate(tests):
        if n == ref:
            res = first
        else:
            # The reference's capacity: a cold HPPC stops at the cut-off long before empty.
            res = identify(
                test,
                template,
                first.capacity_ah,
                None,
                progress,
                rates[n],
                shape_ocv=first.battery.ocv_curve(),
            )
            res.notes.append(f"capacity of the {temps[ref]:.1f} degC test used")
        res.temperature_c = temps[n]
        results.append(res)
    battery = over_temperature(results, ref)
    return _with_tunings(battery, first, results, rates[ref], load_test, tuning, progress), results


def _with_tunings(
    battery: BatteryParams,
    reference: IdentificationResult,
    results: list[IdentificationResult],
    rate_test: BatterySeries | None,
    load_test: BatterySeries | None,
    given: Mapping[tuple[str, str], float | tuple[float, ...]] | None,
    progress,
) -> BatteryParams:
    """``battery`` with the filters this identification writes (``tuning.py``): the model's
    own error measured on the reference temperature's tests (its pulse test as fitted, its rate
    test and the load test, both from full), the hybrid's gate and current-dependent error
    derived from them and ``results``' rate tests, the template's model-independent entries and
    the ``given`` ones; noted on ``reference``."""
    if progress:
        progress("model error and filter tunings over the reference temperature's tests")
    assert reference.test is not None and reference.soc_track is not None
    tests = [(reference.test, reference.soc_track)]
    for extra, label in ((rate_test, "rate test"), (load_test, "load test")):
        if extra is not None:
            # from_full's notes on these tests are already in the report (identify)
            tests.append(counted(extra, battery.capacity_ah, [], label))
    battery, _ = identified_tunings(battery, reference, results, tests, given)
    return battery


def report(result: IdentificationResult) -> str:
    """The per-pulse fit report (seed 000 Fig. 7 as a table)."""
    temp = "" if math.isnan(result.temperature_c) else f" (test at {result.temperature_c:.1f} degC)"
    lines = [
        f"capacity: {result.capacity_ah:.4f} Ah ({result.capacity_source}){temp}",
        f"{'pulse':>5} {'SoC':>6} {'R0_mohm':>8} {'R1_mohm':>8} {'tau1_s':>8} {'R2_mohm':>8} "
        f"{'tau2_s':>8} {'rmse_lin_mV':>11} {'rmse_mV':>8}",
    ]
    for n, f in enumerate(result.pulses, 1):
        lines.append(
            f"{n:>5} {f.soc:6.3f} {1000 * f.r0_ohm:8.2f} {1000 * f.r1_ohm:8.2f} {f.tau1_s:8.1f} "
            f"{1000 * f.r2_ohm:8.2f} {f.tau2_s:8.1f} {1000 * f.rmse_linear_v:11.2f} "
            f"{1000 * f.rmse_v:8.2f}"
        )
    rc = result.battery.rc_model
    tau_s = float(np.median([r.tau_s for r in result.rc]))
    lines.append(
        f"RC model: R_b = R_s = {1000 * rc.r_b_ohm:.2f} mohm, R_t = {1000 * rc.r_t_ohm:.2f} mohm, "
        f"C_s = {rc.c_s_f:.1f} F (tau_s median {tau_s:.2f} s), "
        f"C_b = {rc.c_b_f:.0f} F"
    )
    if result.kinetic:
        lines.append(
            f"{'rate level':>10} {'SoC':>6} {'R_mohm':>8} {'a_mV':>8} {'i0_A':>8} {'steps':>5} "
            f"{'rmse_mV':>8} {'i_sat_A':>8} {'end_rmse_mV':>11}"
        )
        for n, k in enumerate(result.kinetic, 1):
            sat = "-" if k.i_sat_a is None else f"{k.i_sat_a:.3f}"
            lines.append(
                f"{n:>10} {k.soc:6.3f} {1000 * k.r_ohm:8.2f} {1000 * k.a_v:8.1f} {k.i0_a:8.3f} "
                f"{len(k.steps):>5} {1000 * k.rmse_v:8.2f} {sat:>8} {1000 * k.end_rmse_v:11.2f}"
            )
    lines += [f"note: {n}" for n in result.notes]
    return "\n".join(lines)


def plot_fit(path: Path, test: BatterySeries, result: IdentificationResult) -> None:
    """Seed 000 Figs. 6-7: measured vs simulated voltage and the parameters over SoC."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from .identify import simulate_voltage

    sim = simulate_voltage(result.battery, result.test or test, 1.0, result.soc_track)
    test = result.test or test
    fig, axes = plt.subplots(3, 1, figsize=(10, 10))
    t_h = test.t_s / 3600.0
    axes[0].plot(t_h, test.voltage_v, "0.5", lw=0.8, label="measured")
    axes[0].plot(t_h, sim, "C0", lw=0.8, label="identified 2RC model")
    axes[0].set_xlabel("time (h)")
    axes[0].set_ylabel("voltage (V)")
    axes[0].legend()
    soc = [f.soc for f in result.pulses]
    for key, label in (("r0_ohm", "R0"), ("r1_ohm", "R1"), ("r2_ohm", "R2")):
        axes[1].plot(soc, [1000 * getattr(f, key) for f in result.pulses], "o-", label=label)
    axes[1].set_ylabel("resistance (mohm)")
    axes[1].set_xlabel("SoC")
    axes[1].legend()
    axes[2].semilogy(soc, [f.tau1_s for f in result.pulses], "o-", label="tau1")
    axes[2].semilogy(soc, [f.tau2_s for f in result.pulses], "o-", label="tau2")
    axes[2].set_ylabel("time constant (s)")
    axes[2].set_xlabel("SoC")
    axes[2].legend()
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def hysteresis_report(fit: HysteresisFit | None) -> str:
    """The report's line on the OCV hysteresis."""
    if fit is None:
        return "hysteresis: none (no --hysteresis-test)"
    rests = (
        f"{fit.rests_after_charge} rests after a charge, {fit.rests_after_discharge} after a "
        "discharge"
    )
    if fit.hysteresis is None:
        return f"hysteresis: none ({fit.why}; {rests})"
    h = fit.hysteresis
    return (
        f"hysteresis: gap {1000 * h.gap_v:.1f} mV (se {1000 * fit.gap_se_v:.1f}), rate "
        f"{h.rate_per_soc:.0f} per unit SoC; {rests}; residual at the rests' ends "
        f"{1000 * fit.rms_before_v:.1f} -> {1000 * fit.rms_after_v:.1f} mV RMS; the model's "
        f"OCV {1000 * fit.offset_v:+.1f} mV off both branches alike (not applied)"
    )


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="soc_identify", description=__doc__.splitlines()[0])
    ap.add_argument("input", type=Path, nargs="+", help="pulse test(s): rosbag2 bag or CSV")
    ap.add_argument("--chemistry", required=True, choices=sorted(BUNDLED_FILES))
    ap.add_argument("--capacity-ah", type=float, help="pack capacity (default: measured)")
    ap.add_argument(
        "--capacity-measured",
        action="store_true",
        help="--capacity-ah was measured on this pack (a C/20 discharge to the cut-off), not a "
        "rating: the OCV's SoC axis is the pack's own (no hybrid.ocv_axis_std_frac)",
    )
    ap.add_argument("--slow-discharge", type=Path, help="slow discharge (C/20) to the cut-off")
    ap.add_argument(
        "--temperature-c", type=float, nargs="+", help="each test's temperature, in order"
    )
    ap.add_argument(
        "--reference-capacity-ah",
        type=float,
        help="capacity behind a CSV's soc_ref column: count the charge from it",
    )
    ap.add_argument(
        "--rate-test",
        type=Path,
        nargs="+",
        help="rate test(s), one per INPUT in order: fits the current-dependent drop",
    )
    ap.add_argument(
        "--load-test",
        type=Path,
        help="load test (steps at a heavy load, long rests) at the reference temperature: "
        "its windows join the surface lag's fit (needs --rate-test: the heavy steps need the "
        "kinetic drop)",
    )
    ap.add_argument(
        "--hysteresis-test",
        type=Path,
        help="a test from full with long rests after charges and after discharges: fits the "
        "OCV's charge/discharge hysteresis (without it the file has none)",
    )
    ap.add_argument("--template", type=Path, help="file to take non-identified values from")
    ap.add_argument(
        "--tuning",
        nargs="+",
        metavar="BLOCK.KEY=VALUE",
        help="filter entries measured elsewhere (e.g. on field runs), written as given "
        'instead of what the tests give (docs/identification.md, "Filter tunings")',
    )
    add_recording_arguments(ap)
    ap.add_argument("--output", type=Path, required=True, help="parameter YAML to write")
    ap.add_argument("--plot", type=Path, help="PNG of the fits")
    return ap


def main(argv: list[str] | None = None) -> int:
    ap = build_parser()
    args = ap.parse_args(argv)
    if args.capacity_measured and args.capacity_ah is None:
        ap.error("--capacity-measured says how --capacity-ah was obtained: give --capacity-ah")
    sign = CurrentSign(args.current_sign)
    if (why := output_dir_error(args.output)) is not None:
        print(f"soc_identify: error: {why}", file=sys.stderr)
        return 2
    try:
        template = load_battery_params(args.template or bundled_file(args.chemistry))
        if template.chemistry != args.chemistry:
            raise IdentificationError(
                f"template {args.template} is {template.chemistry}, not {args.chemistry}"
            )
        tests = [
            load_test(path, args.topic, sign, args.reference_capacity_ah) for path in args.input
        ]
        slow = load_test(args.slow_discharge, args.topic, sign) if args.slow_discharge else None
        given = parse_given(args.tuning or [])
        rate_tests = (
            [load_test(path, args.topic, sign) for path in args.rate_test]
            if args.rate_test
            else None
        )
        battery, results = identify_tests(
            tests,
            args.temperature_c,
            template,
            args.capacity_ah,
            slow,
            progress=lambda msg: print(f"soc_identify: {msg}", file=sys.stderr, flush=True),
            rate_tests=rate_tests,
            load_test=load_test(args.load_test, args.topic, sign) if args.load_test else None,
            tuning=given,
            capacity_measured=args.capacity_measured,
        )
        hyst_fit = None
        if args.hysteresis_test:
            hyst_test = load_test(args.hysteresis_test, args.topic, sign)
            hyst_fit = fit_hysteresis(battery, hyst_test, results[0].notes)
        battery = replace(battery, hysteresis=None if hyst_fit is None else hyst_fit.hysteresis)
    except SocEstimatorError as exc:
        print(f"soc_identify: error: {exc}", file=sys.stderr)
        return 2
    for result in results:
        print(report(result))
    print(hysteresis_report(hyst_fit))
    command = shlex.join(["soc_identify", *(argv if argv is not None else sys.argv[1:])])
    inputs = [
        *args.input,
        *(args.rate_test or []),
        *([args.load_test] if args.load_test else []),
        *([args.hysteresis_test] if args.hysteresis_test else []),
    ]
    names = " and ".join(p.name for p in inputs)
    header = (
        f"# Generated by soc_identify from {names}"
        + (f" and {args.slow_discharge.name}" if args.slow_discharge else "")
        + f'.\n# Regenerate: {command}\n# Schema: README "Battery parameter files".\n'
    )
    data = battery_params_to_dict(battery)
    data["source"] = f"identified by soc_identify from {names}"
    try:  # a fit the battery files' rules refuse (a value no battery has) writes nothing
        write_battery_file(args.output, data, header)
    except (SocEstimatorError, OSError) as exc:
        print(f"soc_identify: error: {exc}", file=sys.stderr)
        return 2
    print(f"wrote {args.output}")
    if args.plot:
        assert results[0].test is not None  # identify() always sets it
        plot_fit(args.plot, results[0].test, results[0])
        print(f"plot: {args.plot}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
