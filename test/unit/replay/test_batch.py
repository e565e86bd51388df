"""soc_replay's t2rc_ukf through the batch engine (``replay/batch.py``) against the per-sample
replay (``replay_estimator``): the tracker's rows, statuses, start, counts and FULL, and the
filter's values.

Tolerances: SoC 1e-9 (the issue's), its std 1e-9 relative, the state 1e-9 and the predicted
voltage 1e-9 V: the engine's rounding (test/unit/batch/test_ukf.py); measured 3e-14 here.
Everything the tracker decides (statuses, start, counts, FULL) is compared for equality.
"""

from __future__ import annotations

import csv
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from conftest import BAGS_DIR, REPO_ROOT

from soc_estimator_ros.params import load_battery_params
from soc_estimator_ros.recordings import read_recording
from soc_estimator_ros.replay import cli
from soc_estimator_ros.replay.batch import BATCH_MIN_LANES, batch_eligible, replay_t2rc_batch
from soc_estimator_ros.replay.run import ReplayJob, replay_estimator
from soc_estimator_ros.series import BatterySeries

LFP = load_battery_params(REPO_ROOT / "config" / "lfp_12v6ah.yaml")


def with_bad_samples(s: BatterySeries) -> BatterySeries:
    """Samples the gate rejects (NaN, out of range, duplicate, out of order), a 20 s gap
    and unknown temperatures."""
    v, c, st, t = s.voltage_v.copy(), s.current_a.copy(), s.stamp_ns.copy(), s.temperature_c.copy()
    v[50], v[60], c[70] = np.nan, 100.0, 1e4
    st[80], st[90] = st[79], st[88]
    t[100:120] = np.nan
    st[500:] += 20_000_000_000
    return replace(
        s, voltage_v=v, current_a=c, stamp_ns=st, temperature_c=t, t_s=(st - st[0]) * 1e-9
    )


@pytest.mark.parametrize("initial_soc", ["ocv", "0.7"])
def test_batch_replay_equals_the_per_sample_replay(initial_soc: str) -> None:
    """lfp_validation_1001's end (a CC-CV charge: FULL recalibrates the SoC to 1 at sample
    1130) and a field run with rejected samples, in one engine."""
    full = read_recording(BAGS_DIR / "lfp_validation_1001").window(14000, 17500)
    bad = with_bad_samples(read_recording(BAGS_DIR / "lfp_field_run_2_partial").window(0, 2000))
    recordings = [("full", full), ("bad", bad)]
    got = replay_t2rc_batch(recordings, LFP, initial_soc)
    for (name, series), g in zip(recordings, got, strict=True):
        ref = replay_estimator(series, LFP, "t2rc_ukf", initial_soc, name)
        e, r = g.estimates, ref.estimates
        assert e.status == r.status
        assert (g.start, g.counts, g.input_name) == (ref.start, ref.counts, ref.input_name)
        np.testing.assert_array_equal(g.runtime.full, ref.runtime.full)
        for a, b, tol in (
            (e.soc, r.soc, 1e-9),
            (e.x, r.x, 1e-9),
            (e.voltage_pred_v, r.voltage_pred_v, 1e-9),
        ):
            np.testing.assert_array_equal(np.isnan(a), np.isnan(b))
            np.testing.assert_allclose(a, b, rtol=0, atol=tol, equal_nan=True)
        np.testing.assert_allclose(e.soc_std, r.soc_std, rtol=1e-9, equal_nan=True)
        np.testing.assert_allclose(e.nis, r.nis, rtol=1e-9, atol=1e-12, equal_nan=True)
        np.testing.assert_allclose(e.p, r.p, rtol=1e-9, atol=1e-15, equal_nan=True)
        if ref.accuracy is not None:
            assert g.accuracy is not None
            assert abs(g.accuracy.mae - ref.accuracy.mae) < 1e-9
    assert got[0].runtime.full.sum() > 0  # the recalibration ran
    assert got[1].counts  # so did the gate


def write_csv(path: Path, s: BatterySeries) -> Path:
    with path.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["time_s", "current_a", "voltage_v", "temperature_c", "soc_ref"])
        assert s.soc_ref is not None
        for row in zip(
            s.stamp_ns * 1e-9, s.current_a, s.voltage_v, s.temperature_c, s.soc_ref, strict=True
        ):
            w.writerow([repr(float(v)) for v in row])
    return path


def test_soc_replay_batch_always_prints_what_never_prints(tmp_path, capsys) -> None:
    """``--all`` over three recordings: t2rc_ukf's rows through the engine, the other
    estimators' as before, the table the same and in the same order."""
    s = read_recording(BAGS_DIR / "sla_validation_1003")  # 0.5 s steps: 1500 are 12.5 min
    paths = [
        write_csv(tmp_path / f"part{k}.csv", s.window(k * 3000, k * 3000 + 1500)) for k in range(3)
    ]
    args = [
        *map(str, paths),
        "--params",
        str(REPO_ROOT / "config" / "sla_12v5ah.yaml"),
        "--all",
        "--jobs",
        "1",
    ]
    outs = []
    for mode in ("never", "always"):
        assert cli.main([*args, "--batch", mode]) == 0
        outs.append(capsys.readouterr().out)
    assert outs[0] == outs[1]
    assert outs[0].count("t2rc_ukf") == 6  # a table row and a start line per input


def test_batch_is_for_many_offline_recordings_without_outputs(monkeypatch) -> None:
    job = ReplayJob(path=Path("x.csv"), estimators=("t2rc_ukf", "hybrid"))
    assert batch_eligible(job)
    assert not batch_eligible(replace(job, estimators=("hybrid",)))
    assert not batch_eligible(replace(job, runtime=True))  # --output / --plot
    assert not batch_eligible(replace(job, live=True))
    assert not batch_eligible(replace(job, health=True))
    assert not batch_eligible(replace(job, extras={"output_bag": "out"}))
    calls = []
    monkeypatch.setattr(cli, "replay_jobs_batched", lambda jobs: calls.append(len(jobs)) or {})
    few = [job] * (BATCH_MIN_LANES - 1)
    assert cli._batched("auto", few) == {} and calls == []
    assert cli._batched("never", few * 2) == {} and calls == []
    cli._batched("auto", few + [job])
    cli._batched("always", [job])
    assert calls == [BATCH_MIN_LANES, 1]
