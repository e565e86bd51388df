"""The filter tunings soc_identify writes follow from the tests it was given (tuning.py).

Issue 24, item 2: a file identified from a pulse test alone (a linear 2RC fitted at 0.2 C) kept
the template's 6 C voltage-update gate (and LFP's r_per_a), tuned for a model with the kinetic
drop fitted up to 6 C: the hybrid then read the field runs' 10-20 A bursts through a model that
is volts wrong there (measured by a user: SLA 12.7 % MAE).
"""

from __future__ import annotations

import math
from dataclasses import replace
from functools import cache
from pathlib import Path

import numpy as np
import pytest
from conftest import REPO_ROOT, bag_path

from soc_estimator_ros.estimators import make_estimator
from soc_estimator_ros.evaluation import accuracy, run_estimator
from soc_estimator_ros.identification.cli import main as identify_main
from soc_estimator_ros.identification.segment import IdentificationError
from soc_estimator_ros.identification.tuning import (
    MODEL_SPECIFIC,
    RateError,
    Simulated,
    charge_gate,
    current_dependent_error,
    floor_2_digits,
    parse_given,
    update_gate,
)
from soc_estimator_ros.params import load_battery_params
from soc_estimator_ros.recordings import read_battery_bag

TEMPLATES = {
    "sla": REPO_ROOT / "config" / "sla_12v5ah.yaml",
    "lfp": REPO_ROOT / "config" / "lfp_12v6ah.yaml",
}


def charged(currents_a, errors_v) -> Simulated:
    """A test at 1 Hz whose blocks of 60 s hold each current, the model off by each error."""
    current = np.repeat(np.asarray(currents_a, dtype=float), 60)
    error = np.repeat(np.asarray(errors_v, dtype=float), 60)
    n = current.size
    test = replace(read_battery_bag(bag_path("sla_pulse_test")), t_s=np.arange(n, dtype=float))
    test = replace(test, current_a=current, voltage_v=12.5 + error, stamp_ns=np.arange(n))
    return Simulated(test, np.full(n, 0.8), np.full(n, 12.5))


def test_the_charge_gate_is_derived_from_the_tests_charges_only() -> None:
    """5 Ah: charges at 0.5, 1 and 2 A (0.1, 0.2, 0.4 C; bins 0.075, 0.15, 0.3 C) with the model
    off by 2, 4 and 30 mV against a 2 x 10 mV limit: read up to the 1-A bin's mean rate; with
    every bin off, 0; a test with discharges only says nothing (None: the code default)."""
    sims = [charged([3.0, -0.5, -1.0, -2.0, 0.0], [0.0, 0.002, 0.004, 0.030, 0.0])]
    gate, why = charge_gate(sims, 5.0, 0.2, 0.010)
    assert gate == 0.2 and "up to 0.2 C" in why
    worse = [charged([-0.5, -1.0], [0.030, 0.030])]
    assert charge_gate(worse, 5.0, 0.2, 0.010)[0] == 0.0
    assert charge_gate([charged([3.0, 0.0], [0.05, 0.0])], 5.0, 0.2, 0.010)[0] is None


def rate(rate_c: float, rms_mv: float, capacity_ah: float = 5.0) -> RateError:
    return RateError(rate_c, rate_c * capacity_ah, rms_mv / 1000.0, 100.0)


def test_the_gate_is_the_highest_rate_the_model_holds_at() -> None:
    # Pulses at 0.5, 1, 2 and 4 C (an HPPC) with the NCR18650PF's errors at 25.8 degC, bias
    # 7.3 mV: the 4 C pulses miss by 26 mV, more than twice the bias state's std; 2 C holds.
    warm = [rate(0.523, 2.1), rate(1.05, 3.6), rate(2.092, 10.4), rate(4.18, 26.4)]
    gate, why = update_gate([("warm", warm)], None, 0.0073)
    assert gate == 2.0 and "up to 2.09 C" in why
    # Its 0.6 degC test holds at 0.5 C only: one gate serves both temperatures.
    cold = [rate(0.523, 13.2), rate(1.05, 29.7), rate(2.09, 45.0)]
    gate, why = update_gate([("warm", warm), ("cold", cold)], None, 0.0073)
    assert gate == 0.52 and "cold: " in why
    # A rate test's kinetic fit covers its top step, whatever the pulses' errors.
    gate, why = update_gate([("warm", warm)], 6.298, 0.0073)
    assert gate == 6.2 and "6.298 C" in why
    # A single rate that misses by more: still the rate the model was fitted at.
    gate, why = update_gate([("one", [rate(0.208, 50.0)])], None, 0.020)
    assert gate == 0.2 and "the lowest rate 0.208 C used" in why
    assert update_gate([("none", [])], None, 0.02)[0] is None
    # Floored, never rounded up past the fitted rate.
    assert [floor_2_digits(x) for x in (6.051, 6.298, 0.2086, 0.2006, 2.092, 12.7)] == [
        6.0,
        6.2,
        0.2,
        0.2,
        2.0,
        12.0,
    ]


def test_r_per_a_covers_the_error_where_r_and_the_bias_do_not() -> None:
    """The hybrid assumes r + bias^2 + (r_per_a I)^2 under load: r_per_a is the smallest value
    for which that covers the model's error in every current bin."""
    bins = [rate(0.2, 15.0), rate(1.0, 40.0), rate(6.0, 37.0)]
    value, why = current_dependent_error(bins, 0.05, 0.0204)  # the bundled files' r: 224 mV
    assert value is None and "stays within" in why  # the code default stays
    # With a one-cell r of (31.6 mV)^2 a 0.3 V error at 6 C (30 A) is not covered.
    bins.append(rate(4.0, 300.0))
    value, why = current_dependent_error(bins, 0.001, 0.0073)
    assert value == pytest.approx(math.sqrt(0.3**2 - 0.001 - 0.0073**2) / 20.0)
    assert "at worst at 4 C" in why
    assert current_dependent_error([], 0.05, 0.02)[0] is None


def test_given_tunings_are_checked() -> None:
    assert parse_given(["hybrid.r_per_a=0.1", "t2rc_ukf.q_diag=[1e-10, 1e-6, 1e-6]"]) == {
        ("hybrid", "r_per_a"): 0.1,
        ("t2rc_ukf", "q_diag"): (1e-10, 1e-6, 1e-6),
    }
    for bad, msg in (
        ("hybrid.r_per_a", "BLOCK.KEY=VALUE"),
        ("r_per_a=0.1", "BLOCK.KEY=VALUE"),
        ("nope.r=1", "no estimator 'nope'"),
        ("hybrid.nope=1", "hybrid has no 'nope'"),
        ("hybrid.r=high", "not a number"),
    ):
        with pytest.raises(IdentificationError, match=msg):
            parse_given([bad])


def highest_pulse_c(bag: Path, capacity_ah: float) -> float:
    """The pulse test's highest pulse rate, from the bag alone: each pulse's mean current (its
    samples above 0.5 A, a minute or longer) less the sensor's offset (the mean at rest), over
    ``capacity_ah``."""
    series = read_battery_bag(bag, reference_topic=None)
    i = series.current_a  # discharge positive
    offset = float(np.mean(i[np.abs(i) < 0.2]))
    edges = np.flatnonzero(np.diff(np.concatenate([[0], (i > 0.5).astype(int), [0]])))
    rates = [
        (float(np.mean(i[a:b])) - offset) / capacity_ah
        for a, b in zip(edges[::2], edges[1::2], strict=True)
        if series.t_s[b - 1] - series.t_s[a] > 60.0
    ]
    assert rates, "no pulse found"
    return max(rates)


@cache
def pulse_only(chem: str, tmp: Path) -> tuple[Path, str]:
    """``soc_identify <chem>_pulse_test --chemistry <chem>``: the file and the report."""
    import contextlib
    import io

    out = tmp / f"{chem}_pulse_only.yaml"
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        code = identify_main(
            [str(bag_path(f"{chem}_pulse_test")), "--chemistry", chem, "--output", str(out)]
        )
    assert code == 0
    return out, buf.getvalue()


@pytest.fixture(scope="module")
def tmp_module(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("tuning")


@pytest.mark.parametrize("chem", ["sla", "lfp"])
def test_a_pulse_test_alone_gets_the_tuning_of_its_model(chem: str, tmp_module: Path) -> None:
    """From the pulse test alone (0.2 C pulses, no rate test) the hybrid's gate is the pulses'
    rate, not the template's 6 C; r_per_a is not the template's (LFP: 0.1 V/A) unless derived;
    the file loads and builds the hybrid. Measured: gates 0.2 C (SLA, pulses 0.2006 C; LFP,
    0.2082 C), r_per_a the code default (one rate: no dependence on the current measured)."""
    path, report = pulse_only(chem, tmp_module)
    battery = load_battery_params(path)
    template = load_battery_params(TEMPLATES[chem])
    hybrid = battery.filters["hybrid"]
    top_c = highest_pulse_c(bag_path(f"{chem}_pulse_test"), battery.capacity_ah)
    assert 0.19 < top_c < 0.22, top_c  # the bags' 0.2 C pulses
    gate = hybrid["update_c_rate_max"]
    assert isinstance(gate, float)
    # At most the fitted rate; floored to two digits, so within 10 % of it.
    assert 0.9 * top_c <= gate <= top_c, (gate, top_c)
    # The same rate is the model's current envelope, which the state of power keeps to.
    assert battery.thevenin.fitted_c_rate_max == gate
    # What was copied before: the bundled file's gate, its rate tests' top step.
    assert template.filters["hybrid"]["update_c_rate_max"] >= 6.0
    notes = {
        key: line
        for line in report.splitlines()
        for key in ("update_c_rate_max", "r_per_a", "bias_std_v")
        if line.startswith(f"note: filters.hybrid.{key} =")
    }
    assert "(derived)" in notes["update_c_rate_max"]
    assert "(measured)" in notes["bias_std_v"]
    if "r_per_a" in hybrid:
        assert "(derived)" in notes["r_per_a"], notes["r_per_a"]
    else:
        assert "(default)" in notes["r_per_a"], notes["r_per_a"]
    if "r_per_a" in template.filters["hybrid"]:
        assert hybrid.get("r_per_a") != template.filters["hybrid"]["r_per_a"] or (
            "(derived)" in notes["r_per_a"]
        )
    # Every other entry is the template's, and the report says so.
    kept = next(line for line in report.splitlines() if "filters from the template" in line)
    for block, entries in template.filters.items():
        for key, value in entries.items():
            if key not in MODEL_SPECIFIC.get(block, {}):  # the gates, r_per_a, the bias std
                assert battery.filters[block][key] == value and f"{block}.{key}" in kept
    make_estimator("hybrid", battery, 1.0)  # the tuning is one the hybrid takes


def test_the_pulse_only_sla_file_tracks_the_field_run(tmp_module: Path) -> None:
    """The user's case: with the template's 6 C gate the hybrid on the pulse-test-only SLA file
    read the run's bursts through the linear model (measured 12.7 % MAE, max 29 %); with the
    derived 0.2 C gate it updates where that model holds. Measured: MAE 0.55 %, max 0.88 %
    (run 1, true start). Bounds: the issue's 1 % MAE and 3 % max."""
    path, _ = pulse_only("sla", tmp_module)
    battery = load_battery_params(path)
    series = read_battery_bag(bag_path("sla_field_run_1_full_rest"))
    est = make_estimator("hybrid", battery, float(series.soc_ref[0]), 0.1)
    out = run_estimator(est, series)
    acc = accuracy(out.t_s, out.soc, series.soc_ref, window_s=600.0)
    assert acc.mae <= 0.01 and acc.max_abs <= 0.03, (acc.mae, acc.max_abs)


def test_a_given_tuning_is_written_as_given(tmp_path: Path, capsys) -> None:
    """--tuning writes an entry measured elsewhere; the report says what the tests give."""
    out = tmp_path / "sla.yaml"
    pulse = str(bag_path("sla_pulse_test"))
    args = [pulse, "--chemistry", "sla", "--output", str(out)]
    given = ["hybrid.r_per_a=0.05", "t2rc_ukf.r=2", "hybrid.update_c_rate_max=3"]
    assert identify_main([*args, "--tuning", *given]) == 0
    report = capsys.readouterr().out
    battery = load_battery_params(out)
    assert battery.filters["hybrid"]["r_per_a"] == 0.05
    # A given gate is a tuning; the model's envelope stays what the 0.2 C pulses covered.
    assert battery.filters["hybrid"]["update_c_rate_max"] == 3.0
    assert battery.thevenin.fitted_c_rate_max == 0.2
    assert battery.filters["t2rc_ukf"] == {"r": 2.0}
    line = next(x for x in report.splitlines() if "filters.hybrid.r_per_a" in x)
    assert "(given)" in line and "from the tests: the code default" in line
    assert "--tuning hybrid.r_per_a=0.05" in out.read_text().splitlines()[1]
    assert identify_main([*args, "--tuning", "hybrid.nope=1"]) == 2
    assert "hybrid has no 'nope'" in capsys.readouterr().err
