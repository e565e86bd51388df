"""The n-RC Thevenin model's discretization against an independent ODE integration."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from soc_estimator_ros.models import (
    OcvCurve,
    ParamTable,
    RcBranch,
    SurfaceLag,
    TheveninModel,
    TheveninParams,
)
from soc_estimator_ros.models.coulomb import coulomb_step

OCV = OcvCurve([0.0, 0.2, 0.5, 0.8, 1.0], [11.6, 11.9, 12.2, 12.5, 12.8])
TOL_V = 1e-4  # 0.1 mV, as for the RC model: exact discretization, solver residual ~1e-9 V


def make_model(n_rc: int, rng: np.random.Generator, eta: float = 0.95) -> TheveninModel:
    branches = tuple(
        RcBranch(
            ParamTable.constant(float(rng.uniform(0.005, 0.05))),
            ParamTable.constant(float(rng.uniform(500.0, 50000.0))),
        )
        for _ in range(n_rc)
    )
    params = TheveninParams(ParamTable.constant(float(rng.uniform(0.01, 0.05))), branches)
    return TheveninModel(OCV, params, capacity_ah=5.0, coulomb_efficiency_charge=eta)


@pytest.mark.parametrize(("n_rc", "seed"), [(1, 0), (2, 1), (2, 2), (3, 3)])
def test_discretization_matches_ode(n_rc: int, seed: int) -> None:
    rng = np.random.default_rng(seed)
    model = make_model(n_rc, rng)
    rs = [b.r_ohm.at(0.5) for b in model.params.branches]
    cs = [b.c_f.at(0.5) for b in model.params.branches]

    def rhs(_t, y, i):
        eta = 0.95 if i < 0 else 1.0
        d = [-eta * i / (3600.0 * 5.0)]
        d += [-y[1 + j] / (rs[j] * cs[j]) + i / cs[j] for j in range(n_rc)]
        return d

    n = 150
    dts = rng.choice([0.02, 0.1, 1.0, 9.0, 120.0], size=n)
    currents = rng.choice([0.0, 3.0, 25.0, -2.0], size=n)
    x = model.rested_state(0.9)
    y = x.copy()
    for k in range(n):
        sol = solve_ivp(rhs, (0.0, dts[k]), y, args=(currents[k],), rtol=1e-11, atol=1e-13)
        y = sol.y[:, -1]
        x = model.step(x, currents[k], dts[k])
        v_model = model.terminal_voltage(x, currents[k])
        v_ref = OCV.ocv(y[0]) - sum(y[1:]) - model.series_drop_v(y[0], currents[k])
        assert abs(v_model - v_ref) < TOL_V
        assert abs(x[0] - y[0]) < 1e-9


def test_soc_follows_coulomb_counting_with_charge_efficiency() -> None:
    model = make_model(2, np.random.default_rng(5), eta=0.9)
    x = model.step(model.rested_state(0.5), -5.0, 3600.0)  # 1 h of 5 A charge
    assert x[0] == pytest.approx(0.5 + 0.9 * 5.0 / 5.0)
    assert x[0] == pytest.approx(coulomb_step(0.5, -5.0, 3600.0, 5.0, 0.9))
    x = model.step(model.rested_state(0.5), 2.5, 3600.0)  # discharge: eta = 1
    assert x[0] == pytest.approx(0.0)


def test_terminal_voltage_drops_under_discharge() -> None:
    model = make_model(2, np.random.default_rng(6))
    x = model.rested_state(0.8)
    v_rest = model.terminal_voltage(x, 0.0)
    assert v_rest == pytest.approx(OCV.ocv(0.8))
    assert model.terminal_voltage(x, 10.0) < v_rest
    x = model.step(x, 10.0, 30.0)
    assert all(x[1:] > 0.0)  # polarization builds up on discharge


def test_jacobians_match_finite_differences() -> None:
    model = make_model(2, np.random.default_rng(7))
    x = np.array([0.63, 0.02, 0.05])
    h = model.output_jacobian(x, 7.0)
    f = model.transition_jacobian(x, 7.0, 0.1)
    eps = 1e-6
    for j in range(3):
        dx = np.zeros(3)
        dx[j] = eps
        num_h = (model.terminal_voltage(x + dx, 7.0) - model.terminal_voltage(x - dx, 7.0)) / (
            2 * eps
        )
        num_f = (model.step(x + dx, 7.0, 0.1) - model.step(x - dx, 7.0, 0.1)) / (2 * eps)
        assert h[0, j] == pytest.approx(num_h, rel=1e-5, abs=1e-8)
        assert np.allclose(f[:, j], num_f, rtol=1e-6, atol=1e-9)


def test_tables_over_soc_and_temperature() -> None:
    table = ParamTable.from_arrays([0.0, 1.0], [[0.02, 0.04], [0.01, 0.02]], [0.0, 25.0])
    assert table.at(0.5, 0.0) == pytest.approx(0.03)
    assert table.at(0.5, 25.0) == pytest.approx(0.015)
    assert table.at(0.5, 12.5) == pytest.approx(0.0225)
    assert table.at(0.5, -40.0) == pytest.approx(0.03)  # held at the grid edge
    assert table.at(2.0, 25.0) == pytest.approx(0.02)
    assert table.at(0.5, None) == pytest.approx(0.015)  # no temperature: the 25 degC row
    with pytest.raises(ValueError):
        ParamTable.from_arrays([0.0, 1.0], [[0.02, 0.04, 0.05]])


def test_array_evaluation_follows_the_temperature_it_is_given() -> None:
    """at_array keeps the rows blended at the temperatures it has seen; any temperature (or
    None, NaN), new or seen before, must give that temperature's values, never a stale row,
    and the kept rows stay bounded when the temperature never repeats."""
    table = ParamTable.from_arrays(
        [0.0, 0.5, 1.0],
        [[0.02, 0.04, 0.03], [0.01, 0.02, 0.025], [0.005, 0.01, 0.02]],
        [0.0, 25.0, 40.0],
    )
    socs = np.array([-0.1, 0.0, 0.3, 0.5, 0.77, 1.0, 1.2])
    for temp in (25.0, 25.0, 3.0, None, 31.0, float("nan"), 40.0, 55.0, 3.0):
        # 1e-15: a blended row interpolated vs two rows interpolated then blended (rounding).
        expected = [table.at(float(s), temp) for s in socs]
        assert table.at_array(socs, temp) == pytest.approx(expected, rel=1e-14, abs=1e-15)
    for k in range(ParamTable.MAX_BLENDED_ROWS + 10):  # a temperature that never repeats
        temp = 10.0 + 0.01 * k
        assert table.at_array(socs[3:4], temp)[0] == pytest.approx(table.at(0.5, temp), rel=1e-14)
    assert len(table._blended) <= ParamTable.MAX_BLENDED_ROWS
    assert table.at_array(socs, 31.0) == pytest.approx([table.at(s, 31.0) for s in socs])


def test_the_surface_lag_is_a_sum_of_first_order_lags_of_the_current_and_moves_the_ocv_only() -> (
    None
):
    """Each mode z_j follows g_j I with time constant tau_j, exactly for any split of a held
    current, and the voltage reads the OCV at SoC - (z_1 + z_2) while the drop stays at the
    SoC."""
    rng = np.random.default_rng(5)
    plain = make_model(2, rng)
    lag = SurfaceLag(gain_soc_per_a=(0.004, 0.008), tau_s=(60.0, 600.0), soc_max=(1.0, 0.9))
    model = TheveninModel(
        OCV, TheveninParams(plain.params.r0_ohm, plain.params.branches, surface_lag=lag), 5.0
    )
    assert plain.surface_rest() == ()  # the papers' model: no lag
    assert plain.surface_step((), 2.0, 10.0, 0.6) == ()
    assert model.surface_rest() == (0.0, 0.0)
    one = model.surface_step(model.surface_rest(), 2.0, 300.0, 0.6)
    assert one == pytest.approx(
        (0.008 * (1.0 - np.exp(-5.0)), 0.016 * (1.0 - np.exp(-0.5))), rel=1e-12
    )
    # Above its soc_max a mode is not driven: it only relaxes.
    top = model.surface_step(one, 2.0, 300.0, 0.95)
    assert top[1] == pytest.approx(one[1] * np.exp(-0.5), rel=1e-12)
    assert top[0] == pytest.approx(one[0] * np.exp(-5.0) + 0.008 * (1 - np.exp(-5.0)), rel=1e-12)
    z = model.surface_rest()
    for _ in range(3000):
        z = model.surface_step(z, 2.0, 0.1, 0.6)
    assert z == pytest.approx(one, rel=1e-9)  # the recursion's round-off over 3000 steps
    x = np.array([0.6, 0.01, 0.02])
    expected = OCV.ocv(0.6 - sum(z)) - model.series_drop_v(0.6, 3.0) - 0.03
    z_soc = sum(z)
    assert model.terminal_voltage(x, 3.0, None, z_soc) == pytest.approx(expected, abs=1e-12)
    assert model.terminal_voltage(x, 3.0) == pytest.approx(plain.terminal_voltage(x, 3.0))
    xs = np.array([x, [0.3, 0.0, 0.01]])
    batch = model.terminal_voltage_batch(xs, 3.0, None, z_soc)
    # ocv_array interpolates the cubic sampled every 1/4000 of the table: within 1 uV.
    assert batch[0] == pytest.approx(model.terminal_voltage(x, 3.0, None, z_soc), abs=1e-6)
    h = model.output_jacobian(x, 3.0, None, z_soc)
    assert h[0, 0] == pytest.approx(OCV.slope(0.6 - z_soc) - 0.0, abs=1e-9)


def test_a_surface_lag_needs_one_tau_and_soc_max_per_gain() -> None:
    for gains, taus, soc_max in (((), (), ()), ((0.004,), (60.0, 600.0), (1.0,))):
        with pytest.raises(ValueError, match="one tau and one soc_max per gain"):
            SurfaceLag(gain_soc_per_a=gains, tau_s=taus, soc_max=soc_max)


def test_resistances_follow_arrhenius_outside_the_identified_temperatures() -> None:
    """Inside the identified range (plus the margin) the model is the tables, to the bit;
    beyond it every resistance carries exp(Ea/Rg (1/T - 1/T_edge)) and the time constants
    stay (models/thevenin.py)."""
    import math
    from dataclasses import replace

    from conftest import REPO_ROOT

    from soc_estimator_ros.models.thevenin import (
        GAS_CONSTANT_J_PER_MOL_K,
        TemperatureExtrapolation,
    )
    from soc_estimator_ros.params import (
        battery_params_to_dict,
        load_battery_params,
        parse_battery_params,
    )

    battery = load_battery_params(REPO_ROOT / "config" / "lfp_12v6ah.yaml")  # 5 and 25 degC
    assert battery.thevenin_model().resistance_factor(-30.0) == 1.0  # no Ea: edge held
    ea_file = TemperatureExtrapolation(activation_energy_j_per_mol=30_000.0)
    battery = replace(battery, thevenin=replace(battery.thevenin, extrapolation=ea_file))
    model = battery.thevenin_model()
    assert model.trusted_c == (2.0, 28.0)
    assert model.resistance_factor(3.0) == 1.0 and model.resistance_factor(None) == 1.0
    t = -10.0
    expected = math.exp(30_000.0 / GAS_CONSTANT_J_PER_MOL_K * (1 / (t + 273.15) - 1 / 275.15))
    assert model.resistance_factor(t) == pytest.approx(expected, rel=1e-12)
    assert model.extrapolation_c(t) == -12.0 and model.extrapolation_c(30.0) == 2.0
    r_edge, tau_edge = model.branch_at(0, 0.5, 2.0)
    r_cold, tau_cold = model.branch_at(0, 0.5, t)
    assert r_cold == pytest.approx(r_edge * expected, rel=1e-12)
    assert tau_cold == pytest.approx(tau_edge, rel=1e-12)
    drop_edge = model.series_drop_v(0.5, 1e-9, 2.0)  # ~ohmic at a tiny current
    assert model.series_drop_v(0.5, 1e-9, t) == pytest.approx(drop_edge * expected, rel=1e-6)
    # The file's key: absent means the default, and only a non-default value is written.
    bundled = load_battery_params(REPO_ROOT / "config" / "lfp_12v6ah.yaml")
    assert "extrapolation" not in battery_params_to_dict(bundled)["thevenin"]
    own = replace(
        battery,
        thevenin=replace(battery.thevenin, extrapolation=TemperatureExtrapolation(20_000.0, 1.0)),
    )
    tree = battery_params_to_dict(own)
    assert tree["thevenin"]["extrapolation"] == {
        "activation_energy_j_per_mol": 20_000.0,
        "margin_c": 1.0,
    }
    assert parse_battery_params(tree, "t").thevenin.extrapolation.margin_c == 1.0


def test_the_hybrid_weighs_the_voltage_less_outside_the_identified_temperatures() -> None:
    from conftest import REPO_ROOT

    from soc_estimator_ros.estimators import make_estimator
    from soc_estimator_ros.params import load_battery_params

    battery = load_battery_params(REPO_ROOT / "config" / "lfp_12v6ah.yaml")
    hybrid = make_estimator("hybrid", battery, 0.6, 0.1)
    hybrid._temp_c = 20.0
    inside = hybrid._measurement_variance(1.0)
    hybrid._temp_c = -8.0  # 10 degC below the trusted 2 degC
    scale = hybrid.tuning["extrapolation_scale_c"]
    assert hybrid._measurement_variance(1.0) == pytest.approx(inside * (1 + (10 / scale) ** 2))


def _per_sample_voltage(
    model: TheveninModel, soc: np.ndarray, current: np.ndarray, dt: np.ndarray, temps: np.ndarray
) -> np.ndarray:
    """The per-sample loop ``voltage_along`` replaces: step, surface_step, terminal_voltage."""
    x = model.rested_state(float(soc[0]))
    z = model.surface_rest()
    out = np.empty(soc.size)
    for k in range(soc.size):
        temp = None if np.isnan(temps[k]) else float(temps[k])
        if k:
            z = model.surface_step(z, float(current[k - 1]), float(dt[k]), float(x[0]))
            x = model.step(x, float(current[k - 1]), float(dt[k]), temp)
            x[0] = soc[k]
        out[k] = model.terminal_voltage(x, float(current[k]), temp, sum(z))
    return out


@pytest.mark.parametrize("ea_j_per_mol", [0.0, 30_000.0])
def test_the_voltage_along_a_recording_is_the_per_sample_loop_to_the_bit(
    ea_j_per_mol: float,
) -> None:
    """``voltage_along`` (identify.simulate_open_loop's one pass) gives every sample the
    per-sample loop's value exactly: the LFP file's model (tables at 5 and 25 degC, OCV shift,
    kinetics, a saturating branch, two lag modes), with and without Arrhenius, on currents that
    rest, charge and burst, temperatures inside, beyond and without a reading (NaN), steps of
    0.1 s to an hour and a SoC that leaves the tables at both ends."""
    from dataclasses import replace

    from conftest import REPO_ROOT

    from soc_estimator_ros.models.thevenin import TemperatureExtrapolation
    from soc_estimator_ros.params import load_battery_params

    battery = load_battery_params(REPO_ROOT / "config" / "lfp_12v6ah.yaml")
    ext = TemperatureExtrapolation(activation_energy_j_per_mol=ea_j_per_mol)
    battery = replace(battery, thevenin=replace(battery.thevenin, extrapolation=ext))
    model = battery.thevenin_model()
    lag = battery.thevenin.surface_lag
    assert battery.thevenin.kinetic is not None and lag is not None and lag.n_modes == 2
    assert any(b.i_sat_a is not None for b in battery.thevenin.branches)
    assert model.ocv_offset is not None
    rng = np.random.default_rng(7)
    n = 3000
    current = rng.choice([0.0, 0.0, 1.2, -3.0, 18.0, 36.0], n) + rng.normal(0.0, 0.05, n)
    current[rng.random(n) < 0.2] = 0.0
    dt = rng.choice([0.1, 1.0, 60.0, 3600.0], n, p=[0.6, 0.3, 0.09, 0.01])
    temps = rng.choice([-12.0, 2.5, 5.0, 17.3, 25.0, 41.0, np.nan], n)
    soc = np.linspace(1.03, -0.03, n) + rng.normal(0.0, 0.002, n)
    soc[:20] = 1.0  # the tables' top node exactly
    got = model.voltage_along(soc, current, dt, temps)
    assert np.array_equal(got, _per_sample_voltage(model, soc, current, dt, temps))


def test_tables_and_the_ocv_at_each_sample_are_their_scalar_values_to_the_bit() -> None:
    """``ParamTable.at_each`` and ``OcvCurve.ocv_each`` (``voltage_along``'s lookups) give each
    element :meth:`at`'s and :meth:`ocv`'s value exactly: inside, on and beyond the grids, one
    or several temperature rows, one SoC point, a NaN temperature (25 degC)."""
    rng = np.random.default_rng(3)
    soc = np.concatenate([rng.uniform(-0.2, 1.2, 500), [0.0, 0.2, 0.5, 1.0, 0.8]])
    temps = rng.choice([-5.0, 0.0, 12.5, 25.0, 30.0, 50.0, np.nan], soc.size)
    tables = [
        ParamTable((0.1, 0.4, 0.9), ((1.0, 2.0, 5.0),)),
        ParamTable((0.1, 0.4, 0.9), ((1.0, 2.0, 5.0), (3.0, 1.0, 0.5)), (0.0, 25.0)),
        ParamTable((0.5,), ((0.7,),)),
        ParamTable((0.5,), ((0.7,), (0.9,), (1.3,)), (0.0, 10.0, 40.0)),
    ]
    for table in tables:
        each = table.at_each(soc, temps)
        pairs = zip(soc.tolist(), temps.tolist(), strict=True)
        scalar = [table.at(s, None if np.isnan(t) else t) for s, t in pairs]
        assert np.array_equal(each, scalar), table
    assert np.array_equal(OCV.ocv_each(soc), [OCV.ocv(float(s)) for s in soc])


def test_a_voltage_under_load_reads_back_as_its_soc() -> None:
    """A terminal voltage made by eq. 14 with the branches half-way to their steady state reads
    back as its SoC; at rest the reading is the OCV curve's inverse. Tolerance 1e-4: the
    root is interpolated between grid points 0.0025 apart on a smooth curve (chord error
    max|V''| h^2 / 8, below 1e-5 of SoC here)."""
    model = make_model(2, np.random.default_rng(7))
    soc, current_a, std_v = 0.6, 8.0, 0.05
    steady = [b.r_ohm.at(soc) * current_a for b in model.params.branches]
    x = np.array([soc, *(0.5 * v for v in steady)])
    read, std = model.soc_at_terminal_voltage(
        model.terminal_voltage(x, current_a), current_a, std_v
    )
    assert read == pytest.approx(soc, abs=1e-4)
    # The voltage's std and the branches' uniform spread, over the slope (tables constant in
    # SoC here: the slope is the OCV's); 1 %: the slope is the grid's chord, not the tangent.
    expected = np.hypot(std_v, sum(steady) / np.sqrt(12.0)) / OCV.slope(soc)
    assert std == pytest.approx(expected, rel=0.01)
    rest, _ = model.soc_at_terminal_voltage(OCV.ocv(0.35), 0.0, std_v)
    assert rest == pytest.approx(0.35, abs=1e-4)


def test_a_reading_outside_the_trusted_temperatures_knows_no_drop() -> None:
    """Beyond the tables' temperatures (and their margin) the whole modelled drop joins the
    std: it is extrapolated there, not measured (the tables are the same at both temperatures,
    so the SoC read and the slope are too, and the stds differ by the drop alone)."""
    base = make_model(1, np.random.default_rng(8))
    r0 = ParamTable((0.0, 1.0), ((0.02, 0.02), (0.02, 0.02)), temperature_c=(5.0, 25.0))
    model = TheveninModel(OCV, TheveninParams(r0, base.params.branches), capacity_ah=5.0)
    current_a, std_v, v = 5.0, 0.02, OCV.ocv(0.5) - 0.2
    soc_in, inside = model.soc_at_terminal_voltage(v, current_a, std_v, 15.0)
    soc_out, outside = model.soc_at_terminal_voltage(v, current_a, std_v, -10.0)
    assert soc_in == soc_out
    known_v = np.hypot(std_v, model.params.branches[0].r_ohm.at(soc_in) * current_a / np.sqrt(12))
    drop_v = current_a * 0.02 + 0.5 * model.params.branches[0].r_ohm.at(soc_in) * current_a
    assert outside / inside == pytest.approx(np.hypot(known_v, drop_v) / known_v, rel=1e-9)


def test_a_reading_met_at_several_socs_spans_them_all() -> None:
    """Where the drop's tables make the voltage under load fall and rise again over the SoC (a
    flat OCV, R_0 three times higher mid-way), one reading is met at several SoCs: every one
    of them, found here by a scan 100 times finer, lies within the std of the result."""
    flat = OcvCurve([0.0, 0.3, 0.5, 0.7, 1.0], [12.0, 13.0, 13.005, 13.01, 13.4])
    r0 = ParamTable((0.3, 0.5, 0.7), ((0.01, 0.03, 0.01),))
    model = TheveninModel(flat, TheveninParams(r0, ()), capacity_ah=5.0)
    current_a, reading_v = 10.0, 12.805
    soc, std = model.soc_at_terminal_voltage(reading_v, current_a, 0.001)
    fine = np.linspace(0.0, 1.0, 40_001)
    v = np.array([model.terminal_voltage(np.array([s]), current_a) for s in fine])
    roots = fine[np.flatnonzero(np.diff(np.sign(v - reading_v)))]
    assert len(roots) == 3  # the steep part below 0.3, and either side of the dip
    assert np.all(np.abs(roots - soc) <= std + 0.0025)  # + one grid step of the search


def test_a_reading_on_a_bending_curve_spans_the_socs_within_its_std() -> None:
    """Where the curve bends within the reading's std (a flat plateau), the std reaches every
    SoC whose voltage lies within one std of the reading (a scan 100 times finer finds them;
    0.0025: one step of the search's grid), beyond what the slope at the root says."""
    flat = OcvCurve([0.0, 0.3, 0.5, 0.7, 1.0], [12.0, 13.0, 13.005, 13.01, 13.4])
    model = TheveninModel(flat, TheveninParams(ParamTable.constant(0.01), ()), capacity_ah=5.0)
    reading_v, std_v = 13.0075, 0.002
    soc, std = model.soc_at_terminal_voltage(reading_v, 0.0, std_v)
    fine = np.linspace(0.0, 1.0, 40_001)
    near = fine[np.abs(np.array([flat.ocv(s) for s in fine]) - reading_v) <= std_v]
    assert std >= max(soc - near[0], near[-1] - soc) - 0.0025
    assert std > 1.1 * std_v / flat.slope(soc)  # the slope alone says 0.086, the scan 0.103
