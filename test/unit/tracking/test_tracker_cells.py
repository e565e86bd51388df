"""The tracker with cell voltages (issue 25): the pack's estimate is the same to the bit with or
without them, the cells ride beside it, a sample with another cell count is not estimated,
and without cell voltages nothing changes (``StepResult.cells`` None, ``usable_soc`` the SoC);
a restart resumes the cells with the SoC."""

from __future__ import annotations

from functools import cache

import numpy as np
from conftest import REPO_ROOT, bag_path

from soc_estimator_ros.params import load_battery_params
from soc_estimator_ros.recordings import read_battery_bag
from soc_estimator_ros.series import BatterySeries
from soc_estimator_ros.tracking import GateConfig, Sample, Tracker, TrackerConfig
from soc_estimator_ros.tracking.persistence import resume_decision, save_state

LFP = load_battery_params(REPO_ROOT / "config" / "lfp_12v6ah.yaml")
N = 1500


@cache
def series() -> BatterySeries:
    return read_battery_bag(bag_path("lfp4s_cells_1_full")).window(0, N)


def run(cells: bool) -> tuple[Tracker, list]:
    s = series()
    assert s.cell_voltage_v is not None
    tr = Tracker(LFP, GateConfig.from_limits(LFP.limits), TrackerConfig(initial_soc="ocv"))
    out = []
    for k in range(len(s)):
        sample = Sample(
            int(s.stamp_ns[k]),
            float(s.current_a[k]),
            float(s.voltage_v[k]),
            float(s.temperature_c[k]),
            cell_voltage_v=tuple(float(v) for v in s.cell_voltage_v[k]) if cells else (),
        )
        out.append(tr.process(sample))
    return tr, out


def test_pack_estimate_is_the_same_to_the_bit_with_or_without_cells() -> None:
    _, with_cells = run(True)
    tr, without = run(False)
    for a, b in zip(with_cells, without, strict=True):
        assert a.verdict is b.verdict
        assert a.estimate is not None and b.estimate is not None
        assert a.estimate.soc == b.estimate.soc
        assert a.estimate.soc_var == b.estimate.soc_var
        np.testing.assert_array_equal(a.estimate.x, b.estimate.x)
        np.testing.assert_array_equal(a.estimate.p, b.estimate.p)
        assert b.cells is None and a.cells is not None
    # Without cells the published SoC is the pack's estimate itself.
    assert tr.cells is None and tr.last_cells is None
    assert tr.usable_soc == without[-1].estimate.soc


def test_cells_are_estimated_and_the_usable_soc_published() -> None:
    tr, out = run(True)
    last = out[-1].cells
    assert last is not None and last.cells == 4
    assert tr.usable_soc == last.usable_soc
    assert last.usable_soc <= float(np.min(last.soc)) + 0.05  # the weakest, capacity +-3 sigma
    np.testing.assert_array_equal(tr.cells.rejected if tr.cells else None, [0, 0, 0, 0])


def test_another_cell_count_is_not_estimated() -> None:
    tr = Tracker(LFP, GateConfig.from_limits(LFP.limits), TrackerConfig(initial_soc=0.5))
    r = tr.process(Sample(1_000_000_000, 0.3, 13.2, cell_voltage_v=(3.3, 3.3, 3.3)))
    assert r.accepted and r.cells is None
    assert tr.cells_miscounted == 1


def test_the_cells_resume_with_the_soc(tmp_path) -> None:
    # A restart keeps the cells' deviations: the saved state carries them, the new tracker's
    # bank starts from them with d's variance grown by its random walk over the time between
    # (exact arithmetic: the same numbers through YAML, which writes floats exactly).
    tr, _ = run(True)
    saved = tr.saved_state()
    assert saved is not None and saved.cells is not None and saved.cells.cells == 4
    x0 = np.array(saved.cells.x)
    assert np.abs(x0[:, 0]).max() > 1e-4  # the deviations moved from their prior of 0
    path = tmp_path / "state.yaml"
    save_state(path, saved)
    gap_s = 600.0
    s = series()
    stamp_ns = int(s.stamp_ns[-1]) + int(gap_s * 1e9)
    resumed = Tracker(
        LFP,
        GateConfig.from_limits(LFP.limits),
        TrackerConfig(initial_soc="resume"),
        resume=lambda now_s: resume_decision(path, now_s, 3600.0, LFP.name),
    )
    cells_v = tuple(float(v) for v in s.cell_voltage_v[-1])
    resumed.process(Sample(stamp_ns, 0.3, float(s.voltage_v[-1]), 25.0, cell_voltage_v=cells_v))
    assert resumed.cells is not None
    f = resumed.cells.filter
    walk = LFP.cells.soc_walk_per_hour**2 * gap_s / 3600.0
    # The bank's first sample has no predict (no sample before it) and no rest long enough
    # for an update (60 s), so it holds what was resumed: x as saved (to the bit, YAML writes floats
    # exactly), d's variance grown by the walk over the gap.
    np.testing.assert_array_equal(f.x, x0)
    np.testing.assert_array_equal(f.p[:, 0, 0], np.array(saved.cells.p)[:, 0, 0] + walk)
    # A pack of another cell count (or no saved cells) starts from the priors.
    other = Tracker(
        LFP,
        GateConfig.from_limits(LFP.limits),
        TrackerConfig(initial_soc="resume"),
        resume=lambda now_s: resume_decision(path, now_s, 3600.0, LFP.name),
    )
    for k in range(2):
        other.process(
            Sample(stamp_ns + k * 1_000_000_000, 0.3, 13.2, 25.0, cell_voltage_v=(3.3,) * 3)
        )
    assert other.cells is None and other.cells_miscounted >= 1
