"""Do no harm where nobody tuned (issue 24), on measured cells: the hybrid against coulomb
counting from the same start, with a file that does not cover the cold.

benchmarks/studies/do_no_harm.py's Panasonic NCR18650PF cases: the file identified from the
25 degC HPPC alone, so the 0 and 10 degC drive cycles lie 12-25 degC outside the identified
temperatures. Split (the script's): the 10 degC cycles are where the guard's rule was looked
at (tuning), the 0 degC cycles the validation. The measured data (../shared/real-data) are read
where they are and never copied; the test skips without them.
"""

from __future__ import annotations

from functools import cache

import numpy as np
import pytest
from conftest import REPO_ROOT, bag_path, load_benchmark

from soc_estimator_ros.params import load_battery_params
from soc_estimator_ros.recordings import read_recording
from soc_estimator_ros.replay.run import battery_file_for

DATA = REPO_ROOT.parent / "shared" / "real-data"

needs_data = pytest.mark.skipif(
    not (DATA / "panasonic18650pf_25C_HPPC.csv").is_file(),
    reason=f"no measured Panasonic cells in {DATA} (../shared/real-data beside the checkout)",
)


@cache
def cases() -> dict:
    study = load_benchmark("studies/do_no_harm")
    found = study.panasonic_cases(DATA, study.LI_ION_EA_J_PER_MOL)  # the script's default file
    return {c.name: (study, c) for c in found if c.split != "inside"}


# Where the rule is not met today: a strict xfail with the measured numbers, the bound untouched.
# None today: the 10 degC US06 cell (margin 1.04 points before) meets it since the hybrid's
# resistance-error state takes part of its cold drop (margin 0.69: max 0.87 %, coulomb 0.18 %).
SHORT: dict[str, str] = {}
COLD = [
    pytest.param(
        name,
        marks=[pytest.mark.xfail(strict=True, reason=f"measured {SHORT[name]}")]
        if name in SHORT
        else [],
        id=name,
    )
    for name in (
        "panasonic18650pf_0C_Cycle_1",
        "panasonic18650pf_0C_LA92",
        "panasonic18650pf_0C_UDDS",
        "panasonic18650pf_0C_US06",
        "panasonic18650pf_10C_Cycle_1",
        "panasonic18650pf_10C_LA92",
        "panasonic18650pf_10C_US06",
    )
]


@needs_data
@pytest.mark.slow
@pytest.mark.parametrize("name", COLD)
def test_hybrid_does_no_harm_outside_its_temperatures(name: str) -> None:
    study, case = cases()[name]
    row = study.score(case, "hybrid")
    # The rule, as it states it: max error at most 1 point above coulomb counting's
    # (same start, std 0.1: the accuracy tests' start). Measured with the guard off: 0 degC
    # margins 8.21 / 0.06 / 3.45 / 6.86 points, coverage 22-100 %; with it 0.00 on all four.
    assert row["margin"] <= 1.0, row
    # The coverage target for the reported sigma: 95 % +- 5 %.
    assert 90.0 <= row["coverage"] <= 100.0, row


def test_the_summary_counts_each_target_per_estimator_and_split() -> None:
    """The script's closing lines, on rows whose counts are known: the rule is margin <= 1
    (1.0 itself meets it), the coverage band is 90-100 % inclusive."""
    study = load_benchmark("studies/do_no_harm")
    row = {"estimator": "hybrid", "split": "validation", "cc_mae": 0.5}
    rows = [
        {**row, "mae": 0.4, "max": 2.9, "margin": 1.0, "coverage": 90.0},
        {**row, "mae": 1.6, "max": 6.1, "margin": 5.2, "coverage": 87.5},
        {**row, "split": "tuning", "mae": 1.0, "max": 3.0, "margin": -0.3, "coverage": 100.0},
    ]
    assert study.summary(rows) == [
        "hybrid on tuning (1): rule met on 1, coverage in 90-100 % on 1, MAE <= 1 and max <= 3 "
        "on 1; mean MAE 1.000 % (coulomb 0.500 %)",
        "hybrid on validation (2): rule met on 1, coverage in 90-100 % on 1, MAE <= 1 and max "
        "<= 3 on 1; mean MAE 1.000 % (coulomb 0.500 %)",
    ]


def test_the_exact_posterior_moves_a_right_start_off_a_plateau_edge() -> None:
    """benchmarks/studies/plateau_posterior.py. On a curve flat (0.1 mV) from 0.4 to 0.8 and
    steep (2 V per unit of SoC) elsewhere, a right start at 0.75 declared with std 0.1 and an
    exact reading of 2 mV std: the reading says "on the flat", the posterior is the prior cut
    to it. Cut at exactly [0.4, 0.8] its mean would be 5.08 points low (scipy's truncnorm);
    the monotone cubic's shoulders widen the flat a little past 0.8, so it moves less (measured
    4.49): bounds 3 to 5.08 points low. On the steep part the reading pins the truth (bound 0.1
    point). On the LFP file at 0.646 (std 0.1, its bias_std_v 20.4 mV) the mean moves 4.0
    points (bound 3); declared with std 0.015 it moves 0.03 (bound 0.5)."""
    from scipy.stats import truncnorm

    from soc_estimator_ros.models.ocv import OcvCurve
    from soc_estimator_ros.params import load_battery_params

    study = load_benchmark("studies/plateau_posterior")
    curve = OcvCurve([0.0, 0.4, 0.8, 1.0], [12.0, 12.8, 12.8001, 13.2001])
    cut = float(truncnorm.mean(-3.5, 0.5, loc=0.75, scale=0.1)) - 0.75  # [0.4, 0.8] in std
    shift = study.posterior(curve, 0.75, 0.1, 0.002).shift
    assert cut - 1e-9 <= shift < -0.03, (shift, cut)
    assert abs(study.posterior(curve, 0.9, 0.1, 0.002).shift) < 0.001
    lfp = load_battery_params(REPO_ROOT / "config" / "lfp_12v6ah.yaml")
    sigma_v = study.model_error_v(lfp)
    ocv = lfp.thevenin_model().ocv
    assert study.posterior(ocv, 0.646, 0.1, sigma_v).shift < -0.03
    assert abs(study.posterior(ocv, 0.646, 0.015, sigma_v).shift) < 0.005


def test_the_tracker_path_is_the_bare_estimator_until_the_charger_stops() -> None:
    """``--tracker`` (``estimates(..., tracker=True)``): the estimator as the node runs it, the
    same numbers to the bit up to the dock charger's stop in ``lfp_validation_1005`` (9512 s,
    test_full_charge.py), where FULL recalibrates even the charge count to 1 (the bare count
    reads 98.45 % there against the reference's 99.89 %)."""
    study = load_benchmark("studies/do_no_harm")
    s = read_recording(bag_path("lfp_validation_1005"))
    assert s.soc_ref is not None
    battery = load_battery_params(battery_file_for(s))
    case = study.Case("lfp_validation_1005", "validation", s, s.soc_ref, battery)
    stop = int(np.searchsorted(s.t_s, 9512.0))
    for name in ("coulomb", "hybrid"):
        bare = study.estimates(case, name, float(s.soc_ref[0]), 0.1)
        node = study.estimates(case, name, float(s.soc_ref[0]), 0.1, tracker=True)
        np.testing.assert_array_equal(node.soc[:stop], bare.soc[:stop])
        np.testing.assert_array_equal(node.soc_std[:stop], bare.soc_std[:stop])
        assert node.soc[stop] == 1.0
        if name == "coulomb":  # what the recalibration corrects: 1.4 points
            assert bare.soc[stop] == pytest.approx(0.9845, abs=1e-4)


@cache
def bundled_validation() -> dict:
    study = load_benchmark("studies/do_no_harm")
    return {c.name: (study, c) for c in study.corpus_cases(REPO_ROOT / "bags")}


@pytest.mark.slow
@pytest.mark.parametrize("bag", ["sla_validation_1003", "lfp_validation_1001"])
@pytest.mark.parametrize("name", ["t2rc_ukf", "ekf", "dcc_ekf", "rc_kf"])
def test_every_filter_that_publishes_sigma_holds_the_truth(bag: str, name: str) -> None:
    """Issue 24 item 5 for the seed papers' filters (base.py ``_published``: the variance
    floored by a charge count from the same start), on the bundled validation missions from a
    start as sure as a resumed state (std 0.015). Measured without the floor: coverage 16.5 /
    0 / 0 / 2.7 % (SLA 1003) and 73.0 / 0 / 53.8 / 6.2 % (LFP 1001); with it 100 % on all
    eight, the mean sigma 1.8-6.0 % but rc_kf's on LFP (17.5 %, its MAE 17.0 %)."""
    study, case = bundled_validation()[bag]
    row = study.score(case, name, 0.015)
    # The band for the +-2 sigma coverage after the 10-minute window.
    assert 90.0 <= row["coverage"] <= 100.0, row
