"""``soc_replay``: the output bag, the progress bar, and clear errors for unusable inputs.

Inputs are short excerpts (3000 samples, 5 minutes at 10 Hz) of a bundled field run, written
as CSV by the tests themselves, so each test takes seconds.
"""

from __future__ import annotations

import csv
from functools import cache
from pathlib import Path

import numpy as np
import pytest
from conftest import REPO_ROOT, bag_path
from rosbags.highlevel import AnyReader

from soc_estimator_ros.estimators import make_estimator
from soc_estimator_ros.evaluation import run_estimator
from soc_estimator_ros.messages import bridge_state, decode_estimate
from soc_estimator_ros.params import load_battery_params
from soc_estimator_ros.recordings import (
    battery_state_message,
    read_battery_bag,
    write_battery_bag,
)
from soc_estimator_ros.replay.cli import main as replay_main
from soc_estimator_ros.series import BatterySeries
from soc_estimator_ros.tracking import TrackerConfig
from soc_estimator_ros.tracking.persistence import load_state

N = 3000


@cache
def excerpt() -> BatterySeries:
    return read_battery_bag(bag_path("sla_field_run_1_full_rest")).window(0, N)


def write_excerpt(path: Path, voltage_v: np.ndarray | None = None) -> Path:
    s = excerpt()
    assert s.soc_ref is not None
    voltage = s.voltage_v if voltage_v is None else voltage_v
    with path.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["time_s", "current_a", "voltage_v", "temperature_c", "soc_ref"])
        for row in zip(
            s.stamp_ns * 1e-9, s.current_a, voltage, s.temperature_c, s.soc_ref, strict=True
        ):
            w.writerow([repr(float(v)) for v in row])
    return path


def run(args: list[str], capsys) -> tuple[int, str, str]:
    code = replay_main(args)
    out = capsys.readouterr()
    return code, out.out, out.err


def test_output_bag_holds_the_input_and_the_estimates_at_the_input_stamps(tmp_path, capsys):
    src = write_excerpt(tmp_path / "run.csv")
    params = ["--params", str(REPO_ROOT / "config" / "sla_12v5ah.yaml")]
    bag = tmp_path / "out_bag"
    est_csv = tmp_path / "est.csv"
    code, out, _ = run(
        [str(src), *params, "--output", str(est_csv), "--output-bag", str(bag)], capsys
    )
    assert code == 0 and f"bag: {bag}" in out
    with AnyReader([bag]) as reader:
        counts = {c.topic: (c.msgtype, c.msgcount) for c in reader.connections}
        assert counts == {
            "/battery/state": ("sensor_msgs/msg/BatteryState", N),
            "/battery/soc_reference": ("sensor_msgs/msg/BatteryState", N),
            "/battery/soc": ("sensor_msgs/msg/BatteryState", N),
            "/battery/soc_estimate": ("std_msgs/msg/Float64MultiArray", N),
        }
        soc, stamps, est = [], [], []
        for conn, t, raw in reader.messages():
            msg = reader.deserialize(raw, conn.msgtype)
            if conn.topic == "/battery/soc":
                soc.append(msg.percentage)
                stamps.append(msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec)
                assert t == stamps[-1]
            elif conn.topic == "/battery/soc_estimate":
                est.append(decode_estimate(msg))
            elif conn.topic == "/battery/state" and len(soc) == 0:
                assert msg.current == pytest.approx(-excerpt().current_a[0], abs=1e-5)  # ROS sign
    # The CSV's stamps are microsecond-rounded floats: equal to the bag's within 1 us.
    np.testing.assert_allclose(np.array(stamps), excerpt().stamp_ns, atol=1e3, rtol=0)
    with est_csv.open() as fh:
        csv_soc = np.array([float(r["soc"]) for r in csv.DictReader(fh)])
    np.testing.assert_allclose(soc, csv_soc, atol=1e-6)  # the CSV keeps 6 significant digits
    assert {"x.soc", "P.soc.soc", "innovation_v"} <= set(est[-1])
    assert est[-1]["soc"] == pytest.approx(soc[-1])
    assert est[-1]["soc_std"] ** 2 == pytest.approx(est[-1]["soc_var"])


def test_output_bag_refuses_an_existing_directory(tmp_path, capsys):
    src = write_excerpt(tmp_path / "run.csv")
    (tmp_path / "taken").mkdir()
    code, _, err = run(
        [str(src), "--params", str(_sla()), "--output-bag", str(tmp_path / "taken")], capsys
    )
    assert code == 2 and "exists" in err


def test_all_estimators_go_under_their_own_namespace(tmp_path, capsys):
    src = write_excerpt(tmp_path / "run.csv")
    bag = tmp_path / "all_bag"
    code, _, _ = run([str(src), "--params", str(_sla()), "--all", "--output-bag", str(bag)], capsys)
    assert code == 0
    with AnyReader([bag]) as reader:
        topics = {c.topic for c in reader.connections}
    assert {"/hybrid/battery/soc", "/rc_kf/battery/soc_estimate", "/battery/state"} <= topics


def test_progress_goes_to_stderr_only(tmp_path, capsys):
    src = write_excerpt(tmp_path / "run.csv")
    code, out, err = run([str(src), "--params", str(_sla()), "--progress"], capsys)
    assert code == 0
    assert "100 %" in err and "[####" in err
    assert "%]" not in out and "####" not in out
    code, out, err = run([str(src), "--params", str(_sla()), "--no-progress"], capsys)
    assert code == 0 and err == ""


def test_unusable_bags_give_one_clear_line(tmp_path, capsys):
    s = excerpt()
    msgs = [battery_state_message(bridge_state(int(t), 12.0, 1.0)) for t in s.stamp_ns[:20]]
    write_battery_bag(tmp_path / "other_topic", [("/bms/state", msgs)])
    code, _, err = run([str(tmp_path / "other_topic"), "--params", str(_sla())], capsys)
    assert code == 2 and "/battery/state" in err and "/bms/state" in err
    write_battery_bag(tmp_path / "empty", [("/battery/state", [])])
    code, _, err = run([str(tmp_path / "empty"), "--params", str(_sla())], capsys)
    assert code == 2 and "/battery/state" in err
    assert err.count("\n") == 1


def _sla() -> Path:
    return REPO_ROOT / "config" / "sla_12v5ah.yaml"


def test_live_replay_equals_the_offline_replay_sample_for_sample(tmp_path, capsys):
    """The same samples through a running soc_estimator_node (sim time, lock-step): the node
    runs the same estimator code on the same float64 inputs, so the estimate vector (float64)
    agrees to rounding, 1e-12; the CSVs, which keep 6 significant digits, agree exactly."""
    from soc_estimator_ros.replay.live import replay_live

    soc0 = float(excerpt().soc_ref[0])
    config = TrackerConfig(estimator="hybrid", initial_soc=soc0, initial_soc_std=0.1)
    live, _, _ = replay_live(excerpt(), _sla(), config)
    offline = run_estimator(
        make_estimator("hybrid", load_battery_params(_sla()), float(excerpt().soc_ref[0]), 0.1),
        excerpt(),
    )
    assert live.soc.shape == offline.soc.shape == (N,)
    np.testing.assert_allclose(live.soc, offline.soc, rtol=0, atol=1e-12)
    np.testing.assert_allclose(live.soc_std, offline.soc_std, rtol=0, atol=1e-12)
    np.testing.assert_allclose(live.x, offline.x, rtol=0, atol=1e-12)
    assert live.state_names == offline.state_names

    src = write_excerpt(tmp_path / "run.csv")
    outs = []
    for extra in ([], ["--live"]):
        out = tmp_path / f"est{len(extra)}.csv"
        code, text, _ = run(
            [str(src), "--params", str(_sla()), "--output", str(out), *extra], capsys
        )
        assert code == 0
        outs.append((out.read_text(), text))
    assert outs[0][0] == outs[1][0]
    assert outs[0][1].splitlines()[:2] == outs[1][1].splitlines()[:2]  # the same table


def test_bad_samples_are_rejected_counted_and_the_run_stays_finite(tmp_path, capsys):
    """40 NaN voltages in a run: today's replay gave NaN for every SoC after the first one and
    exit 0; through the tracker they are rejected, counted and printed, as the node does."""
    voltage = excerpt().voltage_v.copy()
    voltage[np.arange(100, 2900, 70)] = np.nan  # 40 samples
    src = write_excerpt(tmp_path / "nan.csv", voltage)
    out_csv = tmp_path / "est.csv"
    code, out, _ = run([str(src), "--params", str(_sla()), "--output", str(out_csv)], capsys)
    assert code == 0
    assert "non_finite 40" in out
    with out_csv.open() as fh:
        soc = np.array([float(r["soc"]) for r in csv.DictReader(fh)])
    assert np.all(np.isfinite(soc))


def test_unusable_csv_files_give_one_clear_line_and_a_short_row_is_a_bad_sample(tmp_path, capsys):
    """A fuzz of CSV inputs found two tracebacks: a file that is not text, and a row cut
    short (a logger stopped mid-line). The first is one line now; the second's missing
    fields read as NaN, so the sample is rejected and counted as an empty field is."""
    binary = tmp_path / "binary.csv"
    binary.write_bytes(b"time_s,current_a,voltage_v\n" + bytes(range(128, 256)))
    code, _, err = run([str(binary), "--params", str(_sla())], capsys)
    assert code == 2 and "not a text CSV file" in err and err.count("\n") == 1
    no_time = tmp_path / "no_time.csv"
    no_time.write_text("time_s,current_a,voltage_v\nx,1.0,12.5\n")
    code, _, err = run([str(no_time), "--params", str(_sla())], capsys)
    assert code == 2 and "time_s" in err and err.count("\n") == 1
    src = write_excerpt(tmp_path / "run.csv")
    lines = src.read_text().splitlines()
    lines[100] = lines[100].split(",")[0]  # time only: current and voltage missing
    short = tmp_path / "short.csv"
    short.write_text("\n".join(lines) + "\n")
    code, out, _ = run([str(short), "--params", str(_sla())], capsys)
    assert code == 0 and "non_finite 1" in out


def test_a_run_without_a_finite_estimate_is_an_error(tmp_path, capsys):
    voltage = np.full(N, np.nan)  # every sample rejected: no estimate at all
    src = write_excerpt(tmp_path / "all_nan.csv", voltage)
    code, _, err = run([str(src), "--params", str(_sla())], capsys)
    assert code == 2 and "not finite" in err and err.count("\n") == 1


def test_replay_starts_as_the_node_does_and_says_so(tmp_path, capsys):
    """Without --initial-soc the start is the OCV of the first accepted sample (the node's
    start), printed; 'ref' takes the reference, a number itself."""
    src = write_excerpt(tmp_path / "run.csv")
    code, out, _ = run([str(src), "--params", str(_sla())], capsys)
    assert code == 0 and "initial_soc=ocv: SoC" in out
    code, out, _ = run([str(src), "--params", str(_sla()), "--initial-soc", "ref"], capsys)
    assert code == 0 and f"initial SoC {float(excerpt().soc_ref[0]):.4f} (given)" in out
    code, _, err = run([str(src), "--params", str(_sla()), "--initial-soc", "1.5"], capsys)
    assert code == 2 and "fraction" in err


def test_csv_columns_contract(tmp_path, capsys):
    """--output's columns, in order, as docs/replay.md lists them: the estimate's, then the
    runtime monitor's time to empty (and its std), time to full and 10-s discharge current,
    the latest prediction (one a second of sample time, as the node publishes them)."""
    from soc_estimator_ros.replay.outputs import CSV_COLUMNS

    assert CSV_COLUMNS == (
        "time_s",
        "soc",
        "soc_std",
        "voltage_v",
        "voltage_pred_v",
        "current_a",
        "time_to_empty_s",
        "time_to_empty_std_s",
        "time_to_full_s",
        "max_discharge_current_10s_a",
        "capacity_ah",
        "r0_factor",
    )
    doc = (REPO_ROOT / "docs" / "replay.md").read_text()
    assert all(f"`{c}`" in doc for c in CSV_COLUMNS)
    src = write_excerpt(tmp_path / "run.csv")
    out = tmp_path / "est.csv"
    code, _, _ = run([str(src), "--params", str(_sla()), "--output", str(out)], capsys)
    assert code == 0
    with out.open() as fh:
        reader = csv.DictReader(fh)
        assert tuple(reader.fieldnames or ()) == CSV_COLUMNS
        rows = list(reader)
    assert len(rows) == N
    t = np.array([float(r["time_s"]) for r in rows])
    tte = np.array([float(r["time_to_empty_s"]) for r in rows])
    std = np.array([float(r["time_to_empty_std_s"]) for r in rows])
    ttf = np.array([float(r["time_to_full_s"]) for r in rows])
    sop = np.array([float(r["max_discharge_current_10s_a"]) for r in rows])
    assert np.all(tte > 0) and np.all(std > 0)  # from the first sample (SoC 1 -> 0.4)
    assert np.all(np.isnan(ttf))  # no charge in a discharge mission
    limit = load_battery_params(_sla()).limits.current_max_discharge_a
    assert np.all((sop > 0) & (sop <= limit))
    changes = t[1:][np.diff(tte) != 0]
    assert np.all(np.diff(changes) >= 0.99)  # at most one prediction a second
    assert 0.9 * (t[-1] - t[0]) <= len(changes) + 1  # and about one every second
    assert all(r["capacity_ah"] == r["r0_factor"] == "nan" for r in rows)  # health not learned


def test_state_carries_the_learned_health_from_replay_to_replay(tmp_path, capsys):
    """``--state FILE``: the health is learned, written back at the end, and the next replay
    starts from it (not from the file's SoC); its CSV columns follow what is learned."""
    src = write_excerpt(tmp_path / "run.csv")
    state = tmp_path / "state.yaml"
    est = tmp_path / "est.csv"
    args = [str(src), "--params", str(_sla()), "--state", str(state), "--output", str(est)]
    code, out, _ = run(args, capsys)
    assert code == 0 and "no saved health" in out
    first = load_state(state)
    assert first.health is not None and first.battery == load_battery_params(_sla()).name
    # One 5-minute run has no rest of 30 min: the capacity stays the file's prior; the
    # R_0 factor may move (current steps), and the CSV's last row holds what was saved.
    with est.open() as fh:
        last = list(csv.DictReader(fh))[-1]
    assert float(last["capacity_ah"]) == pytest.approx(first.health.capacity_ah, rel=1e-5)
    assert float(last["r0_factor"]) == pytest.approx(first.health.r0_factor, rel=1e-5)
    # (rel 1e-5: the CSV's 6 significant digits.)
    code, out, _ = run(args, capsys)
    assert code == 0 and f"health from {state}: capacity {first.health.capacity_ah:.3f} Ah" in out
    assert "initial_soc=ocv" in out  # the SoC starts as without a state file
    code, _, err = run([str(src), "--params", str(_sla()), "--state", str(state), "--all"], capsys)
    assert code == 2 and "--state needs one estimator" in err


def test_cells_in_series_and_capacity_scale_the_file(tmp_path, capsys):
    """--cells-in-series / --capacity-ah: a pack of twice the file's cells and rating, its
    recording twice the voltage and current, gives the file's estimates (n = q = 2: exact)."""
    s = excerpt()
    battery = load_battery_params(_sla())
    doubled = tmp_path / "doubled.csv"
    with doubled.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["time_s", "current_a", "voltage_v", "temperature_c", "soc_ref"])
        for row in zip(
            s.stamp_ns * 1e-9, 2 * s.current_a, 2 * s.voltage_v, s.temperature_c, s.soc_ref,
            strict=True,
        ):  # fmt: skip
            w.writerow([repr(float(v)) for v in row])
    plain, scaled = tmp_path / "plain.csv", tmp_path / "scaled.csv"
    base = ["--params", str(_sla()), "--initial-soc", "ref"]
    assert run([str(write_excerpt(tmp_path / "run.csv")), *base, "--output", str(plain)],
               capsys)[0] == 0  # fmt: skip
    pack = ["--cells-in-series", str(2 * battery.cells_in_series),
            "--capacity-ah", str(2 * battery.nominal_capacity_ah)]  # fmt: skip
    assert run([str(doubled), *base, *pack, "--output", str(scaled)], capsys)[0] == 0
    with plain.open() as a, scaled.open() as b:
        rows_a, rows_b = list(csv.DictReader(a)), list(csv.DictReader(b))
    assert [r["soc"] for r in rows_a] == [r["soc"] for r in rows_b]
    code, _, err = run([str(doubled), *base, "--cells-in-series", "-2"], capsys)
    assert code == 2 and "--cells-in-series" in err


def test_csv_cell_columns_contract(tmp_path, capsys):
    """With cell voltages --output adds ``soc_lumped`` and ``cell_soc_1`` ... ``cell_soc_N``
    after :data:`CSV_COLUMNS`, and ``soc`` is the usable SoC (docs/replay.md); the first
    2000 samples of a bundled 4S mission."""
    from soc_estimator_ros.replay.outputs import CSV_COLUMNS, cell_csv_columns

    assert cell_csv_columns(4) == [
        "soc_lumped",
        "cell_soc_1",
        "cell_soc_2",
        "cell_soc_3",
        "cell_soc_4",
    ]
    doc = (REPO_ROOT / "docs" / "replay.md").read_text()
    assert "`soc_lumped`" in doc and "`cell_soc_1`" in doc
    bag = bag_path("lfp4s_cells_2_partial")
    out = tmp_path / "est.csv"
    lfp = REPO_ROOT / "config" / "lfp_12v6ah.yaml"
    code, _, _ = run([str(bag), "--params", str(lfp), "--output", str(out)], capsys)
    assert code == 0
    with out.open() as fh:
        reader = csv.DictReader(fh)
        assert tuple(reader.fieldnames or ()) == (*CSV_COLUMNS, *cell_csv_columns(4))
        rows = list(reader)
    soc = np.array([float(r["soc"]) for r in rows])
    cells = np.array([[float(r[f"cell_soc_{k}"]) for k in range(1, 5)] for r in rows])
    lumped = np.array([float(r["soc_lumped"]) for r in rows])
    assert np.all((cells >= -0.05) & (cells <= 1.05))  # fractions, not percent
    # soc is the usable SoC: never above the fullest cell's, and apart from the lumped one.
    assert np.all(soc <= cells.max(axis=1) + 0.05)
    assert np.max(np.abs(soc - lumped)) > 0.005


def test_output_bag_carries_the_cell_voltages(tmp_path, capsys):
    """--output-bag with a 4S mission: /battery/state keeps cell_voltage, /battery/soc is the
    usable SoC (the node's percentage), /battery/soc_estimate's soc the pack's own and its
    ``cell.*`` values the cells' (cell.usable_soc the percentage)."""
    bag = bag_path("lfp4s_cells_2_partial")
    out = tmp_path / "out_bag"
    est_csv = tmp_path / "est.csv"
    lfp = REPO_ROOT / "config" / "lfp_12v6ah.yaml"
    args = [str(bag), "--params", str(lfp), "--output", str(est_csv), "--output-bag", str(out)]
    code, _, _ = run(args, capsys)
    assert code == 0
    cells, soc, est, usable = [], [], [], []
    with AnyReader([out]) as reader:
        for conn, _, raw in reader.messages():
            msg = reader.deserialize(raw, conn.msgtype)
            if conn.topic == "/battery/state":
                cells.append(len(msg.cell_voltage))
            elif conn.topic == "/battery/soc":
                soc.append(msg.percentage)
            elif conn.topic == "/battery/soc_estimate":
                decoded = decode_estimate(msg)
                est.append(decoded["soc"])
                usable.append(decoded["cell.usable_soc"])
    assert set(cells) == {4}
    np.testing.assert_allclose(soc, usable, atol=1e-6)  # percentage is float32
    with est_csv.open() as fh:
        rows = list(csv.DictReader(fh))
    np.testing.assert_allclose(soc, [float(r["soc"]) for r in rows], atol=1e-6)
    np.testing.assert_allclose(est, [float(r["soc_lumped"]) for r in rows], atol=1e-5)


def test_filter_rate_replays_offline_and_counts_the_same_charge(tmp_path, capsys):
    """``--filter-rate-hz`` (the node's filter_rate_hz): coulomb counting at a fifth of the
    10 Hz input ends on the SoC of a step on every sample; refused with --live."""
    src = write_excerpt(tmp_path / "run.csv")
    ends = []
    for rate in ("0", "2"):
        out_csv = tmp_path / f"out_{rate}.csv"
        args = [str(src), "--params", str(_sla()), "--estimator", "coulomb"]
        code, _, err = run([*args, "--filter-rate-hz", rate, "--output", str(out_csv)], capsys)
        assert code == 0, err
        with out_csv.open() as fh:
            ends.append(float(list(csv.DictReader(fh))[-1]["soc"]))
    # The same charge summed in another grouping: rounding ~1e-16 per sample over 3000.
    assert ends[1] == pytest.approx(ends[0], abs=1e-12)
    code, _, err = run([str(src), "--live", "--filter-rate-hz", "2"], capsys)
    assert code == 2 and "--filter-rate-hz replays offline" in err
