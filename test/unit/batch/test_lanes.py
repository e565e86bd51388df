"""Recordings as lanes: padding of ragged recordings, lanes sharing a recording, the run.

The engine itself is compared with the per-sample path in test_ukf.py; here a run over
ragged lanes must equal each recording run alone (tolerance 1e-15: per-lane arithmetic is
elementwise, only the lanes around it differ).
"""

from __future__ import annotations

import numpy as np
import pytest
from conftest import BAGS_DIR, REPO_ROOT

from soc_estimator_ros.batch import BatchError, BatchT2rcUkf, LaneInputs, LaneStatus, run_lanes
from soc_estimator_ros.params import load_battery_params
from soc_estimator_ros.recordings import read_recording

LFP = load_battery_params(REPO_ROOT / "config" / "lfp_12v6ah.yaml")


def test_ragged_recordings_of_other_time_bases_equal_each_alone() -> None:
    """0.5 Hz and 0.1 s recordings of different lengths in one run: the shorter is frozen
    after its end (its last state kept), each lane equals its recording run alone."""
    a = read_recording(BAGS_DIR / "lfp_aged75_m1")  # 0.5 s steps
    b = read_recording(BAGS_DIR / "lfp_field_run_1_full_rest")  # 0.1 s steps
    inputs = LaneInputs.from_series([a, b], lane_recording=[0, 1, 1], max_samples=400)
    short = a.window(0, 250)
    ragged = LaneInputs.from_series([short, b], lane_recording=[0, 1, 1], max_samples=400)
    assert ragged.present[0].sum() == 250 and ragged.present[1].all()
    soc0 = np.array([0.8, 0.9, 0.5])
    run = run_lanes(BatchT2rcUkf(LFP, soc0), ragged)
    full = run_lanes(BatchT2rcUkf(LFP, soc0), inputs)
    assert run is not None and full is not None
    assert run.soc.shape == (400, 3)
    # lane 0 up to its end equals the unpadded run; then frozen
    np.testing.assert_allclose(run.soc[:250, 0], full.soc[:250, 0], rtol=0, atol=1e-15)
    assert np.all(run.status[250:, 0] == LaneStatus.FROZEN)
    assert np.all(run.soc[250:, 0] == run.soc[249, 0])
    assert np.all(run.soc_var[250:, 0] == run.soc_var[249, 0])
    assert np.all(np.isnan(run.voltage_pred_v[250:, 0]))
    # lanes 1 and 2 read one recording from two starts
    for lane, soc in ((1, 0.9), (2, 0.5)):
        alone = run_lanes(
            BatchT2rcUkf(LFP, np.array([soc])), LaneInputs.from_series([b], max_samples=400)
        )
        assert alone is not None
        np.testing.assert_allclose(run.soc[:, lane], alone.soc[:, 0], rtol=0, atol=1e-15)
    assert run.status[0].tolist() == [LaneStatus.INITIALIZED] * 3
    assert np.all(run.status[1:250] == LaneStatus.OK)


def test_run_without_keeping_outputs() -> None:
    b = read_recording(BAGS_DIR / "lfp_field_run_1_full_rest")
    inputs = LaneInputs.from_series([b], lane_recording=[0, 0], max_samples=50)
    engine = BatchT2rcUkf(LFP, np.array([0.9, 0.6]))
    assert run_lanes(engine, inputs, keep=False) is None
    assert np.all(engine.t_last_s == b.t_s[49])


def test_lane_input_errors() -> None:
    b = read_recording(BAGS_DIR / "lfp_field_run_1_full_rest")
    with pytest.raises(BatchError, match="no recording"):
        LaneInputs.from_series([])
    with pytest.raises(BatchError, match=r"one recording index in \[0, 1\) per lane"):
        LaneInputs.from_series([b], lane_recording=[0, 1], max_samples=10)
    inputs = LaneInputs.from_series([b], max_samples=10)
    with pytest.raises(BatchError, match="the engine has 2 lanes, the inputs 1"):
        run_lanes(BatchT2rcUkf(LFP, np.array([0.5, 0.5])), inputs)
    with pytest.raises(BatchError, match="arrays of one shape"):
        LaneInputs(
            inputs.t_s,
            inputs.current_a[:, :5],
            inputs.voltage_v,
            inputs.temperature_c,
            inputs.present,
            inputs.lane_recording,
        )
