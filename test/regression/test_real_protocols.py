"""The identification on real test protocols, on small recordings the tests build themselves.

The measured files (../shared/real-data) are never copied here: each parsing path they need
(repeated time stamps, logging gaps under load and at rest, HPPC pulse sets at several rates,
a recharge at the start, regen pulses inside a block, tests at two temperatures) is rebuilt in
a few lines. The pack voltage comes from known 2-RC parameters through the package's own model:
these tests check that the identification finds them back, not an estimator's accuracy. The
full real-data evaluation is ``benchmarks/studies/real_data.py``.
"""

from __future__ import annotations

from dataclasses import replace
from functools import cache
from pathlib import Path

import numpy as np
import pytest
import yaml
from conftest import REPO_ROOT

from soc_estimator_ros.identification.cli import identify_tests
from soc_estimator_ros.identification.cli import main as identify_main
from soc_estimator_ros.identification.fit import charge_removed_ah, step_current_a
from soc_estimator_ros.identification.identify import identify, ocv_shift_v
from soc_estimator_ros.identification.segment import find_windows, start_after_last_charge
from soc_estimator_ros.models import OcvCurve, ParamTable, RcBranch, TheveninModel, TheveninParams
from soc_estimator_ros.params import OcvTable, load_battery_params
from soc_estimator_ros.recordings import BatterySeries, RecordingError, read_csv
from soc_estimator_ros.units import CurrentSign

ROOT = REPO_ROOT
LI_ION = load_battery_params(ROOT / "config" / "li_ion_ncr18650pf.yaml")
OCV = OcvCurve([0.0, 0.1, 0.3, 0.5, 0.7, 0.9, 1.0], [3.0, 3.35, 3.55, 3.66, 3.86, 4.06, 4.17])
CAPACITY_AH = 2.8
TRUE = {"r0": 0.030, "r1": 0.010, "tau1": 8.0, "r2": 0.015, "tau2": 150.0}


def cell(scale: float = 1.0, ocv_shift_v: float = 0.0) -> TheveninModel:
    """A cell with known constant 2-RC parameters (resistances times ``scale``), its OCV
    shifted by ``ocv_shift_v``."""
    th = TheveninParams(
        ParamTable.constant(TRUE["r0"] * scale),
        (
            RcBranch(
                ParamTable.constant(TRUE["r1"] * scale),
                ParamTable.constant(TRUE["tau1"] / (TRUE["r1"] * scale)),
            ),
            RcBranch(
                ParamTable.constant(TRUE["r2"] * scale),
                ParamTable.constant(TRUE["tau2"] / (TRUE["r2"] * scale)),
            ),
        ),
    )
    ocv = OcvCurve(OCV.soc_points, OCV.ocv_points_v + ocv_shift_v)
    return TheveninModel(ocv, th, capacity_ah=CAPACITY_AH, coulomb_efficiency_charge=1.0)


def record(
    segments: list[tuple[float, float, float]],
    model: TheveninModel,
    soc0: float = 1.0,
    temperature_c: float = 25.0,
) -> BatterySeries:
    """Simulate ``(duration_s, current_a, log_period_s)`` segments, logged at their periods,
    with a tester's amp-hour counter as the reference SoC (``soc_ref`` over 2.9 Ah)."""
    fine_dt = 0.1
    t_log, i_log, v_log, q_log = [], [], [], []
    x = model.rested_state(soc0)
    t, q = 0.0, 0.0
    for duration, current, period in segments:
        n = round(duration / fine_dt)
        every = max(1, round(period / fine_dt))
        for k in range(n):
            if k % every == 0 or k == n - 1:  # a tester logs each step's last point too
                t_log.append(t)
                i_log.append(current)
                v_log.append(model.terminal_voltage(x, current))
                q_log.append(q)
            x = model.step(x, current, fine_dt)
            t += fine_dt
            q += current * fine_dt / 3600.0
    t_arr = np.array(t_log)
    return BatterySeries(
        t_s=t_arr,
        stamp_ns=(t_arr * 1e9).astype(np.int64),
        current_a=np.array(i_log),
        voltage_v=np.array(v_log),
        temperature_c=np.full(t_arr.size, temperature_c),
        soc_ref=1.0 - np.array(q_log) / 2.9,
        reference_capacity_ah=2.9,
    )


def hppc_segments(levels: int = 3) -> list[tuple[float, float, float]]:
    """Pulse sets (10-s pulses at 0.5, 2 and 4 C, 20-min rests, 10 Hz under load) separated
    by 10 % discharges at C/3 logged once a minute (as the Panasonic HPPC)."""
    segs: list[tuple[float, float, float]] = [(600.0, 0.0, 1.0)]
    for n in range(levels):
        for rate in (0.5, 2.0, 4.0):
            segs += [(10.0, rate * CAPACITY_AH, 0.1), (1200.0, 0.0, 1.0)]
        if n + 1 < levels:
            segs += [(0.1 * 3 * 3600.0, CAPACITY_AH / 3, 60.0), (1800.0, 0.0, 60.0)]
    return segs


@cache
def hppc(scale: float = 1.0, temperature_c: float = 25.0, ocv_shift_v: float = 0.0):
    return record(hppc_segments(), cell(scale, ocv_shift_v), temperature_c=temperature_c)


def test_repeated_time_stamps_are_dropped_and_backwards_time_refused(tmp_path: Path) -> None:
    path = tmp_path / "tester.csv"
    path.write_text(
        "time_s,current_a,voltage_v,temperature_c,soc_ref,source\n"
        "0.0,0,4.17,25,1,hppc\n"
        "0.1,1.45,4.10,25,1,hppc\n"
        "0.1,1.45,4.10,25,1,hppc\n"  # the step boundary logged twice
        "0.2,0,4.15,,0.99,hppc\n"
    )
    s = read_csv(path, CurrentSign.DISCHARGE_POSITIVE)
    assert s.t_s.tolist() == pytest.approx([0.0, 0.1, 0.2])
    assert s.repeated_stamps == 1
    assert np.isnan(s.temperature_c[2])  # an empty cell is "not measured"
    path.write_text("time_s,current_a,voltage_v\n0,0,4.1\n1,0,4.1\n0.5,0,4.1\n")
    with pytest.raises(RecordingError, match="must not decrease"):
        read_csv(path, CurrentSign.DISCHARGE_POSITIVE)


def test_charge_comes_from_the_reference_across_logging_gaps() -> None:
    s = hppc()
    notes: list[str] = []
    q = charge_removed_ah(s, notes=notes)
    truth = (s.soc_ref[0] - s.soc_ref) * 2.9
    np.testing.assert_allclose(q, truth, atol=1e-12)
    assert "reference SoC" in notes[0]
    # Without the reference's capacity the held current is used and the gaps are reported
    # (here the current really was constant through them, so the two counts agree).
    notes = []
    held = charge_removed_ah(replace(s, reference_capacity_ah=None), notes=notes)
    assert "logging gap" in notes[0] and "--reference-capacity-ah" in notes[0]
    np.testing.assert_allclose(held, truth, atol=1e-9)
    # A point logged just before a discharge began holds 0 A for its minute: the samples
    # miss that minute's charge, the tester's counter does not.
    t = np.array([0.0, 60.0, 120.0])
    gap = BatterySeries(
        t_s=t,
        stamp_ns=(t * 1e9).astype(np.int64),
        current_a=np.array([0.0, 1.0, 1.0]),
        voltage_v=np.full(3, 3.7),
        temperature_c=np.full(3, 25.0),
        soc_ref=np.array([1.0, 1.0 - 1 / 60 / 2.9, 1.0 - 2 / 60 / 2.9]),
        reference_capacity_ah=2.9,
    )
    assert charge_removed_ah(gap)[-1] == pytest.approx(2 / 60)
    assert charge_removed_ah(replace(gap, reference_capacity_ah=None))[-1] == pytest.approx(1 / 60)


def test_a_load_step_into_a_sparsely_logged_rest_ends_at_its_last_point() -> None:
    t = np.array([0.0, 1.0, 2.0, 62.0, 122.0])
    i = np.array([10.0, 10.0, 10.0, 0.0, 0.0])
    np.testing.assert_array_equal(step_current_a(t, i), [10.0, 10.0, 0.0, 0.0, 0.0])
    # A gap between two loaded points holds the load (it is not known to have ended).
    i2 = np.array([10.0, 10.0, 10.0, 10.0, 0.0])
    np.testing.assert_array_equal(step_current_a(t, i2), [10.0, 10.0, 10.0, 0.0, 0.0])


def test_hppc_windows_pulses_fitted_and_gapped_discharges_skipped() -> None:
    s = hppc()
    windows = find_windows(s)
    # 3 levels x 3 pulses, and 2 C/3 discharges between the levels.
    assert len(windows) == 11
    gapped = [w for w in windows if w.max_step_s > 10.0]
    assert len(gapped) == 2 and all(w.net_ah > 0.25 for w in gapped)
    res = identify(s, LI_ION, capacity_ah=CAPACITY_AH)
    assert len(res.pulses) == 9
    assert any("2 skipped: a logging gap" in n for n in res.notes)
    assert len(res.levels) == 3  # one table point per pulse set (median over the rates)
    assert len(res.battery.thevenin.r0_ohm.soc) == 3


def test_hppc_recovers_the_known_parameters() -> None:
    """Noise-free 10-s pulses: R0 from the step and the fit within 2 % (the issue's bound for
    resistances); the fast branch within 5 %. The 150-s branch, seen for 10 s of load and a
    20-min rest, within 10 %: a 10-s pulse charges it to 6 % of its final value."""
    res = identify(hppc(), LI_ION, capacity_ah=CAPACITY_AH)
    for f in res.levels:
        assert f.r0_ohm == pytest.approx(TRUE["r0"], rel=0.02)
        assert f.r1_ohm == pytest.approx(TRUE["r1"], rel=0.05)
        assert f.tau1_s == pytest.approx(TRUE["tau1"], rel=0.05)
        assert f.r2_ohm == pytest.approx(TRUE["r2"], rel=0.10)
        assert f.tau2_s == pytest.approx(TRUE["tau2"], rel=0.10)


def test_a_recording_that_starts_with_a_recharge_starts_after_it() -> None:
    """The Nissan files: a discharge to the cut-off, a rest, a CC charge, a 1-h rest, then
    blocks of a 30-s pulse, a 40-s rest, a 10-s regen pulse and a 10 % discharge."""
    model = cell()
    block = [(30.0, 3.0, 1.0), (40.0, 0.0, 1.0), (10.0, -2.2, 1.0), (1080.0, 1.0, 1.0)]
    segs = [(300.0, 0.0, 1.0), (600.0, 1.0, 1.0), (3600.0, 0.0, 60.0)]
    segs += [(0.2 * 3600 * CAPACITY_AH, -1.0, 1.0), (3600.0, 0.0, 60.0)]
    for _ in range(3):
        segs += [*block, (3600.0, 0.0, 60.0)]
    s = record(segs, model, soc0=0.8)
    k = start_after_last_charge(s)
    assert k is not None and s.t_s[k] == pytest.approx(300 + 600 + 3600 + 0.2 * 3600 * 2.8, abs=2)
    res = identify(s, LI_ION, capacity_ah=CAPACITY_AH)
    assert any("after the last recharge" in n for n in res.notes)
    assert len(res.pulses) == 3  # the regen pulse stays inside its block
    for f in res.pulses:
        assert f.r0_ohm == pytest.approx(TRUE["r0"], rel=0.05)  # 1 Hz: a second of branch 1


def test_two_temperatures_give_a_table_over_temperature(tmp_path: Path) -> None:
    cold, warm = hppc(2.0, 0.0, -0.02), hppc(1.0, 25.0)
    battery, results = identify_tests([cold, warm], None, LI_ION, None, None, None)
    r0 = battery.thevenin.r0_ohm
    assert r0.temperature_c == (0.0, 25.0)
    assert r0.at(0.5, 0.0) == pytest.approx(2 * TRUE["r0"], rel=0.02)
    assert r0.at(0.5, 25.0) == pytest.approx(TRUE["r0"], rel=0.02)
    assert r0.at(0.5, 12.5) == pytest.approx(1.5 * TRUE["r0"], rel=0.02)  # bilinear
    assert results[0].capacity_source == "given"  # the cold test takes the warm one's
    # The cold cell's OCV is 20 mV lower: the shift table finds it where the cold test's rests
    # were (SoC 0.8-1); 1 mV: the rests' remaining relaxation (150-s branch, 20-30 min).
    offset = battery.ocv.offset_table()
    assert offset is not None and offset.temperature_c == (0.0, 25.0)
    for soc in (0.85, 0.95):
        assert offset.at(soc, 0.0) == pytest.approx(-0.02, abs=1e-3)
        assert offset.at(soc, 25.0) == 0.0
    model = TheveninModel(battery.ocv_curve(), battery.thevenin, CAPACITY_AH, ocv_offset=offset)
    x = model.rested_state(0.9)
    assert model.terminal_voltage(x, 0.0, 0.0) - model.terminal_voltage(x, 0.0, 25.0) == (
        pytest.approx(offset.at(0.9, 0.0), abs=1e-12)
    )

    # The same through the CLI, from CSV files without a temperature column.
    paths = []
    for name, s in (("cold", cold), ("warm", warm)):
        p = tmp_path / f"{name}.csv"
        rows = ["time_s,current_a,voltage_v,soc_ref"] + [
            f"{t:.1f},{i:.4f},{v:.6f},{r:.8f}"
            for t, i, v, r in zip(s.t_s, s.current_a, s.voltage_v, s.soc_ref, strict=True)
        ]
        p.write_text("\n".join(rows) + "\n")
        paths.append(str(p))
    out = tmp_path / "cell.yaml"
    args = [*paths, "--chemistry", "li_ion", "--reference-capacity-ah", "2.9"]
    assert identify_main([*args, "--output", str(out)]) == 2  # no sensor, no temperatures
    assert identify_main([*args, "--temperature-c", "0", "25", "--output", str(out)]) == 0
    data = yaml.safe_load(out.read_text())
    assert data["thevenin"]["temperature_c"] == [0.0, 25.0]
    assert data["ocv"]["temperature_c"] == [0.0, 25.0]
    loaded = load_battery_params(out)
    assert loaded.chemistry == "li_ion"
    # The CSV's six decimals of voltage against the in-memory run: 0.2 mV.
    np.testing.assert_allclose(loaded.ocv.offset_v, battery.ocv.offset_v, atol=2e-4)


def test_the_ocv_shift_is_measured_at_the_other_tests_rests_not_between_them() -> None:
    """A reference OCV with LFP's knee near full (the bundled LFP table's shape), another
    temperature's rests 20 mV below it at SoC 0.5, 0.87 and 1.0 only: the shift is -20 mV
    across the knee too, and held below the rests. The difference of the two curves (the
    table before) is the knee's depth there: the other test's curve is a line between rests."""
    soc = (0.2, 0.5, 0.8, 0.87, 0.9, 0.95, 0.975, 0.99, 1.0)
    volts = (12.74, 13.08, 13.24, 13.26, 13.265, 13.275, 13.356, 13.83, 14.41)
    ref = OcvTable(soc, volts)
    own_soc = (0.5, 0.87, 1.0)
    own = OcvTable(own_soc, tuple(ref.curve().ocv(s) - 0.02 for s in own_soc))
    np.testing.assert_allclose(ocv_shift_v(ref, own), -0.02, atol=1e-12)
    assert own.curve().ocv(0.95) - ref.curve().ocv(0.95) > 0.3  # the old table's error


def test_real_data_benchmark_skips_clearly_without_the_data(tmp_path: Path) -> None:
    """benchmarks/studies/real_data.py reads ../shared/real-data when present; elsewhere (a clean CI
    checkout) it says so and exits 0, without touching the network or the repository."""
    import subprocess
    import sys

    out = subprocess.run(
        [
            sys.executable,
            str(ROOT / "benchmarks" / "studies" / "real_data.py"),
            "--data",
            str(tmp_path),
        ],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert out.returncode == 0, out.stderr
    assert (
        out.stdout.strip()
        == f"real_data: skipped: no measured data in {tmp_path} (pass --data DIR)"
    )
