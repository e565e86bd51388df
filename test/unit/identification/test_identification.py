"""soc_identify against known truth, its error paths, and on the physics-simulated bags.

The synthetic pulse test is made from KNOWN 2-RC Thevenin parameters with the package's own
model: that is fine here, it tests the identifier's recovery, not an estimator's accuracy.
"""

from __future__ import annotations

import shlex
from dataclasses import replace
from functools import cache
from pathlib import Path

import numpy as np
import pytest
import yaml
from conftest import REPO_ROOT, bag_path, load_benchmark

from soc_estimator_ros.identification.cli import main as identify_main
from soc_estimator_ros.identification.fit import fit_pulse
from soc_estimator_ros.identification.identify import (
    identify,
    offset_corrected,
    other_rest_points,
    simulate_voltage,
    voltage_rmse,
    with_model_error,
)
from soc_estimator_ros.identification.segment import IdentificationError, segment_pulses
from soc_estimator_ros.identification.surface import (
    TAU_BOUNDS_S,
    LagStage,
    LagWindow,
    fit_surface_lag,
    mode_path,
)
from soc_estimator_ros.identification.tuning import ocv_axis_std
from soc_estimator_ros.models import (
    OcvCurve,
    ParamTable,
    RcBranch,
    SurfaceLag,
    TheveninModel,
    TheveninParams,
)
from soc_estimator_ros.params import load_battery_params
from soc_estimator_ros.recordings import BatterySeries, read_battery_bag, read_recording

ROOT = REPO_ROOT
SLA = load_battery_params(ROOT / "config" / "sla_12v5ah.yaml")
TRUE = {"r0": 0.030, "r1": 0.012, "tau1": 25.0, "r2": 0.020, "tau2": 700.0}


SYNTHETIC_OCV = OcvCurve([0.0, 0.2, 0.5, 0.8, 1.0], [11.6, 11.9, 12.2, 12.5, 12.85])
# An OCV with LFP's bend leaving full: 450 mV over the first 1 % of SoC, 15 mV from a straight
# line over the first pulse's 3-min onset (the LFP bag's: 14.5 mV).
KNEE_OCV = OcvCurve(
    [0.0, 0.2, 0.5, 0.8, 0.96, 0.98, 1.0], [11.6, 11.9, 12.2, 12.5, 12.58, 12.7, 13.4]
)


def synthetic_thevenin() -> TheveninParams:
    """The known 2-RC parameters ``TRUE``, constant over SoC."""
    return TheveninParams(
        ParamTable.constant(TRUE["r0"]),
        (
            RcBranch(
                ParamTable.constant(TRUE["r1"]), ParamTable.constant(TRUE["tau1"] / TRUE["r1"])
            ),
            RcBranch(
                ParamTable.constant(TRUE["r2"]), ParamTable.constant(TRUE["tau2"] / TRUE["r2"])
            ),
        ),
    )


def synthetic_pulse_test(
    seed: int = 0,
    noise: bool = True,
    ocv: OcvCurve = SYNTHETIC_OCV,
    lag: SurfaceLag | None = None,
) -> BatterySeries:
    """Seed 000 protocol at 10 Hz: 10 min rest, six 30-min 1 A pulses with 1-h rests."""
    rng = np.random.default_rng(seed)
    model = TheveninModel(ocv, replace(synthetic_thevenin(), surface_lag=lag), capacity_ah=5.0)
    segments = [(600.0, 0.0)] + [(1800.0, 1.0), (3600.0, 0.0)] * 6
    current = np.concatenate([np.full(int(d * 10), i) for d, i in segments])
    t = np.arange(current.size) * 0.1
    v = np.empty(current.size)
    x = model.rested_state(1.0)
    z = model.surface_rest()
    for k in range(current.size):
        if k:
            z = model.surface_step(z, current[k - 1], 0.1, x[0])
            x = model.step(x, current[k - 1], 0.1)
        v[k] = model.terminal_voltage(x, current[k], None, sum(z))
    i_meas = current
    if noise:
        # Sensor noise like the bags' (no gain error: a gain error biases every resistance
        # by the same fraction, which no identification can see).
        i_meas = np.round((current + rng.normal(0, 0.01, current.size)) / 0.01) * 0.01
        v = np.round((v + rng.normal(0, 0.002, v.size)) / (16 / 4096)) * (16 / 4096)
    return BatterySeries(
        t_s=t,
        stamp_ns=(t * 1e9).astype(np.int64),
        current_a=i_meas,
        voltage_v=v,
        temperature_c=np.full(t.size, 25.0),
    )


def synthetic_slow_discharge(ocv: OcvCurve, lag: SurfaceLag | None = None) -> BatterySeries:
    """C/20 at 1 Hz from full to 10 % with the same model: the OCV's shape between the rests
    (as the LFP bag's slow discharge gives the knee's)."""
    model = TheveninModel(ocv, replace(synthetic_thevenin(), surface_lag=lag), capacity_ah=5.0)
    n = int(0.9 * 20 * 3600)
    t = np.arange(n, dtype=float)
    current = np.full(n, 0.25)
    current[:600] = 0.0  # a 10-min rest first
    v = np.empty(n)
    x = model.rested_state(1.0)
    z = model.surface_rest()
    for k in range(n):
        if k:
            z = model.surface_step(z, current[k - 1], 1.0, x[0])
            x = model.step(x, current[k - 1], 1.0)
        v[k] = model.terminal_voltage(x, current[k], None, sum(z))
    return BatterySeries(
        t_s=t,
        stamp_ns=(t * 1e9).astype(np.int64),
        current_a=current,
        voltage_v=v,
        temperature_c=np.full(n, 25.0),
    )


@cache
def synthetic_result(seed: int = 0, noise: bool = True):
    return identify(synthetic_pulse_test(seed, noise), SLA, capacity_ah=5.0)


FIELDS = {"r0": "r0_ohm", "r1": "r1_ohm", "tau1": "tau1_s", "r2": "r2_ohm", "tau2": "tau2_s"}
BOUND = {"r0": 0.02, "r1": 0.02, "r2": 0.02, "tau1": 0.05, "tau2": 0.05}  # the bounds


def test_recovers_known_parameters_exactly_without_noise() -> None:
    res = synthetic_result(noise=False)
    assert len(res.pulses) == 6
    for f in res.pulses:
        for key, attr in FIELDS.items():
            # Noise-free, only the OCV curvature inside the 3-min onset window is unmodelled:
            # 0.5 %, four times tighter than the issue asks.
            assert getattr(f, attr) == pytest.approx(TRUE[key], rel=5e-3), (key, f)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_recovers_known_parameters_with_sensor_noise(seed: int) -> None:
    """Bag-like sensors (2 mV noise + 3.9 mV ADC steps, 10 mA current noise). R0 and the slow
    branch meet the issue's bounds pulse by pulse. The fast branch (12 mV that relaxes in 25 s)
    is noise-limited per pulse: about 2 % (R1) and 4 % (tau1) standard deviation, measured over
    18 pulses; it meets the bounds averaged over the test's six pulses (same true values)."""
    res = synthetic_result(seed)
    for f in res.pulses:
        for key in ("r0", "r2", "tau2"):
            assert getattr(f, FIELDS[key]) == pytest.approx(TRUE[key], rel=BOUND[key]), (key, f)
        assert f.rmse_v < 0.003  # the fit's residual is the sensor noise (about 2.3 mV)
    for key in ("r1", "tau1"):
        mean = float(np.mean([getattr(f, FIELDS[key]) for f in res.pulses]))
        assert mean == pytest.approx(TRUE[key], rel=BOUND[key]), key


def test_a_pulse_whose_onset_crosses_a_bend_of_the_ocv_is_fitted_on_its_end() -> None:
    """LFP leaving full: the OCV along the first pulse's onset is no straight line, and a fit
    that takes it for one puts the bend into R0 and the fast branch. Noise-free, so that the
    only error is the window's."""
    series = synthetic_pulse_test(noise=False, ocv=KNEE_OCV)
    res = identify(series, SLA, capacity_ah=5.0, slow=synthetic_slow_discharge(KNEE_OCV))
    bent = [n for n in res.notes if "bends" in n]
    assert len(bent) == 1 and "at SoC 1.00" in bent[0], res.notes  # the first pulse only
    first = min(res.pulses, key=lambda f: abs(f.soc - 0.9))
    # Labelled where its window and the relaxation after it are: the pulse's last 3 min end
    # at SoC 0.90 (1 A over 30 min of 5 Ah) and start 1 % above.
    assert first.soc == pytest.approx(0.905, abs=0.002)
    for key in ("r0", "r1", "r2", "tau2"):
        # The bounds (the onset-window fits of the other pulses meet 0.5 %, above).
        assert getattr(first, FIELDS[key]) == pytest.approx(TRUE[key], rel=BOUND[key]), key
    # Why: the same pulse fitted on its onset takes the bend for resistance (measured: R0
    # +12 %, R1 +65 %; asserted: each beyond the 2 % by half of that).
    pulse = segment_pulses(series)[0]
    soc_at = 1.0 - np.concatenate(
        [[0.0], np.cumsum(series.current_a[:-1] * np.diff(series.t_s))]
    ) / (3600.0 * 5.0)
    onset = fit_pulse(series, pulse, soc_at)
    assert onset.r0_ohm > 1.06 * TRUE["r0"] and onset.r1_ohm > 1.3 * TRUE["r1"], onset
    # Without a lag in the data the fitted one is small: measured 3.9e-4 SoC per ampere (what
    # the window's other fits leave at the bend), asserted below a quarter of the LFP bag's
    # fitted fast mode, 3.8e-3 (no slower mode kept).
    lag = res.battery.thevenin.surface_lag
    assert lag is None or (lag.n_modes == 1 and lag.gain_soc_per_a[0] < 1e-3), lag


def test_the_surface_lag_is_found_on_the_pulse_that_crosses_the_bend() -> None:
    """The same test with a known surface lag (g 0.004 SoC/A, tau 60 s: the LFP bag's order)
    in the data, the slow discharge's too: the fit finds it back, and the model with it
    follows the whole test."""
    true = SurfaceLag(gain_soc_per_a=(0.004,), tau_s=(60.0,), soc_max=(1.0,))
    series = synthetic_pulse_test(noise=False, ocv=KNEE_OCV, lag=true)
    res = identify(series, SLA, capacity_ah=5.0, slow=synthetic_slow_discharge(KNEE_OCV, true))
    lag = res.battery.thevenin.surface_lag
    assert any(n.startswith("surface lag: ") for n in res.notes), res.notes
    # Tolerances: what the window's other parameters (fitted first, each within the issue's
    # 2 % / 5 %) and the slow discharge's own lag in the OCV table leave. Measured: g -5 %,
    # tau -23 % (tau -12 %, g +6 % with a slow discharge free of the lag): tau trades against the
    # fast branch's 25 s over the same minutes.
    assert lag.n_modes == 1, lag  # a second mode is not worth MODE_GAIN of the RMSE
    assert lag.gain_soc_per_a == pytest.approx(true.gain_soc_per_a, rel=0.10), lag
    assert lag.tau_s == pytest.approx(true.tau_s, rel=0.30), lag
    without = replace(res.battery, thevenin=replace(res.battery.thevenin, surface_lag=None))
    with_lag_v, without_v = (voltage_rmse(b, series, 1.0) for b in (res.battery, without))
    assert with_lag_v < 0.5 * without_v, (with_lag_v, without_v)


# An OCV with a knee near full and a bend at 0.4 (LFP's cathode knee and a graphite stage).
BENT_OCV = OcvCurve(
    [0.0, 0.2, 0.35, 0.4, 0.45, 0.6, 0.9, 0.97, 1.0],
    [12.0, 12.6, 12.8, 12.95, 13.05, 13.08, 13.2, 13.3, 13.8],
)


def lag_window(
    soc0: float, current_a: float, pulse_s: float, modes, ocv: OcvCurve = BENT_OCV
) -> LagWindow:
    """A window on the fit's 1-s grid (10 min rest, the pulse, 1 h rest) of a 5 Ah pack whose
    model is exact but for the lag: v0 = OCV(SoC), measured = OCV(SoC - z)."""
    current = np.concatenate([np.zeros(600), np.full(int(pulse_s), current_a), np.zeros(3600)])
    soc = soc0 - np.concatenate([[0.0], np.cumsum(current[:-1])]) / (3600.0 * 5.0)
    z = sum((mode_path(current, soc, *m) for m in modes), np.zeros(soc.size))
    return LagWindow(current, ocv.ocv_array(soc - z), ocv.ocv_array(soc), soc)


def test_the_surface_lag_modes_come_back_stage_by_stage() -> None:
    """Two modes, the knee's (everywhere) and a slower one driven below 0.9 only: fitted in
    stages, the knee's on the 0.2 C pulse from full, the second on 3 C steps below the knee
    with the first held, each comes back; the fit's model is the data's, so the bound is the
    optimizer's tolerance (measured within 1e-4 relative)."""
    true = [(0.004, 15.0, 1.0), (0.008, 60.0, 0.9)]
    knee = [lag_window(1.0, 1.0, 1800.0, true)]
    below = [lag_window(soc0, 15.0, 120.0, true) for soc0 in (0.9, 0.5, 0.43, 0.37)]
    fit = fit_surface_lag(BENT_OCV, [LagStage(knee), LagStage(below, soc_max=0.9)])
    assert fit.kept == (True, True), fit
    lag = fit.lag
    assert lag.gain_soc_per_a == pytest.approx((0.004, 0.008), rel=1e-3)
    assert lag.tau_s == pytest.approx((15.0, 60.0), rel=1e-3)
    assert lag.soc_max == (1.0, 0.9)
    for without, with_mode in fit.rmse_v:
        assert with_mode < 1e-4 < without  # V: exact with the modes, mV off without


def test_a_lag_mode_is_kept_only_where_it_pays() -> None:
    """A stage without windows gets no mode; a lag the data do not hold is not kept (< 10 %
    off); one slower than TAU_BOUNDS_S (the fit ends at the bound) is not kept either."""
    plain = [lag_window(soc0, 15.0, 120.0, []) for soc0 in (0.5, 0.43)]
    fit = fit_surface_lag(BENT_OCV, [LagStage([]), LagStage(plain)])
    assert fit.lag is None and fit.kept == (False, False), fit
    assert np.isnan(fit.rmse_v[0][0])
    slow = [(0.01, 3.0 * TAU_BOUNDS_S[1], 1.0)]
    windows = [lag_window(soc0, 15.0, 120.0, slow) for soc0 in (0.5, 0.43)]
    fit = fit_surface_lag(BENT_OCV, [LagStage(windows)])
    assert fit.lag is None and fit.kept == (False,), fit
    assert fit.rmse_v[0][1] < 0.9 * fit.rmse_v[0][0]  # it would pay: the bound is what refuses


def since_load_s(test: BatterySeries) -> np.ndarray:
    """Seconds since the test's last loaded sample (inf before its first)."""
    loaded = np.where(test.current_a > 0.5, test.t_s, -np.inf)
    return test.t_s - np.maximum.accumulate(loaded)


def test_model_error_is_measured_where_the_hybrid_bias_applies() -> None:
    """bias_std_v is the model's RMS error from a load until the hybrid's 20-min rest: an error
    of 15 mV there and 50 mV in the long rests (and before the first pulse) gives 15 mV."""
    res = synthetic_result(noise=False)  # the model identified from this test: near exact
    since = since_load_s(res.test)
    # The rest test low-passes the current over 5 s: a 1 A step is light 11.5 s after it ends.
    error_v = np.where(since <= 1200.0, 0.015, 0.050)
    assert np.any(since > 1250.0) and np.all(error_v[since > 1250.0] == 0.050)
    test = replace(res.test, voltage_v=res.test.voltage_v + error_v)
    notes: list[str] = []
    battery = with_model_error(res.battery, [(test, res.soc_track)], notes)
    # 15 mV with the fit's own residual (0.8 mV RMS, below) in quadrature and a few seconds of
    # the 50 mV within the 11.5 s of the low-pass: measured 15.7 mV; bound 1 mV.
    assert battery.filters["hybrid"]["bias_std_v"] == pytest.approx(0.015, abs=0.001)
    assert "mV RMS (filters.hybrid.bias_std_v)" in notes[0]
    # The other tunings are the template's.
    rest = {k: v for k, v in battery.filters["hybrid"].items() if k != "bias_std_v"}
    assert rest == {k: v for k, v in SLA.filters["hybrid"].items() if k != "bias_std_v"}


def test_model_error_without_loads_leaves_the_code_default() -> None:
    """Not the template's value: that is another model's error (tuning.py)."""
    res = synthetic_result(noise=False)
    rest = res.test.window(0, 5000)  # the first 500 s: the rest before the first pulse
    assert not np.any(rest.current_a > 0.0)
    assert "bias_std_v" in res.battery.filters["hybrid"]  # the template's
    notes: list[str] = []
    battery = with_model_error(res.battery, [(rest, res.soc_track[:5000])], notes)
    hybrid = dict(res.battery.filters["hybrid"])
    del hybrid["bias_std_v"]
    assert battery.filters == {**res.battery.filters, "hybrid": hybrid}
    assert "fewer than 600" in notes[0] and "left at the code default (60 mV)" in notes[0]


def test_ocv_points_from_rests_and_rc_model() -> None:
    res = synthetic_result()
    curve = res.battery.ocv_curve()
    # The rest before each pulse is 1 h after the previous one: relaxed to within ~1 mV.
    for soc in (0.9, 0.7, 0.5):
        truth = SYNTHETIC_OCV.ocv(soc)
        assert curve.ocv(soc) == pytest.approx(truth, abs=0.01)
    rc = res.battery.rc_model
    assert rc.r_b_ohm == pytest.approx(rc.r_s_ohm)  # eq. 7
    assert rc.r_t_ohm == pytest.approx(rc.r_b_ohm / 0.75 - rc.r_b_ohm / 2)  # eq. 8


def test_errors_are_clear() -> None:
    good = synthetic_pulse_test(noise=False)
    flat = BatterySeries(
        good.t_s, good.stamp_ns, good.current_a * 0.0, good.voltage_v, good.temperature_c
    )
    with pytest.raises(IdentificationError, match="no pulses"):
        segment_pulses(flat)
    charge = BatterySeries(
        good.t_s, good.stamp_ns, -good.current_a, good.voltage_v, good.temperature_c
    )
    with pytest.raises(IdentificationError, match="wrong current sign"):
        segment_pulses(charge)
    n = 100
    short = BatterySeries(
        good.t_s[:n],
        good.stamp_ns[:n],
        good.current_a[:n],
        good.voltage_v[:n],
        good.temperature_c[:n],
    )
    with pytest.raises(IdentificationError, match="too short"):
        segment_pulses(short)
    k = 6000 + 18000 + 100  # cut inside the first rest: no 10-minute rest after any pulse
    cut = BatterySeries(
        good.t_s[6000:k],
        good.stamp_ns[6000:k],
        good.current_a[6000:k],
        good.voltage_v[6000:k],
        good.temperature_c[6000:k],
    )
    with pytest.raises(IdentificationError, match="rest"):
        segment_pulses(cut)


def test_cli_on_csv_with_sign_flag(tmp_path: Path, capsys) -> None:
    test = synthetic_pulse_test(noise=False)
    csv_path = tmp_path / "pulse.csv"
    rows = ["time_s,current_a,voltage_v,temperature_c"] + [
        f"{t:.1f},{-i:.4f},{v:.5f},25.0"  # charge-positive logger: discharge is negative
        for t, i, v in zip(test.t_s, test.current_a, test.voltage_v, strict=True)
    ]
    csv_path.write_text("\n".join(rows) + "\n")
    out = tmp_path / "p.yaml"
    assert (
        identify_main(
            [
                str(csv_path),
                "--chemistry",
                "sla",
                "--capacity-ah",
                "5",
                "--current-sign",
                "charge_positive",
                "--output",
                str(out),
            ]
        )
        == 0
    )
    params = load_battery_params(out)
    # The template's tunings pass through unchanged but the hybrid's, which describe the model
    # (tuning.py): bias_std_v, the model's own error (model_error.py), on a noise-free test made
    # by a 2RC only the fits' residual (measured 0.8 mV; bound 2 mV, below the 2.3 mV sensor
    # noise the noisy fits are held to); the voltage-update gate, the pulses' 1 A over 5 Ah (the
    # template's 6 C is its rate tests'); r_per_a the code default (one rate); the OCV axis'
    # std, the capacity being given (a rating), the guard's capacity spread (the code
    # default's 3 %: the template does not set it). The template's other hybrid entries
    # (soc_tune's, docs/tuning.md) pass through.
    hybrid = dict(params.filters["hybrid"])
    assert 0.0 < hybrid.pop("bias_std_v") < 0.002
    derived = ("bias_std_v", "update_c_rate_max", "r_per_a", "ocv_axis_std_frac")
    kept = {k: v for k, v in SLA.filters["hybrid"].items() if k not in derived}
    assert "capacity_std_frac" not in SLA.filters["hybrid"]
    assert kept and hybrid == {**kept, "update_c_rate_max": 0.2, "ocv_axis_std_frac": 0.03}
    assert SLA.filters["hybrid"]["update_c_rate_max"] == 6.0
    assert {k: v for k, v in params.filters.items() if k != "hybrid"} == {
        k: v for k, v in SLA.filters.items() if k != "hybrid"
    }
    assert params.capacity_ah == pytest.approx(5.0)
    assert "pulse" in capsys.readouterr().out
    # Without the flag the pulses look like charge: a one-line error, exit code 2.
    assert identify_main([str(csv_path), "--chemistry", "sla", "--output", str(out)]) == 2
    assert "wrong current sign" in capsys.readouterr().err
    # An output that cannot be written: one line before any fit, exit code 2, no traceback.
    flags = ["--chemistry", "sla", "--capacity-ah", "5", "--current-sign", "charge_positive"]
    nowhere = str(tmp_path / "missing" / "p.yaml")
    assert identify_main([str(csv_path), *flags, "--output", nowhere]) == 2
    err = capsys.readouterr().err
    assert err.startswith("soc_identify: error: no directory") and err.count("\n") == 1
    # A block of NaN voltages (a logger's dropout) raised a ValueError from the OCV table, or
    # wrote bias_std_v = nan: now one line naming the first such sample, before any fit.
    rows[2000:2100] = [",".join([*r.split(",")[:2], "nan", "25.0"]) for r in rows[2000:2100]]
    csv_path.write_text("\n".join(rows) + "\n")
    assert identify_main([str(csv_path), *flags, "--output", str(out)]) == 2
    err = capsys.readouterr().err
    assert "100 sample(s)" in err and "not a finite number" in err and err.count("\n") == 1


# -- on the physics-simulated bags ------------------------------------------------------------
BAGS = ROOT / "bags"
#: The checkout's bundled file of each chemistry the bags cover (the template, or the result).
BUNDLED = {"sla": ROOT / "config" / "sla_12v5ah.yaml", "lfp": ROOT / "config" / "lfp_12v6ah.yaml"}


@cache
def bag_identification(chem: str):
    pulse = BAGS / f"{chem}_pulse_test"
    slow = BAGS / f"{chem}_slow_discharge"
    template = load_battery_params(BUNDLED[chem])
    # As soc_identify reads them: a robot owner's pulse test has no reference SoC.
    return identify(
        read_battery_bag(pulse, reference_topic=None),
        template,
        slow=read_battery_bag(slow, reference_topic=None),
    )


# Measured with the identified files (docs/identification.md): the pulse tests' RMSE is
# SLA 9.6 mV, LFP 8.2 mV identified from the pulse test alone (24.9 mV before the knee pulse's
# end fit and the surface lag; 12.1 mV with the bundled file, made with the rate and load tests
# too). The
# issue's bounds stay as they are; where they are not met the test is a strict xfail carrying
# the numbers, so it flags the day they are met.
FIELD_XFAIL = {
    "lfp": "LFP field runs: 41 / 40 / 46 mV RMSE > 30 mV (26 / 17 / 25 above SoC 0.45). The "
    "graphite's slow diffusion: tables that follow one run give another 22-26 mV but miss the "
    "load test by 69 mV, those of the lab tests give the runs 44-66 mV "
    "(benchmarks/studies/table_transfer.py), and with the graphite 10x faster the same "
    "identification gives the runs 27.7 / 16.5 / 22.7 mV (docs/identification.md)"
}


def bundled_identification(chem: str):
    """Everything soc_identify can use from the bundled bags (the pulse test and rate test at
    each temperature recorded, 25 and 5 degC, the slow discharge and the load test where there
    is one, LFP): the bundled file, which test_bundled_files_are_the_identified_ones holds to be
    what its soc_identify command writes from those bags (the same voltage along every input
    test). Read rather than identified again here: the identification costs 5-7 s a file."""
    return load_battery_params(BUNDLED[chem])


@pytest.mark.parametrize(
    "chem",
    [
        "sla",
        "lfp",
    ],
)
def test_identified_model_reproduces_the_pulse_test(chem: str) -> None:
    if not (BAGS / f"{chem}_pulse_test").exists():
        pytest.skip(f"no {chem} pulse-test bag")
    res = bag_identification(chem)
    # The model runs open loop from the full pack on the current with the offset the test's
    # own rests measured (as the identification does): 25 mA over 12 h is 5 % of SoC.
    pulse = offset_corrected(read_battery_bag(BAGS / f"{chem}_pulse_test"), [], "pulse test")
    assert voltage_rmse(res.battery, pulse, 1.0) <= 0.015  # issue bound: 15 mV


@pytest.mark.parametrize(
    "chem",
    [
        "sla",
        pytest.param("lfp", marks=pytest.mark.xfail(strict=True, reason=FIELD_XFAIL["lfp"])),
    ],
)
def test_identified_model_reproduces_the_field_runs(chem: str) -> None:
    """Measured, open loop from the true SoC: SLA 20.6 / 26.4 / 23.6 mV (the Butler-Volmer drop
    and the fastest branch's saturation from the rate tests, tables at 25 and 5 degC)."""
    runs = sorted(BAGS.glob(f"{chem}_field_run_*"))
    if not runs:
        pytest.skip(f"no {chem} field runs")
    battery = bundled_identification(chem)
    for run in runs:
        series = read_battery_bag(run)
        rmse = voltage_rmse(battery, series, float(series.soc_ref[0]))
        assert rmse <= 0.030, (run.name, rmse)  # issue bound: 30 mV, open loop from true SoC


def test_the_table_transfer_benchmark_runs_the_files_model() -> None:
    """benchmarks/studies/table_transfer.py (docs/identification.md: why the LFP field runs stay
    near 40 mV) fits factors on the file's tables through its own copy of the model's recursion.
    With every factor at 1 it must be the file's model with the SoC imposed at every sample
    (``simulate_voltage(..., gap_s=-1)``) to rounding: on the cold run's first 5 minutes, which
    blend the tables' 5 and 25 degC rows at a noisy sensor temperature and go through the LFP
    file's kinetics, saturating branch and lag. And its fit must find the factors from a voltage
    the same model made with other ones (at the SoC point the window reaches: x1.5 and x0.7)."""
    transfer = load_benchmark("studies/table_transfer")
    lfp = load_battery_params(ROOT / "config" / "lfp_12v6ah.yaml")
    series = read_battery_bag(bag_path("lfp_field_run_3_cold")).window(0, 3000)
    prep = transfer.prepare(lfp, series, "cold run, 5 min")
    ones = np.zeros(transfer.n_factors(prep))
    model_v = simulate_voltage(lfp, series, float(series.soc_ref[0]), series.soc_ref, gap_s=-1)
    assert np.max(np.abs(transfer.simulate(prep, ones) - model_v)) < 1e-9  # volts
    assert np.ptp(series.temperature_c) > 0.5 and np.ptp(series.current_a) > 10.0

    reached = prep.tables["r0"].any(axis=0)  # the SoC points the window's SoC weighs
    truth = np.zeros((len(transfer.TABLES), reached.size))
    truth[:, reached] = np.log([[1.5], [0.7], [1.5], [0.7], [1.5]])
    made = replace(prep, voltage_v=transfer.simulate(prep, truth.ravel()))
    fitted = transfer.fit([made])
    before_mv, after_mv = transfer.rmse_mv(made, ones), transfer.rmse_mv(made, fitted)
    # Measured: 7.96 mV -> 0.0008 mV, the factors back within 0.15 % (R2 and C2 the farthest:
    # their branch's 154 s is half the window). Bounds: a twentieth of the ADC's 2 mV step,
    # and 1 % on the factors.
    assert before_mv > 5.0 and after_mv < 0.1, (before_mv, after_mv)
    got = np.exp(fitted.reshape(truth.shape)[:, reached])
    assert np.allclose(got, np.exp(truth[:, reached]), rtol=0.01), got


@pytest.mark.parametrize("chem", ["sla", "lfp"])
def test_why_the_field_runs_miss_the_voltage(chem: str) -> None:
    """The 2RC identified at 0.2 C over-predicts the drop under heavy load: its error is small
    where it was identified and grows with the current (Butler-Volmer kinetics are sub-linear
    in current; the linear R0 + RC branches are not)."""
    res = bag_identification(chem)
    for run in sorted(BAGS.glob(f"{chem}_field_run_*")):
        series = read_battery_bag(run)
        resid = series.voltage_v - simulate_voltage(res.battery, series, float(series.soc_ref[0]))
        light = np.abs(series.current_a) <= 0.25 * res.battery.capacity_ah
        heavy = series.current_a > 10.0
        # Measured: light-load RMSE 17-23 mV (SLA), 36-60 mV (LFP); heavy-load mean residual
        # +1.2..+1.9 V (SLA), +0.39..+0.54 V (LFP). Bounds: twice the light-load value, half
        # the heavy-load one.
        light_rmse = float(np.sqrt(np.mean(resid[light] ** 2)))
        heavy_mean = float(np.mean(resid[heavy]))
        assert light_rmse <= (0.050 if chem == "sla" else 0.120), (run.name, light_rmse)
        assert heavy_mean >= (0.6 if chem == "sla" else 0.19), (run.name, heavy_mean)
        assert heavy_mean > 5.0 * light_rmse, (run.name, heavy_mean, light_rmse)


@cache
def bag_identification_with_rates(chem: str):
    """The pulse test and slow discharge as above, plus the rate test (``--rate-test``)."""
    base = bag_identification(chem)
    return identify(
        read_battery_bag(BAGS / f"{chem}_pulse_test", reference_topic=None),
        base.battery,
        slow=read_battery_bag(BAGS / f"{chem}_slow_discharge", reference_topic=None),
        rate_test=read_battery_bag(BAGS / f"{chem}_rate_test", reference_topic=None),
    )


@pytest.mark.parametrize("chem", ["sla", "lfp"])
def test_a_rate_test_cuts_the_field_runs_voltage_error(chem: str) -> None:
    """With the rate test's Butler-Volmer drop and the fastest branch's saturation the same 2RC
    follows the field runs' voltage closer (open loop from the true SoC; measured, 25 degC
    tables for every run): SLA 348 / 577 / 431 mV -> 20.6 / 26.4 / 37.6 mV (ratios 0.05-0.09;
    the cold run meets 30 mV with the 5 degC tables: test above), LFP (with the surface lag)
    114 / 130 / 93 -> 60 / 55 / 93 mV (0.43-0.53 on the 25 degC runs). Bounds: the worst ratio
    plus about a third (SLA 0.12, LFP 0.7) and the worst value plus about a third (SLA 50 mV,
    LFP 130 mV)."""
    if not (BAGS / f"{chem}_rate_test").exists():
        pytest.skip(f"no {chem} rate-test bag")
    linear = bag_identification(chem)
    kinetic = bag_identification_with_rates(chem)
    assert kinetic.battery.thevenin.kinetic is not None
    assert len(kinetic.kinetic) == (5 if chem == "sla" else 7)  # one fit per SoC level
    # The fitted overpotential scale per cell is Butler-Volmer's 2RT/F = 51 mV at 25 degC
    # (transfer coefficient 0.5) within 25 %: measured 50-57 mV (SLA), 48-57 mV (LFP).
    cells = kinetic.battery.cells_in_series
    for fit in kinetic.kinetic:
        assert fit.a_v / cells == pytest.approx(0.0513, rel=0.25)
    for run in sorted(BAGS.glob(f"{chem}_field_run_*")):
        series = read_battery_bag(run)
        soc0 = float(series.soc_ref[0])
        rmse_lin = voltage_rmse(linear.battery, series, soc0)
        rmse_kin = voltage_rmse(kinetic.battery, series, soc0)
        if chem == "lfp" and "cold" in run.name:
            # With the surface lag the LFP 2RC follows the cold run within 93 mV on 25 degC
            # tables, and the 25 degC rate test adds nothing there (92.5 mV): its kinetics are
            # 20 K too warm. Asserted: no worse (5 %, the fits' run-to-run spread).
            assert rmse_kin <= 1.05 * rmse_lin, (run.name, rmse_kin, rmse_lin)
            continue
        assert rmse_kin < (0.12 if chem == "sla" else 0.7) * rmse_lin, (
            run.name,
            rmse_kin,
            rmse_lin,
        )
        assert rmse_kin <= (0.050 if chem == "sla" else 0.130), (run.name, rmse_kin)


def test_the_rate_test_keeps_the_pulse_test_fit() -> None:
    """The SLA pulse test's open-loop RMSE with the kinetic model and RC time constants of at
    least 5 s and the saturating fastest branch: measured 9.6 mV, the issue's 15 mV bound holds."""
    res = bag_identification_with_rates("sla")
    pulse = offset_corrected(read_battery_bag(BAGS / "sla_pulse_test"), [], "pulse test")
    assert voltage_rmse(res.battery, pulse, 1.0) <= 0.015  # issue bound: 15 mV
    assert min(f.tau1_s for f in res.pulses) >= 5.0


def test_the_rested_ocv_holds_the_other_tests_rests_and_leaves_the_model() -> None:
    """With a rate test, its hour-long rests join the pulse test's in ``rest_ocv``; the model's
    ``ocv`` stays the pulse test's alone (the fits are made with it). On LFP the rate test
    rests at 24 % and 11 %, between and below the pulse test's points, where the model's table
    misses the rested voltage by tens of mV (measured: 20 mV and 150 mV); the rested table
    passes through those rests (1 mV: the PCHIP through its own points, and a rest of another
    test within 2 points of SoC of a pulse test's one loses to the longer-rested)."""
    base = bag_identification("lfp")
    res = bag_identification_with_rates("lfp")
    assert base.battery.rest_ocv is None  # a pulse test alone: one table
    assert res.battery.rest_ocv is not None
    assert res.battery.ocv.voltage_v == base.battery.ocv.voltage_v
    rate = read_battery_bag(BAGS / "lfp_rate_test", reference_topic=None)
    points = other_rest_points(rate, res.capacity_ah)
    assert len(points) == 7  # the seven levels' hour-long rests
    model, rested = res.battery.ocv_curve(), res.battery.rest_ocv_curve()
    for pt in points:
        if pt.soc < 0.3:  # the two below the pulse test's 28 %: 24 % and 11 %
            assert abs(rested.ocv(pt.soc) - pt.voltage_v) < 0.001
            assert abs(model.ocv(pt.soc) - pt.voltage_v) > 0.01


#: The fits stop at scipy's default ``xtol = 1e-8`` (``least_squares``, and ``curve_fit`` with
#: bounds): a machine whose BLAS differs in the last bits stops one iteration apart, anywhere
#: within that tolerance of the optimum. Two such results differ by up to 2 xtol, a value
#: derived from two fitted ones by up to twice that (measured across two CPUs outside the 2-RC
#: model: 1.5e-8 relative at most, on the hybrid's tuning).
SAME_FIT_REL = 4e-8
#: The 2-RC model (``thevenin``) holds entries the tests barely determine: a slow branch at its
#: time-constant bound, a saturation current far above the test's currents. Their cost is
#: flat, so ``ftol`` leaves them free: across two CPUs up to 1e-4 relative (LFP's slow branch
#: at SoC 0.25; i_sat 387 A in a test of 36 A at most), 4e-8 on the surface lag's tau. The
#: model is held to what it does: its open-loop voltage along every input test, within
#: ``SAME_VOLTAGE_V`` (measured across the two CPUs: 0.55 uV at most, on lfp_rate_test; 10 uV
#: is a hundredth of the 1 mV a bridge's ADC resolves, and any real change of the
#: identification moves it by millivolts).
LOOSE_FIT_KEY = ".thevenin."
SAME_VOLTAGE_V = 1e-5


def assert_same_tree(ours, theirs, key: str = "") -> None:
    """Equal YAML trees: the same keys, shapes and text; numbers to ``SAME_FIT_REL``, but those
    under ``LOOSE_FIT_KEY`` (compared by the voltage they give, in the test below)."""
    if isinstance(theirs, dict):
        assert isinstance(ours, dict) and sorted(ours) == sorted(theirs), key
        for k in theirs:
            assert_same_tree(ours[k], theirs[k], f"{key}.{k}")
    elif isinstance(theirs, list):
        assert isinstance(ours, list) and len(ours) == len(theirs), key
        for n, (a, b) in enumerate(zip(ours, theirs, strict=True)):
            assert_same_tree(a, b, f"{key}[{n}]")
    elif isinstance(theirs, float):
        assert isinstance(ours, float), key
        if not key.startswith(LOOSE_FIT_KEY):
            assert ours == pytest.approx(theirs, rel=SAME_FIT_REL, abs=1e-15), key
    else:
        assert ours == theirs, key


@pytest.mark.parametrize(
    "name",
    ["sla_12v5ah.yaml", "lfp_12v6ah.yaml", "li_ion_ncr18650pf.yaml", "li_ion_4s_chen2020.yaml"],
)
def test_bundled_files_are_the_identified_ones(name: str, tmp_path: Path, monkeypatch) -> None:
    """config/*.yaml hold what soc_identify produces from the bundled bags: the command in each
    header, run again, writes the same file (the NCR18650PF's needs ../shared/real-data), and
    the two files' models give the same voltage along every input test. A file tuned by
    soc_tune since (SLA) keeps soc_identify's command under its own: identification takes the
    tuned entries from its template, so the command still writes the same file."""
    text = (ROOT / "config" / name).read_text()
    # soc_identify's own header, or soc_tune's above it (the file then tuned: "# From ...").
    header = [line for line in text.splitlines() if line.startswith("#")]
    assert any("Generated by soc_identify" in line for line in header), name
    prefix = "Regenerate: soc_identify "
    command = next(line for line in header if prefix in line)
    args = shlex.split(command.split(prefix, 1)[1])
    inputs = [a for a in args if "/" in a and not a.startswith("config/")]
    absent = [a for a in inputs if not (ROOT / a).exists()]
    if absent:
        pytest.skip(f"inputs of {name} absent: {absent}")
    args[args.index("--output") + 1] = str(tmp_path / name)
    monkeypatch.chdir(ROOT)
    assert identify_main(args) == 0
    ours = yaml.safe_load((tmp_path / name).read_text())
    assert_same_tree(ours, yaml.safe_load(text))
    regenerated = load_battery_params(tmp_path / name)
    bundled = load_battery_params(ROOT / "config" / name)
    for test in inputs:
        series = read_recording(ROOT / test, reference_topic=None)
        dv = simulate_voltage(regenerated, series, 1.0) - simulate_voltage(bundled, series, 1.0)
        assert np.max(np.abs(dv)) <= SAME_VOLTAGE_V, (test, float(np.max(np.abs(dv))))


#: The model error (``bias_std_v``) is measured with the file's own model along the 25 degC
#: pulse test, whose temperature reads 25 +- 0.3 degC (the bag's sensor noise): with a 5 degC
#: row the samples below 25 interpolate a little toward it. Measured: 1.0 % apart.
BIAS_STD_WITH_COLD_ROW_REL = 0.02


def at_temperature(tree: dict, temperature_c: float) -> dict:
    """A battery file's tree cut to one temperature of its tables: each ``temperature_c`` axis
    becomes that one value, each row table its row; the OCV's offsets (zero at the reference
    temperature) go with its axis."""
    out = yaml.safe_load(yaml.safe_dump(tree))
    ocv, thev = out["ocv"], out["thevenin"]
    k = ocv["temperature_c"].index(temperature_c)
    assert not any(ocv.pop("offset_v")[k]), "the reference temperature's OCV has no offset"
    del ocv["temperature_c"]
    k = thev["temperature_c"].index(temperature_c)
    thev["temperature_c"] = [temperature_c]
    thev["r0_ohm"] = thev["r0_ohm"][k]
    for branch in thev["branches"]:
        branch["r_ohm"], branch["c_f"] = branch["r_ohm"][k], branch["c_f"][k]
    return out


def test_the_li_ion_files_warm_row_is_the_bundled_bags(tmp_path: Path, monkeypatch) -> None:
    """config/li_ion_4s_chen2020.yaml is identified from the bundled 25 degC pulse test and a
    5 degC one ``tools/make_bags.py --dev`` makes into dev_bags/ (1.7 MB: bags/ has no room),
    so without it the regeneration above skips. What the bundled bags alone determine is still
    checked: identified from them alone, the file's 25 degC row, its OCV, capacity and every
    other entry are the bundled file's (the model error within
    ``BIAS_STD_WITH_COLD_ROW_REL``), and the two models give the same voltage along the test."""
    pulse, slow = "bags/li_ion4s_pulse_test", "bags/li_ion4s_slow_discharge"
    out = tmp_path / "warm.yaml"
    monkeypatch.chdir(ROOT)
    args = [pulse, "--chemistry", "li_ion", "--slow-discharge", slow]
    args += ["--template", "config/li_ion_4s_chen2020.yaml", "--output", str(out)]
    assert identify_main(args) == 0
    warm = yaml.safe_load(out.read_text())
    bundled = yaml.safe_load((ROOT / "config" / "li_ion_4s_chen2020.yaml").read_text())
    assert bundled["thevenin"]["temperature_c"] == [5.0, 25.0]
    cut = at_temperature(bundled, 25.0)
    assert "li_ion4s_pulse_test_5c" in cut.pop("source")
    warm.pop("source")
    bias, warm_bias = (
        cut["filters"]["hybrid"].pop("bias_std_v"),
        warm["filters"]["hybrid"].pop("bias_std_v"),
    )
    assert bias == pytest.approx(warm_bias, rel=BIAS_STD_WITH_COLD_ROW_REL)
    assert_same_tree(warm, cut)
    cut["source"], cut["filters"]["hybrid"]["bias_std_v"] = "cut", bias
    (tmp_path / "cut.yaml").write_text(yaml.safe_dump(cut))
    series = read_recording(ROOT / pulse, reference_topic=None)
    dv = simulate_voltage(load_battery_params(out), series, 1.0) - simulate_voltage(
        load_battery_params(tmp_path / "cut.yaml"), series, 1.0
    )
    assert np.max(np.abs(dv)) <= SAME_VOLTAGE_V, float(np.max(np.abs(dv)))


def test_cli_takes_a_rate_test_per_input(tmp_path: Path, capsys) -> None:
    if not (BAGS / "sla_rate_test").exists():
        pytest.skip("no sla rate-test bag")
    out = tmp_path / "sla.yaml"
    pulse, rate = str(BAGS / "sla_pulse_test"), str(BAGS / "sla_rate_test")
    args = [pulse, "--chemistry", "sla", "--output", str(out)]
    assert identify_main([*args, "--rate-test", rate]) == 0
    report = capsys.readouterr().out
    assert "rate level" in report and "rate test: 45 steps at 5 SoC levels" in report
    battery = load_battery_params(out)
    assert battery.thevenin.kinetic is not None
    assert "sla_rate_test" in out.read_text().splitlines()[0]  # the header names its inputs
    assert identify_main([*args, "--rate-test", rate, rate]) == 2
    assert "2 rate test(s) for 1 tests" in capsys.readouterr().err


def test_cli_fits_the_second_lag_mode_on_a_load_test(tmp_path: Path, capsys) -> None:
    """``--load-test`` (with the rate test, whose kinetics the 3 C steps need: without them the
    load test's windows sit 60 mV off and no mode helps): its windows below the knee give the
    LFP lag its second mode (the pulse test alone does not keep one: 6.4 -> 6.4 mV), driven
    below the knee's end; the header names the load test; a missing one is a clear error."""
    names = ("lfp_pulse_test", "lfp_slow_discharge", "lfp_rate_test", "lfp_load_test")
    if not all((BAGS / n).exists() for n in names):
        pytest.skip("no lfp pulse, slow-discharge, rate-test and load-test bags")
    out = tmp_path / "lfp.yaml"
    args = [str(BAGS / "lfp_pulse_test"), "--chemistry", "lfp", "--output", str(out)]
    args += ["--slow-discharge", str(BAGS / "lfp_slow_discharge")]
    args += ["--rate-test", str(BAGS / "lfp_rate_test")]
    assert identify_main([*args, "--load-test", str(BAGS / "lfp_load_test")]) == 0
    report = capsys.readouterr().out
    assert "note: load test: current offset" in report  # its own start, reported
    below = [line for line in report.splitlines() if "surface lag, below the knee" in line]
    assert len(below) == 1 and below[0].endswith("kept"), below
    lag = load_battery_params(out).thevenin.surface_lag
    assert lag is not None and lag.n_modes == 2, lag
    assert lag.soc_max[0] == 1.0 and 0.85 < lag.soc_max[1] < 0.95, lag  # the knee's end: 0.90
    assert lag.tau_s[0] < lag.tau_s[1] <= TAU_BOUNDS_S[1], lag
    assert "lfp_load_test" in out.read_text().splitlines()[0]
    assert identify_main([*args, "--load-test", str(tmp_path / "absent")]) == 2
    assert "no such file or bag" in capsys.readouterr().err


def test_the_ocv_axis_std_follows_where_the_capacity_came_from() -> None:
    """``hybrid.ocv_axis_std_frac``: the OCV table's SoC axis is the charge over the file's
    capacity, so it is derived (the guard's capacity spread) where the capacity is a given
    rating or the template's, and left at the code default (0) where a slow discharge
    measured it on the pack (the synthetic pulse test stops at 50 %: no cut-off)."""
    series = synthetic_pulse_test(noise=False)
    given = identify(series, SLA, capacity_ah=5.0)
    assert given.capacity_source == "given" and not given.capacity_measured
    assert ocv_axis_std(given, 0.03)[:2] == (0.03, "derived")
    template = identify(series, SLA)
    assert template.capacity_source.startswith("template") and not template.capacity_measured
    assert ocv_axis_std(template, 0.025)[:2] == (0.025, "derived")
    slow = identify(series, SLA, slow=synthetic_slow_discharge(SYNTHETIC_OCV))
    assert slow.capacity_source.startswith("slow discharge") and slow.capacity_measured
    assert ocv_axis_std(slow, 0.03)[:2] == (None, "default")
    told = identify(series, SLA, capacity_ah=5.0, capacity_measured=True)  # --capacity-measured
    assert told.capacity_source == "given, measured on this pack" and told.capacity_measured
    assert ocv_axis_std(told, 0.03)[:2] == (None, "default")


def test_cli_capacity_measured_writes_no_axis_std(tmp_path: Path) -> None:
    """The CLI passes ``--capacity-measured`` to the reference test's identification: the
    file the CSV test above gets with a given (rated) capacity, without the axis' std."""
    test = synthetic_pulse_test(noise=False)
    csv_path = tmp_path / "pulse.csv"
    rows = ["time_s,current_a,voltage_v,temperature_c"] + [
        f"{t:.1f},{i:.4f},{v:.5f},25.0"
        for t, i, v in zip(test.t_s, test.current_a, test.voltage_v, strict=True)
    ]
    csv_path.write_text("\n".join(rows) + "\n")
    out = tmp_path / "p.yaml"
    args = [str(csv_path), "--chemistry", "sla", "--capacity-ah", "5", "--output", str(out)]
    assert identify_main([*args, "--capacity-measured"]) == 0
    assert "ocv_axis_std_frac" not in load_battery_params(out).filters["hybrid"]


def test_capacity_measured_needs_the_capacity(capsys) -> None:
    """``--capacity-measured`` says how ``--capacity-ah`` was obtained: alone, a usage error."""
    with pytest.raises(SystemExit) as exc:
        identify_main(
            [
                str(bag_path("sla_pulse_test")),
                "--chemistry",
                "sla",
                "--capacity-measured",
                "--output",
                "x.yaml",
            ]
        )
    assert exc.value.code == 2
    assert "give --capacity-ah" in capsys.readouterr().err
