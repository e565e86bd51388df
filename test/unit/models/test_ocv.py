"""OCV curve: PCHIP monotonicity, slope, the inverse, and what the inverse does on plateaus."""

from __future__ import annotations

import numpy as np
import pytest

from soc_estimator_ros.models.ocv import UNINFORMATIVE_SOC_STD, OcvCurve
from soc_estimator_ros.params import load_battery_params

# An LFP-like pack curve with a plateau: 30 mV between 30 % and 70 %.
LFP = OcvCurve(
    [0.0, 0.05, 0.1, 0.2, 0.3, 0.5, 0.7, 0.9, 1.0],
    [11.2, 12.4, 12.72, 12.92, 13.0, 13.015, 13.03, 13.25, 13.5],
)


def test_pchip_is_monotone_and_passes_through_points() -> None:
    soc = np.linspace(-0.1, 1.1, 5001)
    v = LFP.ocv_array(soc)
    assert np.all(np.diff(v) > 0.0)
    for s, ov in zip(LFP.soc_points, LFP.ocv_points_v, strict=True):
        assert LFP.ocv(float(s)) == pytest.approx(ov, abs=1e-12)


def test_slope_matches_finite_difference() -> None:
    for s in np.linspace(0.01, 0.99, 37):
        eps = 1e-7
        fd = (LFP.ocv(s + eps) - LFP.ocv(s - eps)) / (2 * eps)
        assert LFP.slope(s) == pytest.approx(fd, rel=1e-5, abs=1e-6)
        assert LFP.slope(s) > 0.0


def test_inverse_round_trip() -> None:
    for s in np.linspace(0.0, 1.0, 101):
        assert LFP.soc_at(LFP.ocv(s)) == pytest.approx(s, abs=1e-9)


def test_inverse_outside_the_table_is_clipped() -> None:
    assert LFP.soc_at(10.0) == 0.0
    assert LFP.soc_at(14.0) == 1.0


def test_plateau_inverse_carries_large_uncertainty() -> None:
    # 10 mV of OCV uncertainty (a 12-bit ADC over 16 V has a 4 mV step): on the plateau the
    # slope is 0.075 V per unit SoC, so the inverse is worth ~0.13 SoC of std; on the steep
    # knee at 10 % it is ~3 V per unit SoC, ~0.3 % std.
    _, std_plateau = LFP.soc_at_with_std(LFP.ocv(0.5), 0.01)
    _, std_knee = LFP.soc_at_with_std(LFP.ocv(0.1), 0.01)
    assert std_plateau > 0.1
    assert std_knee < 0.01
    _, std_capped = LFP.soc_at_with_std(LFP.ocv(0.5), 1.0)
    assert std_capped == pytest.approx(UNINFORMATIVE_SOC_STD)


def test_interval_std_equals_the_slope_std_on_a_straight_curve() -> None:
    # A straight OCV (1 V per unit SoC): the interval's sides are the linearization's std
    # exactly; the tolerance is the inverse's Newton tolerance (1e-13) times a few.
    line = OcvCurve([0.0, 0.5, 1.0], [12.0, 12.5, 13.0])
    for s in (0.2, 0.5, 0.8):
        soc, std = line.soc_at_with_interval_std(line.ocv(s), 0.02)
        assert soc == pytest.approx(s, abs=1e-12)
        assert std == pytest.approx(line.soc_at_with_std(line.ocv(s), 0.02)[1], abs=1e-9)
        assert std == pytest.approx(0.02, abs=1e-9)


def test_interval_std_sees_a_plateau_beside_the_reading() -> None:
    # At 29 %, at the plateau's foot, the slope (0.33 V per unit SoC) gives 3 points of std
    # for 10 mV; but OCV + 10 mV lands on the plateau, 8 points up: the interval std is that
    # distance (the larger side), 2.7 times the linearized one on this curve.
    v = LFP.ocv(0.29)
    soc, std_lin = LFP.soc_at_with_std(v, 0.01)
    _, std_interval = LFP.soc_at_with_interval_std(v, 0.01)
    hi = LFP.soc_at(v + 0.01)
    assert std_lin < 0.035
    assert std_interval == pytest.approx(hi - soc, abs=1e-12)
    assert std_interval > 2.5 * std_lin
    # Capped as the linearized std is.
    _, capped = LFP.soc_at_with_interval_std(LFP.ocv(0.5), 1.0)
    assert capped == pytest.approx(UNINFORMATIVE_SOC_STD)


@pytest.mark.parametrize(
    ("soc", "ocv", "match"),
    [
        ([0.0, 0.5, 0.4], [1.0, 2.0, 3.0], "SoC points"),
        ([0.0, 0.5, 1.0], [1.0, 2.0, 2.0], "voltages"),
        ([0.0, 1.0], [1.0, float("nan")], "non-finite"),
        ([0.0, 1.5], [1.0, 2.0], "within"),
        ([0.5], [1.0], "length"),
    ],
)
def test_rejects_bad_tables(soc, ocv, match) -> None:
    with pytest.raises(ValueError, match=match):
        OcvCurve(soc, ocv)


def test_bundled_curves_load(repo_root) -> None:
    for name in ("sla_12v5ah.yaml", "lfp_12v6ah.yaml"):
        curve = load_battery_params(repo_root / "config" / name).ocv_curve()
        assert curve.soc_at(curve.ocv(0.55)) == pytest.approx(0.55, abs=1e-9)


def test_vectorized_ocv_matches_the_cubic_within_ten_microvolts() -> None:
    soc = np.linspace(-0.3, 1.3, 20001)
    exact = np.array([LFP.ocv(float(s)) for s in soc])
    assert np.max(np.abs(LFP.ocv_array(soc) - exact)) < 1e-5
