"""The OCV hysteresis' fit (identification/hysteresis.py).

The synthetic test's voltage is the bundled LFP file's own model plus a known hysteresis: it
checks the fit's arithmetic (what it recovers when the model is right), not the model; the
PyBaMM test (``bags/lfp_hysteresis_test``) is the regression suite's.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from conftest import REPO_ROOT, bag_path

from soc_estimator_ros.identification.hysteresis import branch_along, fit_hysteresis, rest_ends
from soc_estimator_ros.identification.identify import simulate_open_loop
from soc_estimator_ros.models.hysteresis import Hysteresis
from soc_estimator_ros.params import load_battery_params
from soc_estimator_ros.recordings import read_recording
from soc_estimator_ros.series import BatterySeries

LFP = load_battery_params(REPO_ROOT / "config" / "lfp_12v6ah.yaml")
TRUE = Hysteresis(gap_v=0.08, rate_per_soc=50.0)
DT_S = 2.0


def two_way_current() -> np.ndarray:
    """From full: 10 % discharge pulses at 0.2 C to 40 %, charge pulses of 2, 3 and 5 %, 10 %
    charges to 70 %, discharge pulses of 2, 3 and 5 %; 1 h of rest after each (0.5 Hz)."""
    amps = 0.2 * LFP.capacity_ah
    pulse_s = 1800.0  # 10 % at 0.2 C

    def seg(current_a: float, seconds: float) -> list[float]:
        return [current_a] * round(seconds / DT_S)

    out = seg(0.0, 600.0)
    plan = [10] * 6 + [-2, -3, -5] + [-10] * 2 + [2, 3, 5]  # % of capacity, + discharge
    for pct in plan:
        out += seg(np.sign(pct) * amps, abs(pct) / 10 * pulse_s) + seg(0.0, 3600.0)
    return np.array(out)


def synthetic_test() -> BatterySeries:
    i = two_way_current()
    t = np.arange(i.size) * DT_S
    bare = BatterySeries(
        t_s=t,
        stamp_ns=(t * 1e9).astype(np.int64),
        current_a=i,
        voltage_v=np.zeros_like(t),
        temperature_c=np.full_like(t, 25.0),
    )
    v_model, _ = simulate_open_loop(LFP, bare, 1.0)
    b = branch_along(TRUE, bare, LFP.capacity_ah, LFP.coulomb_efficiency_charge)
    return replace(bare, voltage_v=v_model + TRUE.gap_v * b)


def test_the_rests_after_each_direction_are_found() -> None:
    after_charge, after_discharge = rest_ends(synthetic_test())
    assert (len(after_charge), len(after_discharge)) == (5, 9)


def test_a_known_hysteresis_comes_back() -> None:
    fit = fit_hysteresis(LFP, synthetic_test(), [])
    assert fit.hysteresis is not None
    # The gap to 1 mV and the rate to one grid step (12 %): the grid's 50.1 is next to 50.
    assert fit.hysteresis.gap_v == pytest.approx(TRUE.gap_v, abs=1e-3)
    assert fit.hysteresis.rate_per_soc == pytest.approx(TRUE.rate_per_soc, rel=0.12)
    assert fit.rms_after_v < 0.1 * fit.rms_before_v
    assert abs(fit.offset_v) < 1e-3  # the model's OCV is the discharge branch here


def test_a_model_on_the_middle_of_the_branches_still_gives_the_gap() -> None:
    """A template's OCV halfway between the branches (the bundled LFP file on the PyBaMM
    hysteretic pack): the common offset goes to ``c``, the gap stays the branches' gap."""
    test = synthetic_test()
    fit = fit_hysteresis(LFP, replace(test, voltage_v=test.voltage_v - 0.04), [])
    assert fit.hysteresis is not None
    assert fit.hysteresis.gap_v == pytest.approx(TRUE.gap_v, abs=1e-3)  # as above
    assert fit.offset_v == pytest.approx(-0.04, abs=1e-3)


def test_no_hysteresis_is_told_from_the_model_alone() -> None:
    test = synthetic_test()
    v_model, _ = simulate_open_loop(LFP, test, 1.0)
    noisy = v_model + np.random.default_rng(0).normal(0.0, 0.002, v_model.size)
    fit = fit_hysteresis(LFP, replace(test, voltage_v=noisy), [])
    assert fit.hysteresis is None and "standard errors" in fit.why


def test_a_discharge_only_pulse_test_gives_none_and_says_why() -> None:
    test = read_recording(bag_path("lfp_pulse_test"))
    fit = fit_hysteresis(LFP, test, [])
    assert fit.hysteresis is None
    assert fit.rests_after_charge == 0 and "after a charge" in fit.why
