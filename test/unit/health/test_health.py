"""Health learning: the capacity's WTLS fit, the R_0 factor's filter, the model's factor, the
rest readings."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from soc_estimator_ros.health import (
    CapacityEstimator,
    CapacityPair,
    OcvAgeing,
    ResistanceFactor,
    fit_capacity,
)
from soc_estimator_ros.health.monitor import HealthMonitor, HealthState, capacity_ageing
from soc_estimator_ros.health.resistance import GATE_RESET, step_observation
from soc_estimator_ros.params import load_battery_params
from soc_estimator_ros.resources import bundled_file


def test_wtls_recovers_a_known_capacity_from_noisy_pairs() -> None:
    rng = np.random.default_rng(7)
    q_true = 4.2
    est = CapacityEstimator(5.0, (0.5) ** 2)  # a prior 19 % off, 10 % std
    for _ in range(12):
        ds_true = rng.uniform(0.3, 0.8)
        pair = CapacityPair(
            charge_ah=q_true * ds_true + rng.normal(0.0, 0.02),
            charge_var_ah2=0.02**2,
            soc_from=1.0,
            soc_from_var=0.0,
            soc_to=1.0 - ds_true + rng.normal(0.0, 0.01),
            soc_to_var=0.01**2,
        )
        est.add(pair)
    # 12 pairs of 1 % SoC noise over ds ~0.55: the fit's own std is ~0.02 Ah; 4 sigma.
    assert abs(est.capacity_ah - q_true) < 4.0 * est.capacity_std_ah
    assert est.capacity_std_ah < 0.05


def test_ocv_ageing_maps_the_readings_below_and_leaves_the_rest() -> None:
    # LFP's form (pivot 0, readings below 0.5): Q_file / Q = 1.25, k = 1.
    lfp = OcvAgeing(exponent=1.0, pivot_soc=0.0, below_soc=0.5, file_capacity_ah=6.0)
    assert lfp.soc(0.2, 4.8) == pytest.approx((0.25, 1.25), rel=1e-12)
    assert lfp.soc(0.9, 4.8) == (0.9, 1.0)  # the top knee: as read
    assert lfp.soc(0.2, 6.0) == (0.2, 1.0)  # a pack of the file's capacity: as read
    # Lead-acid's form (pivot 1): the depth of discharge read grows by the factor.
    sla = OcvAgeing(exponent=1.0, pivot_soc=1.0, below_soc=1.0, file_capacity_ah=6.0)
    assert sla.soc(0.6, 4.8) == pytest.approx((0.5, 1.25), rel=1e-12)
    assert sla.soc(1.0, 4.8) == (1.0, 1.0)  # full stays full


def test_the_fit_reads_an_aged_pack_through_the_law() -> None:
    # An aged pack of 4.5 Ah on a 6 Ah file whose readings below the plateau follow the law at
    # k = 0.7: from full (read 1.0) to 20 % of its capacity, each reading comes out at
    # 0.2 (4.5 / 6)^0.7. Pairs without noise: through the law the fit is the pack's capacity
    # (to the optimizer's 1e-6 of the prior, the weak prior's pull ~1e-4); read as they come,
    # 4-5 % low.
    q_true, q_file, k = 4.5, 6.0, 0.7
    ageing = OcvAgeing(k, 0.0, 0.5, q_file)
    pairs = []
    for s_end in (0.18, 0.22, 0.26):
        s_read = s_end * (q_true / q_file) ** k
        pairs.append(CapacityPair(q_true * (1.0 - s_end), 1e-6, 1.0, 1e-6, s_read, 1e-4))
    q, _ = fit_capacity(pairs, q_file, (0.6 * q_file) ** 2, ageing)
    assert q == pytest.approx(q_true, rel=1e-3)
    plain, _ = fit_capacity(pairs, q_file, (0.6 * q_file) ** 2)
    assert plain / q_true - 1.0 < -0.03


def test_the_bundled_files_carry_the_law_chosen_on_the_tuning_packs() -> None:
    # The least squares over the *_tuning packs' readings (benchmarks/studies/health.py
    # --readings; docs/architecture.md#health): LFP 0.63 below 0.5 (pivot 0), SLA 0.04 with
    # pivot 1, rounded to two digits.
    lfp = load_battery_params(bundled_file("lfp"))
    assert capacity_ageing(lfp) == OcvAgeing(0.63, 0.0, 0.5, lfp.capacity_ah)
    sla = load_battery_params(bundled_file("sla"))
    assert capacity_ageing(sla) == OcvAgeing(0.04, 1.0, 1.0, sla.capacity_ah)


def _rest_readings(idle_a: float, noise_a: float, rest_s: float) -> int:
    """Pairs a monitor on the SLA file makes from a pack that rested at full (the saved state
    says so), was loaded at 2 A to 60 % and rested ``rest_s`` at an idle ``idle_a`` with
    Gaussian sensor noise ``noise_a`` (2 Hz), then loaded again."""
    battery = load_battery_params(bundled_file("sla"))
    q = battery.capacity_ah
    state = replace(HealthState.of_file(battery), stamp_s=-7200.0, current_a=0.0)
    monitor = HealthMonitor(battery, state)
    ocv = battery.rest_ocv_curve()
    rng = np.random.default_rng(11)
    t, soc = 0.0, 1.0
    monitor.update(t, t, 0.0, ocv.ocv(1.0), 25.0, 1.0)
    while soc > 0.6:
        t += 0.5
        soc -= 2.0 * 0.5 / 3600.0 / q
        monitor.update(t, t, 2.0, ocv.ocv(soc) - 2.0 * 0.15, 25.0, soc)
    for _ in range(int(2.0 * rest_s)):
        t += 0.5
        i = idle_a + rng.normal(0.0, noise_a)
        monitor.update(t, t, i, ocv.ocv(soc), 25.0, soc)
    monitor.update(t + 0.5, t + 0.5, 2.0, ocv.ocv(soc) - 0.3, 25.0, soc)
    return len(monitor.capacity.pairs)


def test_a_rest_at_an_idle_near_the_threshold_is_read() -> None:
    # sla_aged86_tuning: 74 mA of idle and offset against the 99-mA rest threshold (0.02 C),
    # 40 mA of sample noise: without the hysteresis the noise ended every rest before its
    # 30 minutes. A 40-minute rest there makes its pair; a load of twice the threshold is
    # no rest.
    assert _rest_readings(0.074, 0.04, 2400.0) == 1
    assert _rest_readings(0.25, 0.0, 2400.0) == 0


def test_the_saved_current_is_low_passed_not_the_last_samples() -> None:
    # A 50 mA idle whose last sample reads 160 mA (one 40-mA step of noise beyond 0.12 A,
    # the LFP rest threshold): the saved state says the run ended at rest (the low-pass of
    # 5 s leaves 50 mA + (160 - 50) (1 - exp(-0.5 / 5)) = 60 mA).
    battery = load_battery_params(bundled_file("lfp"))
    monitor = HealthMonitor(battery)
    for k in range(200):
        monitor.update(0.5 * k, 0.5 * k, 0.05, 13.2, 25.0, 0.9)
    monitor.update(100.0, 100.0, 0.16, 13.2, 25.0, 0.9)
    assert monitor.state().current_a == pytest.approx(0.0605, abs=1e-3)


def test_no_pairs_keeps_the_prior() -> None:
    assert fit_capacity([], 5.0, 0.25) == (5.0, 0.25)


def test_resistance_factor_learns_a_grown_r0_and_rejects_outliers() -> None:
    rng = np.random.default_rng(3)
    f_true, r0 = 1.5, 0.014
    rf = ResistanceFactor(1.0, 0.3**2, 0.0)
    for _ in range(200):
        di = rng.choice([-10.0, 10.0])
        measured = -f_true * r0 * di + rng.normal(0.0, 0.004)
        model = -rf.factor * r0 * di  # the model's answer at its present factor
        obs, var = step_observation(rf.factor, model, measured, di, r0, 0.004, 0.05, 0.05)
        rf.update(obs, var)
    # 200 steps of 0.14 V with 4 mV noise and a 5 % model error: std ~0.004; 5 sigma.
    assert abs(rf.factor - f_true) < 0.02
    assert not rf.update(rf.factor + 50.0 * math.sqrt(rf.var + 0.01), 0.01)
    assert rf.rejected == 1


def test_a_factor_beyond_the_priors_reach_is_learned_not_locked_out() -> None:
    """The aged-75 % LFP pack's steps all say f ~ 10.6 (9.2-11.9) against the prior 1 +- 0.3:
    GATE_RESET rejections in a row on one side widen the prior, then the steps are taken."""
    rng = np.random.default_rng(5)
    rf = ResistanceFactor(1.0, 0.3**2, 0.0)
    taken = [rf.update(10.6 + rng.normal(0.0, 0.45), 0.45**2) for _ in range(100)]
    assert taken[: GATE_RESET - 1] == [False] * (GATE_RESET - 1) and taken[GATE_RESET - 1]
    assert rf.rejected == GATE_RESET - 1
    # 91 observations of std 0.45: the mean's std 0.05; 4 sigma.
    assert abs(rf.factor - 10.6) < 0.2
    # Outliers on alternating sides never make a run: each is rejected.
    for k in range(2 * GATE_RESET):
        assert not rf.update(rf.factor + (-1) ** k * 50.0, 0.01)


def test_factor_one_is_the_files_model_bit_for_bit() -> None:
    model = load_battery_params(bundled_file("sla")).thevenin_model()
    x = np.array([[0.6, 0.01, 0.02], [0.3, 0.0, -0.01]])
    before = model.terminal_voltage_batch(x, 12.0, 25.0)
    model.r0_factor = 1.0
    assert np.array_equal(before, model.terminal_voltage_batch(x, 12.0, 25.0))
    model.r0_factor = 2.0
    r0 = model.params.r0_ohm.at(0.6, 25.0)
    assert model.r0_ohm(0.6, 25.0) == 2.0 * r0
    # Doubling R_0 lowers the voltage under 12 A by exactly 12 A x R_0 (1e-12: float rounding).
    assert abs(before[0] - model.terminal_voltage_batch(x, 12.0, 25.0)[0] - 12.0 * r0) < 1e-12


def _capacity_after_one_rest(battery, soc_end: float) -> float:
    """A pack of the file's capacity that rested at full (the saved state says so), was
    discharged at 3 A to ``soc_end`` and rested 40 minutes at the file's rested OCV there;
    loaded again, the rest's reading is paired with the start's: the capacity learned."""
    q = battery.capacity_ah
    state = replace(HealthState.of_file(battery), stamp_s=-7200.0, current_a=0.0)
    monitor = HealthMonitor(battery, state)
    rested = load_battery_params(bundled_file("lfp")).rest_ocv_curve()  # the pack's truth
    t = 0.0
    monitor.update(t, t, 0.0, rested.ocv(1.0), 25.0, 1.0)
    soc = 1.0
    while soc > soc_end:
        t += 1.0
        soc -= 3.0 / 3600.0 / q
        monitor.update(t, t, 3.0, rested.ocv(soc) - 3.0 * 0.05, 25.0, soc)
    for _ in range(2400):
        t += 1.0
        monitor.update(t, t, 0.0, rested.ocv(soc), 25.0, soc)
    monitor.update(t + 1.0, t + 1.0, 3.0, rested.ocv(soc) - 0.15, 25.0, soc)
    return monitor.capacity_ah


def test_rests_are_read_through_the_rested_ocv() -> None:
    # At 23 % the LFP file's model table (the pulse test's rests every 10 %, the slow discharge
    # between them) sits 17 mV above what the pack rests at (its rate test's rest there):
    # read through it, the rest reads the SoC low and the capacity comes out low; read through
    # the rested table it comes out as the pack's. Tolerance 0.3 %: the model's relaxation
    # left after 40 minutes (< 1 mV) and the pair's count (3 A held exactly).
    battery = load_battery_params(bundled_file("lfp"))
    q = battery.capacity_ah
    learned = _capacity_after_one_rest(battery, 0.23)
    assert abs(learned / q - 1.0) < 0.003
    plain = _capacity_after_one_rest(replace(battery, rest_ocv=None), 0.23)
    assert plain / q - 1.0 < -0.01
