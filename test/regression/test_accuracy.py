"""Accuracy of the estimators on the physics-simulated field-run bags (issue: estimators).

The bags were made by PyBaMM's electrochemical models (tools/make_bags.py), never by this
package's equivalent-circuit models, so these numbers measure the estimators, not the models'
agreement with themselves. Each (bag, estimator, initial SoC) run happens once per test session
(``runs`` fixture) and several tests read it.

Bounds are the issue's targets, with the window and thresholds it states:
* ``hybrid``: MAE <= 1.0 %, max <= 3 % after a 10-minute window, both chemistries; from a
  +-30 % initial error, |error| < 2 % within 10 minutes and for the rest of the run;
* ``t2rc_ukf`` with a correct start: MAE <= 1.0 %;
* ``rc_kf``: the paper's finding, usable on SLA (seed 000: 2.2 % MAE) and poor on LFP.
"""

from __future__ import annotations

from functools import cache
from pathlib import Path

import numpy as np
import pytest
from conftest import HYBRID_FIELD_RUNS, REPO_ROOT, hybrid_on_field_run

from soc_estimator_ros.estimators import make_estimator
from soc_estimator_ros.evaluation import Accuracy, accuracy, run_estimator
from soc_estimator_ros.params import load_battery_params

ROOT = REPO_ROOT
BAGS = ROOT / "bags"
BATTERY_FILES = {
    "sla": ROOT / "config" / "sla_12v5ah.yaml",
    "lfp": ROOT / "config" / "lfp_12v6ah.yaml",
}
FIELD_RUNS = sorted(p for p in BAGS.glob("*_field_run_*") if p.is_dir())
WINDOW_S = 600.0  # the 10-minute convergence window
INITIAL_SOC_STD = 0.1  # what a user's guess is worth; the same for correct and wrong starts


def chemistry_of(bag: Path) -> str:
    return bag.name.split("_", 1)[0]


@cache
def series_of(bag: Path):
    from soc_estimator_ros.recordings import read_battery_bag

    return read_battery_bag(bag)


@cache
def run(bag: Path, estimator: str, soc_offset: float) -> tuple[Accuracy, np.ndarray, np.ndarray]:
    """Run ``estimator`` on ``bag`` from the reference SoC plus ``soc_offset`` (clipped)."""
    series = series_of(bag)
    battery = load_battery_params(BATTERY_FILES[chemistry_of(bag)])
    soc0 = float(np.clip(series.soc_ref[0] + soc_offset, 0.0, 1.0))
    est = make_estimator(estimator, battery, soc0, INITIAL_SOC_STD)
    out = run_estimator(est, series)
    acc = accuracy(out.t_s, out.soc, series.soc_ref, window_s=WINDOW_S)
    return acc, out.t_s - out.t_s[0], out.soc - series.soc_ref


pytestmark = pytest.mark.skipif(not FIELD_RUNS, reason="no field-run bags under bags/")

# Where a target is not met today: (test, bag, start offset) -> the measured numbers. These stay
# strict xfails, with the bound untouched, so they flag the day they pass. SLA run 2
# (coulomb counting from the same start: MAE 0.00 %) sits on the bound: the UKF reads its start
# (std 0.1) 0.7 point high in the first minutes and the count, as uncertain, follows it; 0.9987 %
# before the guard's fusion, 1.0011 % with it (docs/accuracy.md "The guard fused").
SHORTFALLS: dict[tuple[str, str, float], str] = {
    ("hybrid", "sla_field_run_2_partial", 0.0): "MAE 1.0011 %, max 1.08 %",
}


def cases(estimator: str, offsets: tuple[float, ...]) -> list:
    out = []
    for bag in FIELD_RUNS:
        for off in offsets:
            why = SHORTFALLS.get((estimator, bag.name, off))
            marks = [pytest.mark.xfail(strict=True, reason=f"measured {why}")] if why else []
            out.append(pytest.param(bag, off, marks=marks, id=f"{bag.name}-{off:+.1f}"))
    return out


@HYBRID_FIELD_RUNS
@pytest.mark.parametrize(("bag", "offset"), cases("hybrid", (0.0,)))
def test_hybrid_correct_start(bag: Path, offset: float) -> None:
    # Through the tracker, shared with test_levels_field_runs (conftest): the same estimates
    # as run(bag, "hybrid", 0.0) to the bit (the tracker adds the gate, which passes them all).
    assert offset == 0.0
    series, soc, _, _ = hybrid_on_field_run(bag.name)
    acc = accuracy(series.t_s, soc, series.soc_ref, window_s=WINDOW_S)
    assert acc.mae <= 0.010, acc  # issue target: MAE <= 1.0 %
    assert acc.max_abs <= 0.030, acc  # issue target: max <= 3 %


@pytest.mark.parametrize(("bag", "offset"), cases("t2rc_ukf", (0.0,)))
def test_t2rc_ukf_correct_start(bag: Path, offset: float) -> None:
    acc, _, _ = run(bag, "t2rc_ukf", offset)
    assert acc.mae <= 0.010, acc  # issue target: MAE <= 1.0 % with a correct start


@pytest.mark.parametrize(("bag", "offset"), cases("hybrid", (0.3, -0.3)))
def test_hybrid_converges_from_a_wrong_start(bag: Path, offset: float) -> None:
    soc_ref0 = float(series_of(bag).soc_ref[0])
    if not 0.0 <= soc_ref0 + offset <= 1.0:
        pytest.skip(f"reference starts at {soc_ref0:.2f}: a {offset:+.0%} start is outside [0, 1]")
    acc, t_rel, err = run(bag, "hybrid", offset)
    after = t_rel >= WINDOW_S
    # Issue target: |error| < 2 % within 10 minutes, and it stays there.
    assert np.max(np.abs(err[after])) < 0.02, acc
    assert acc.max_abs <= 0.030 and acc.mae <= 0.010, acc


@pytest.mark.xfail(
    strict=True,
    reason="measured SLA MAE up to 12.8 % (paper 2.2 %): the RC model identified at 0.2 C "
    "carries the same 10-30 A voltage bias as the 2RC, and RC+KF has no load gate",
)
def test_rc_kf_reproduces_the_paper_finding() -> None:
    """Seed 000: RC+KF is usable on SLA (2.2 % MAE there) and fails on LFP's flat OCV."""
    chemistries = {chemistry_of(b) for b in FIELD_RUNS}
    if not {"sla", "lfp"} <= chemistries:
        pytest.skip("needs field runs of both chemistries")
    sla = [run(b, "rc_kf", 0.0)[0] for b in FIELD_RUNS if chemistry_of(b) == "sla"]
    sla_mae = max(a.mae for a in sla)
    assert sla_mae <= 0.05, sla  # usable: within about twice the paper's 2.2 %
    # The LFP runs only once SLA passes (today it does not: the xfail's reason).
    lfp = [run(b, "rc_kf", 0.0)[0] for b in FIELD_RUNS if chemistry_of(b) == "lfp"]
    lfp_mae = max(a.mae for a in lfp)
    assert lfp_mae > sla_mae, (sla, lfp)  # and clearly worse on LFP's plateau
