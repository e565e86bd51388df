"""``soc_tune`` end to end on short recordings, and ``objective.py``'s score against an
independent computation of the same numbers.

The recordings are 12-minute CSV excerpts (7200 samples at 10 Hz) of three bundled SLA field
runs, past the 10-minute window the scores start after; t2rc_ukf runs at about 8000 samples a
second, so a candidate costs about a second per recording.
"""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path

import numpy as np
import pytest
from conftest import REPO_ROOT, bag_path

from soc_estimator_ros.estimators import make_estimator
from soc_estimator_ros.evaluation import accuracy, run_estimator
from soc_estimator_ros.params import load_battery_params
from soc_estimator_ros.recordings import read_battery_bag, read_recording
from soc_estimator_ros.tuning import cli, score_recording
from soc_estimator_ros.tuning.cli import main
from soc_estimator_ros.tuning.objective import Score

N = 7200
SLA = REPO_ROOT / "config" / "sla_12v5ah.yaml"
RUNS = ("sla_field_run_1_full_rest", "sla_field_run_2_partial", "sla_field_run_3_cold")


def write_excerpt(path: Path, run: str) -> Path:
    s = read_battery_bag(bag_path(run)).window(0, N)
    assert s.soc_ref is not None
    with path.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["time_s", "current_a", "voltage_v", "temperature_c", "soc_ref"])
        for row in zip(
            s.stamp_ns * 1e-9, s.current_a, s.voltage_v, s.temperature_c, s.soc_ref, strict=True
        ):
            w.writerow([repr(float(v)) for v in row])
    return path


@pytest.fixture(scope="module")
def excerpts(tmp_path_factory) -> list[Path]:
    d = tmp_path_factory.mktemp("tune")
    return [write_excerpt(d / f"{run}.csv", run) for run in RUNS]


def test_the_score_is_the_accuracy_and_coverage_of_the_true_start(excerpts):
    series = read_recording(excerpts[0])
    battery = load_battery_params(SLA)
    tuning = {"r": 0.5}
    score = score_recording(series, battery, "t2rc_ukf", tuning, wrong_start=0.0)
    est = run_estimator(
        make_estimator("t2rc_ukf", battery, float(series.soc_ref[0]), 0.1, tuning), series
    )
    acc = accuracy(series.t_s, est.soc, series.soc_ref)
    after = series.t_s >= 600.0
    cover = np.mean(np.abs(est.soc[after] - series.soc_ref[after]) <= 2 * est.soc_std[after])
    # The same runs computed twice: equal to rounding.
    assert score.mae_pct == pytest.approx(100 * acc.mae, rel=1e-12)
    assert score.max_pct == pytest.approx(100 * acc.max_abs, rel=1e-12)
    assert score.coverage == pytest.approx(cover, abs=1e-12)
    assert math.isnan(score.t_converge_s)
    count = run_estimator(make_estimator("coulomb", battery, float(series.soc_ref[0]), 0.1), series)
    cc_max = np.max(np.abs(count.soc[after] - series.soc_ref[after]))
    assert score.coulomb_max_pct == pytest.approx(100 * cc_max, rel=1e-12)


def test_the_objective_weighs_as_its_docstring_says():
    assert Score(1.0, 2.0, 0.95, math.nan).total == pytest.approx(2.0)  # in the band: no cost
    assert Score(1.0, 2.0, 0.80, 600.0).total == pytest.approx(2.0 + 20 * 0.10 + 1.0)
    assert Score(0.0, 0.0, 1.00, math.inf).total == pytest.approx(20 * 0.02 + 3.0)
    # The do-no-harm term: 2 per point of max beyond coulomb counting's max + 1 point.
    assert Score(1.0, 2.0, 0.95, math.nan, 1.5).total == pytest.approx(2.0)  # within the rule
    assert Score(1.0, 4.0, 0.95, math.nan, 1.5).total == pytest.approx(3.0 + 2 * 1.5)


def test_soc_tune_is_deterministic_and_writes_only_an_accepted_tuning(excerpts, tmp_path, capsys):
    """From a file whose t2rc_ukf block is badly tuned (r = 1e-6 V^2: the filter takes the
    2RC model's volts of error under load for SoC), any r of 0.1-10 V^2 does better on every
    recording, so the tuning is accepted; the same seed gives the same file."""
    bad = tmp_path / "bad.yaml"
    text = SLA.read_text()
    assert "\nfilters:\n" in text
    bad.write_text(text.replace("\nfilters:\n", "\nfilters:\n  t2rc_ukf: {r: 1.0e-06}\n", 1))
    assert load_battery_params(bad).filters["t2rc_ukf"] == {"r": 1e-6}
    args = [
        *map(str, excerpts[:2]),  # two recordings, two folds: 4 runs a call
        "--params",
        str(bad),
        "--estimator",
        "t2rc_ukf",
        "--space",
        "r=0.1:10:log",
        "--trials",
        "1",
        "--folds",
        "2",
        "--wrong-start",
        "0",
        "--jobs",
        "1",
    ]
    out_a, out_b = tmp_path / "a.yaml", tmp_path / "b.yaml"
    code_a = main([*args, "--output", str(out_a)])
    printed_a = capsys.readouterr().out
    code_b = main([*args, "--output", str(out_b)])
    printed_b = capsys.readouterr().out
    assert code_a == code_b == 0, printed_a
    assert printed_a.replace(str(out_a), "") == printed_b.replace(str(out_b), "")
    assert printed_a.count("fold ") == 2 and "held-out mean" in printed_a
    tuned = load_battery_params(out_a)
    assert out_a.read_text() == out_b.read_text().replace("b.yaml", "a.yaml")
    assert 0.1 <= float(tuned.filters["t2rc_ukf"]["r"]) <= 10.0
    assert tuned.thevenin == load_battery_params(SLA).thevenin  # only the filters changed


def test_local_search_moves_the_files_tuning_a_step(excerpts, tmp_path, capsys):
    """``--search local`` from the same badly tuned file: on r's 7 decades (log) a step of
    0.8 moves 1e-6 up by 5.6 decades to 0.398 V^2 (down it is at the bound: no candidate), in
    the range that does better on every recording, so that move is chosen and written."""
    bad = tmp_path / "bad.yaml"
    bad.write_text(
        SLA.read_text().replace("\nfilters:\n", "\nfilters:\n  t2rc_ukf: {r: 1.0e-06}\n", 1)
    )
    out = tmp_path / "local.yaml"
    args = [*map(str, excerpts[:2]), "--params", str(bad), "--output", str(out)]
    args += ["--estimator", "t2rc_ukf", "--space", "r=1e-6:10:log", "--search", "local"]
    args += ["--step", "0.8", "--folds", "2", "--wrong-start", "0", "--jobs", "1"]
    assert main(args) == 0
    printed = capsys.readouterr().out
    assert "chosen on all after 1 move: r 0.3981" in printed, printed
    assert math.isclose(float(load_battery_params(out).filters["t2rc_ukf"]["r"]), 10**-0.4)
    # The header: soc_tune's command, then how the input file was made (its own header).
    header = [line for line in out.read_text().splitlines() if line.startswith("#")]
    assert header[0].startswith("# Tuned by soc_tune (t2rc_ukf) on ")
    assert header[1].startswith("# Regenerate: soc_tune ")
    made = [ln for ln in SLA.read_text().splitlines() if ln.startswith("#")]
    made = [ln for ln in made if not ln.startswith("# Schema:")]
    assert made and header[2:] == [f"# From bad.yaml: {line[2:]}" for line in made]


def test_errors_are_one_line(excerpts, tmp_path, capsys):
    no_ref = tmp_path / "no_ref.csv"
    rows = excerpts[0].read_text().splitlines()
    no_ref.write_text("\n".join(",".join(r.split(",")[:4]) for r in rows) + "\n")
    base = ["--params", str(SLA), "--output", str(tmp_path / "x.yaml"), "--jobs", "1"]
    for extra, needle in (
        ([str(no_ref), str(excerpts[1]), "--folds", "2"], "no reference SoC"),
        ([*map(str, excerpts), "--space", "r=1"], "--space"),
        ([*map(str, excerpts), "--space", "nosuch=1:2"], "no tuning entry 'nosuch'"),
        ([*map(str, excerpts), "--estimator", "ekf"], "no default space"),
        ([*map(str, excerpts), "--search", "local", "--step", "0"], "--step"),
        (
            [*map(str, excerpts[:2]), "--folds", "3", "--trials", "1", "--wrong-start", "0"],
            "--folds",
        ),
    ):
        assert main([*extra, *base]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and needle in err, err
    assert not (tmp_path / "x.yaml").exists()
    # An --output nowhere is said before the search, not after it.
    nowhere = ["--params", str(SLA), "--output", str(tmp_path / "missing" / "x.yaml")]
    assert main([*map(str, excerpts), *nowhere]) == 2
    err = capsys.readouterr().err
    assert err.startswith("soc_tune: error: no directory") and err.count("\n") == 1


def test_a_cached_search_resumes_and_computes_only_what_it_lacks(
    excerpts, tmp_path, capsys, monkeypatch
):
    """``--cache``: a second run of the same command scores nothing and prints the same
    report; with the cache's last tuning lost (a run stopped before it), only that tuning's
    runs are computed again. Counted by wrapping the scoring function (``--jobs 1`` calls it
    in this process)."""
    calls = []
    score = cli._score

    def counted(task):
        calls.append(task[3])
        return score(task)

    monkeypatch.setattr(cli, "_score", counted)
    bad = tmp_path / "bad.yaml"
    bad.write_text(
        SLA.read_text().replace("\nfilters:\n", "\nfilters:\n  t2rc_ukf: {r: 1.0e-06}\n", 1)
    )
    cache = tmp_path / "scores.jsonl"
    args = [*map(str, excerpts[:2]), "--params", str(bad), "--output", str(tmp_path / "o.yaml")]
    args += ["--estimator", "t2rc_ukf", "--space", "r=1e-6:10:log", "--search", "local"]
    args += ["--step", "0.8", "--rounds", "2", "--folds", "2", "--wrong-start", "0"]
    args += ["--jobs", "1", "--cache", str(cache)]
    assert main(args) == 0
    first = capsys.readouterr()
    # Two rounds: 1e-6 and its one move up by 5.6 decades, 0.398 (round 1); from there down
    # is 1e-6 again (scored) and up the bound 10 (round 2): 3 tunings on 2 recordings.
    assert len(calls) == 6 and "0 tunings scored before" in first.err
    lines = cache.read_text().splitlines()
    assert len(lines) == 1 + 3
    calls.clear()
    assert main(args) == 0
    second = capsys.readouterr()
    assert calls == [] and "3 tunings scored before" in second.err
    assert second.out == first.out
    cache.write_text("\n".join(lines[:-1]) + "\n")
    assert main(args) == 0
    third = capsys.readouterr()
    assert len(calls) == 2 and third.out == first.out
    assert json.loads(lines[-1])["values"] == calls[0] == calls[1] == {"r": 10.0}
