"""The do-no-harm guard (estimators/guard.py) and the hybrid that publishes through it."""

from __future__ import annotations

import math

import numpy as np
import pytest
from conftest import REPO_ROOT
from scipy.stats import norm

from soc_estimator_ros.estimators import make_estimator
from soc_estimator_ros.estimators.guard import ChargeCount, CountErrorModel, guard
from soc_estimator_ros.estimators.hybrid import Hybrid
from soc_estimator_ros.params import load_battery_params

SLA = load_battery_params(REPO_ROOT / "config" / "sla_12v5ah.yaml")
ERRORS = CountErrorModel(current_offset_std_a=0.02, current_gain_std=0.005, capacity_std_frac=0.03)


@pytest.mark.parametrize(("d", "prior"), [(0.0, 0.9), (0.02, 0.9), (0.05, 0.5), (0.2, 0.99)])
def test_guard_is_the_mixture_of_the_two_hypotheses(d: float, prior: float) -> None:
    u_var, c, c_var = 0.01**2, 0.6, 0.015**2
    out = guard(c + d, u_var, c, c_var, prior)
    # The weight by Bayes' rule with scipy's normal density, and the uniform density 1/2.
    right = prior * norm.pdf(d, 0.0, math.sqrt(u_var + c_var))
    w = right / (right + (1.0 - prior) * 0.5)
    assert out.model_weight == pytest.approx(w, rel=1e-12)
    # Under "the model holds" the two readings fused by their variances, at the worst
    # correlation (the variance of a weighted sum of two errors correlated by 1).
    a = c_var / (u_var + c_var)
    f, f_std = c + a * d, (1 - a) * math.sqrt(c_var) + a * math.sqrt(u_var)
    # The published moments are the mixture's, integrated on a grid: 2e-5 wide over +-12 sigma
    # of both components, so the Riemann sums are exact to about 1e-9 (relative 1e-6 asked).
    x = np.arange(c - 0.5, c + d + 0.5, 2e-5)
    pdf = w * norm.pdf(x, f, f_std) + (1 - w) * norm.pdf(x, c, math.sqrt(c_var))
    pdf /= pdf.sum()
    mean = float(np.sum(x * pdf))
    assert out.soc == pytest.approx(mean, rel=1e-6)
    assert out.soc_var == pytest.approx(float(np.sum((x - mean) ** 2 * pdf)), rel=1e-6)


def test_guard_fuses_an_agreeing_filter_and_drops_a_stray_one() -> None:
    agree = guard(0.601, 1e-4, 0.6, 1e-4, 0.9)  # as sure as the count: half its move
    assert agree.model_weight > 0.99 and abs(agree.soc - 0.6005) < 1e-5
    assert agree.soc_var == pytest.approx(1e-4, rel=1e-3)  # no surer than either
    # A filter surer than the count carries the SoC, one less sure moves it by its share.
    assert guard(0.62, 1e-6, 0.6, 1e-4, 0.9).soc == pytest.approx(0.62, abs=5e-4)
    assert guard(0.62, 0.025**2, 0.6, 0.015**2, 0.9).soc == pytest.approx(
        0.6 + 0.02 * 0.015**2 / (0.015**2 + 0.025**2), abs=1e-3
    )
    stray = guard(0.75, 1e-4, 0.6, 1e-4, 0.9)  # 10.6 sigma apart
    assert stray.model_weight < 1e-12 and stray.soc == pytest.approx(0.6, abs=1e-12)
    assert stray.soc_var == pytest.approx(1e-4, rel=1e-9)  # the count's, as it is published


def test_count_variance_is_the_error_budget() -> None:
    count = ChargeCount(ERRORS, capacity_ah=5.0, efficiency_charge=0.9)
    count.anchor(0.8, 1e-4)
    for _ in range(3600):
        count.step(1.0, 1.0)  # one hour at 1 A: 0.2 of 5 Ah
    assert count.soc == pytest.approx(0.6, abs=1e-12)
    offset = 0.02 * 3600.0 / (3600.0 * 5.0)  # 20 mA for an hour, over 5 Ah
    expected = 1e-4 + offset**2 + (0.005**2 + 0.03**2) * 0.2**2
    assert count.var == pytest.approx(expected, rel=1e-9)
    # Charging counts with the coulomb efficiency, as the estimators' model does.
    count.anchor(0.5, 1e-4)
    count.step(-5.0, 360.0)
    assert count.soc == pytest.approx(0.5 + 0.9 * 5.0 * 360.0 / 3600.0 / 5.0, abs=1e-12)


def test_count_fuse_is_a_scalar_kalman_update_and_clips() -> None:
    count = ChargeCount(ERRORS, capacity_ah=5.0, efficiency_charge=1.0)
    count.anchor(0.5, 0.01)
    count.fuse(0.1, 1.0, 0.01)  # K = 0.5
    assert count.soc == pytest.approx(0.55) and count.var == pytest.approx(0.005)
    count.fuse(0.0, 1.0, 1e-9, var_floor=1e-4)
    assert count.var == pytest.approx(1e-4)  # never surer than the floor
    count.anchor(0.5, 1e-6)  # surer than the floor already: it moves, its variance stays
    count.fuse(0.1, 1.0, 1e-4, var_floor=1e-4)  # K = 1e-6 / (1e-6 + 1e-4) = 1 / 101
    assert count.soc == pytest.approx(0.5 + 0.1 / 101.0, rel=1e-12)
    assert count.var == pytest.approx(1e-6, rel=1e-12)
    count.anchor(0.999, 1e-4)
    count.step(-5.0, 3600.0)  # an hour of 1 C charge from full: clipped, the excess is variance
    assert count.soc == 1.0 and count.var > 0.9


def test_a_reading_of_the_filter_keeps_the_counts_growth() -> None:
    """``reanchor=False`` (the filter's SoC, whose error persists): the count moves, the
    reduction comes off the anchor's variance, and the sensor's and capacity's growth since the
    anchor goes on, where a re-anchor would restart it from nothing."""
    count = ChargeCount(ERRORS, capacity_ah=5.0, efficiency_charge=1.0)
    count.anchor(0.8, 0.015**2)
    for _ in range(1800):
        count.step(5.0, 1.0)  # half an hour at 1 C: 0.5 moved
    growth = count.var - 0.015**2
    count.fuse(0.01, 1.0, 1.0, reanchor=False)  # a weak reading
    k = (0.015**2 + growth) / (0.015**2 + growth + 1.0)
    assert count.soc == pytest.approx(0.3 + k * 0.01, rel=1e-9)
    assert count.var == pytest.approx((1 - k) * (0.015**2 + growth), rel=1e-9)
    assert count.var - count.var_anchor == pytest.approx(growth, rel=1e-9)  # the growth kept
    for _ in range(360):
        count.step(5.0, 1.0)  # 0.1 more: the capacity's and gain's share grows with 0.6 moved
    offset = 0.02 * 2160.0 / 3600.0 / 5.0
    assert count.var == pytest.approx(
        (1 - k) * (0.015**2 + growth) - growth + offset**2 + (0.005**2 + 0.03**2) * 0.6**2,
        rel=1e-6,
    )
    # A reading that takes more than the anchor's variance re-anchors.
    count.fuse(0.0, 1.0, 1e-6, reanchor=False)
    assert count.var_anchor == pytest.approx(count.var) and count.soc_anchor == count.soc


def feed(est, minutes: float, current_a: float, voltage_v: float, temp_c: float) -> None:
    for k in range(int(minutes * 600)):
        est.step(0.1 * k, current_a, voltage_v, temp_c)


def test_outside_the_envelope_the_published_soc_keeps_to_the_count() -> None:
    """A voltage 0.3 below what the counted SoC gives, at 0.1 C, 25 degC below the SLA file's
    identified range (5-25 degC): the UKF follows the voltage, the published SoC does not."""
    est = make_estimator("hybrid", SLA, 0.8, 0.02)
    ocv_low = est.model.ocv.ocv(0.5)
    feed(est, 20.0, 0.5, ocv_low, -20.0)
    counted = 0.8 - 0.5 * 1200.0 / 3600.0 / SLA.capacity_ah
    assert est.count.soc == pytest.approx(counted, abs=1e-3)  # 1e-3: 0.1 s zero-order hold
    assert est.x[0] < counted - 0.1  # the UKF went with the voltage
    assert abs(est.soc - counted) < 0.005  # the published SoC did not
    off = make_estimator("hybrid", SLA, 0.8, 0.02, tuning={"model_prior": 1.0})
    feed(off, 20.0, 0.5, ocv_low, -20.0)
    assert off.soc == float(off.x[0]) and off.soc_var == float(off.p[0, 0])  # the guard off


def test_inside_the_envelope_a_wrong_start_is_followed() -> None:
    """The same voltage at 25 degC, from a start 0.3 too high with std 0.1 (a 3-sigma error):
    the UKF corrects it at light load and the count follows the trusted UKF."""
    est = make_estimator("hybrid", SLA, 0.8, 0.1)
    feed(est, 10.0, 0.5, est.model.ocv.ocv(0.5), 25.0)
    assert abs(est.soc - float(est.x[0])) < 0.02  # the 2 % within 10 minutes
    assert est.x[0] < 0.6


LFP = load_battery_params(REPO_ROOT / "config" / "lfp_12v6ah.yaml")


@pytest.mark.parametrize("soc", [0.1, 0.38, 0.65])
def test_the_filters_soc_floor_is_what_the_models_error_hides(soc: float) -> None:
    """Item 7's floor of the UKF's SoC variance, on the LFP file's OCV and model error with the
    code's default ``model_soc_std`` (0.01), at a steep SoC (0.1: the model_soc_std), a sloped
    one (0.38: bias_std_v over the OCV slope, 1.7 %) and the flat plateau (0.65:
    flat_soc_std_max); the guard reads the UKF's variance no smaller (exact: the same max over
    the same floats). The file's own ``model_soc_std`` (0.025) lies above ``flat_soc_std_max``
    (0.02), so with it the floor is ``model_soc_std`` at all three."""
    default = {**LFP.filters["hybrid"], "model_soc_std": Hybrid.default_tuning["model_soc_std"]}
    est = make_estimator("hybrid", LFP, soc, 1e-4, tuning=default)
    t = est.tuning
    hidden = t["bias_std_v"] / abs(est.model.ocv.slope(soc))
    expected = max(t["model_soc_std"], min(hidden, t["flat_soc_std_max"]))
    assert math.sqrt(est._model_soc_var()) == pytest.approx(expected, rel=1e-12)
    which = {0.1: t["model_soc_std"], 0.38: hidden, 0.65: t["flat_soc_std_max"]}[soc]
    assert expected == which  # each SoC is the case it is named for
    g = est.guarded()
    # The start's P (1e-8) is below the floor: the mixture of the UKF at the floor fused with
    # the count at the start's variance, and the count, d = 0 (no disagreement).
    a = 1e-8 / (expected**2 + 1e-8)
    fused_var = ((1 - a) * 1e-4 + a * expected) ** 2
    assert g.soc_var == pytest.approx(
        g.model_weight * fused_var + (1 - g.model_weight) * 1e-8, rel=1e-9
    )
    tuning = {**default, "flat_soc_std_max": 0.0}  # the flat part of the floor off
    off = make_estimator("hybrid", LFP, soc, 1e-4, tuning=tuning)
    assert off._model_soc_var() == t["model_soc_std"] ** 2
    as_filed = make_estimator("hybrid", LFP, soc, 1e-4)
    assert as_filed._model_soc_var() == LFP.filters["hybrid"]["model_soc_std"] ** 2


def test_outside_the_envelope_a_knee_still_corrects_the_count() -> None:
    """At -3 degC (the LFP file is trusted from 2 degC), a start 30 points low at a full
    pack's voltage under 0.36 A (lfp_tuning_1004's start): the OCV's top knee tells the SoC
    through a model volts wrong, so the count follows the UKF there
    (``outside_follow_soc_max``); on the plateau at the same temperature it does not, and
    inside the range it always does."""
    est = make_estimator("hybrid", LFP, 0.70, 0.15)
    feed(est, 10.0, 0.36, est.model.ocv.ocv(0.995), -3.0)
    assert est.x[0] > 0.95  # the UKF read the knee
    assert est.count.soc > 0.95 and est.soc > 0.95  # and the count followed it
    assert est._resolves_outside(-3.0)
    est.kf.x[0] = 0.65  # the plateau: 20.4 mV grown 2.7-fold, a 45 mV/unit slope
    assert not est._resolves_outside(-3.0)
    assert est._resolves_outside(20.0)
    off = make_estimator(
        "hybrid", LFP, 0.70, 0.15, tuning={**LFP.filters["hybrid"], "outside_follow_soc_max": 0}
    )
    feed(off, 10.0, 0.36, off.model.ocv.ocv(0.995), -3.0)
    assert off.x[0] > 0.95 and off.soc < 0.75  # without it the published SoC keeps the count


def test_a_rated_capacity_widens_the_filters_floor_by_the_ocv_axis() -> None:
    """A file whose capacity is a rating given to ``soc_identify`` (the 4S Li-ion pack's 5.0
    Ah, on a pack of 5.14) carries ``ocv_axis_std_frac`` 0.03: the OCV table's SoC axis is off
    by ``(1 - soc)`` times the rating's error, and the floor of the UKF's SoC variance adds
    ``(0.03 (1 - soc))^2`` (exact: the same floats). Such a pack, 2.8 % above its rating and
    rested at 57 %, reads its OCV as 55.8 % through the file. From a sure start there (std
    0.015), after 40 minutes of rest, measured on the bundled 4S Li-ion file with the key set:
    published -1.06 points with sigma 1.59 (without the term -1.17 with sigma 1.00: the error
    outside one sigma); the bounds are those two facts."""
    li = load_battery_params(REPO_ROOT / "config" / "li_ion_4s_chen2020.yaml")
    assert "ocv_axis_std_frac" not in li.filters["hybrid"]  # its capacity is measured
    rated = {**li.filters["hybrid"], "ocv_axis_std_frac": 0.03}
    est = make_estimator("hybrid", li, 0.57, 0.015, tuning=rated)
    off = make_estimator("hybrid", li, 0.57, 0.015)
    axis = 0.03 * (1.0 - 0.57)
    assert est._model_soc_var() == pytest.approx(off._model_soc_var() + axis**2, rel=1e-12)
    rest_v = est.model.ocv.ocv(0.57 - (1.0 - 0.57) * 0.028)
    for e in (est, off):
        for k in range(40 * 60 * 2):  # 2 Hz
            e.step(0.5 * k, 0.0, rest_v, 25.0)
    err, err_off = est.soc - 0.57, off.soc - 0.57
    assert err < 0.0 and abs(err) < abs(err_off)  # less dragged
    assert abs(err) <= math.sqrt(est.soc_var)  # and its sigma holds the error
    assert abs(err_off) > math.sqrt(off.soc_var)  # where without the term it did not


FLOORED = ["t2rc_ukf", "ekf", "dcc_ekf", "rc_kf"]


@pytest.mark.parametrize("name", FLOORED)
def test_a_filter_without_a_guard_publishes_its_distance_from_the_count(name: str) -> None:
    """Issue 24 item 5 (base.py ``_published``): a voltage 0.3 below what the counted SoC gives,
    at 0.1 C for 20 minutes from 0.8 with std 0.02 (as the guard's tests above): each filter
    goes with the voltage and its own ``P`` stays small; the published variance is the
    squared distance from the count plus the count's variance, the SoC the filter's."""
    est = make_estimator(name, SLA, 0.8, 0.02)
    feed(est, 20.0, 0.5, est.battery.ocv_curve().ocv(0.5), 25.0)
    count = est.floor_count
    counted = 0.8 - 0.5 * 1200.0 / 3600.0 / SLA.capacity_ah
    assert count.soc == pytest.approx(counted, abs=1e-3)  # 1e-3: 0.1 s zero-order hold
    # The count's budget is the file's (the guard's entries of filters.hybrid).
    offset = 0.02 * 1199.9 / 3600.0 / SLA.capacity_ah
    budget = 0.02**2 + offset**2 + (0.005**2 + 0.03**2) * (count.soc - 0.8) ** 2
    assert count.var == pytest.approx(budget, rel=1e-9)  # rounding only
    out = est.last
    assert out.soc == est.soc and est.soc < counted - 0.05  # dragged, not moved by the floor
    assert est.soc_var < (est.soc - count.soc) ** 2  # its own P does not show it
    assert out.soc_var == pytest.approx((est.soc - count.soc) ** 2 + count.var, rel=1e-12)
    # What a saved state and a handover keep (tracking/tracker.py) is the published variance.
    assert est.published_soc_var == out.soc_var


@pytest.mark.parametrize("name", FLOORED)
def test_the_floors_count_starts_with_the_filter_and_follows_its_capacity(name: str) -> None:
    est = make_estimator(name, SLA, 0.8, 0.02)
    est.step(0.0, 1.0, 12.6)
    est.reset_soc(0.4, 0.05)
    assert (est.floor_count.soc, est.floor_count.var) == (0.4, pytest.approx(0.05**2))
    est.start_from(10.0, 0.6, 1e-3, 1.0)
    assert (est.floor_count.soc, est.floor_count.var) == (0.6, pytest.approx(1e-3))
    est.set_health(4.0, 1.0)
    assert est.floor_count.capacity_ah == 4.0
    # A gap widens the count as it widens the filter (base.py's gap rule).
    before = est.floor_count.var
    est.step(610.0, 1.0, 12.6)
    gap_std = est.time_policy.gap_current_std_a * 600.0 / 3600.0 / 4.0
    assert est.floor_count.var >= before + gap_std**2


@pytest.mark.parametrize("name", ["hybrid", "coulomb"])
def test_the_guarded_hybrid_and_the_count_itself_carry_no_floor(name: str) -> None:
    assert make_estimator(name, SLA, 0.8, 0.02).floor_count is None
