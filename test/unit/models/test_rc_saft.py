"""The Saft RC model's exact discretization against an independent circuit simulation.

The reference integrates the circuit's node equations (KCL at the internal node, seed 000
Fig. 4a) with scipy's ``solve_ivp`` -- it never uses the state-space matrices under test.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from soc_estimator_ros.models.rc_saft import RcModelParams, SaftRcModel

# 0.1 mV: the bound; the discretization is exact, so the residual is the ODE solver's
# tolerance (rtol 1e-10 on ~12 V states gives ~1e-9 V), five orders below the bound.
TOL_V = 1e-4


def circuit_reference(p: RcModelParams, v0: float, times_s: np.ndarray, charge_a: np.ndarray):
    """V_cb, V_cs and V_o at t_k+ from the node equations; ``charge_a[k]`` holds on [t_k, t_k+1)."""

    def rhs(_t, y, i_charge):
        v_cb, v_cs = y
        # Node voltage from KCL: (V_n - V_cb)/R_b + (V_n - V_cs)/R_s = I
        g_b, g_s = 1.0 / p.r_b_ohm, 1.0 / p.r_s_ohm
        v_n = (i_charge + g_b * v_cb + g_s * v_cs) / (g_b + g_s)
        return [(v_n - v_cb) / (p.r_b_ohm * p.c_b_f), (v_n - v_cs) / (p.r_s_ohm * p.c_s_f)]

    def v_o(y, i_charge):
        g_b, g_s = 1.0 / p.r_b_ohm, 1.0 / p.r_s_ohm
        v_n = (i_charge + g_b * y[0] + g_s * y[1]) / (g_b + g_s)
        return v_n + p.r_t_ohm * i_charge

    y = np.array([v0, v0])
    out = [(y[0], y[1], v_o(y, charge_a[0]))]
    for k in range(len(times_s) - 1):
        sol = solve_ivp(
            rhs,
            (times_s[k], times_s[k + 1]),
            y,
            args=(charge_a[k],),
            rtol=1e-10,
            atol=1e-12,
            method="LSODA",
        )
        y = sol.y[:, -1]
        out.append((y[0], y[1], v_o(y, charge_a[k + 1])))
    return np.array(out)


def random_params(rng: np.random.Generator) -> RcModelParams:
    return RcModelParams(
        c_b_f=float(rng.uniform(2e3, 5e4)),
        c_s_f=float(rng.uniform(20.0, 2e3)),
        r_b_ohm=float(rng.uniform(0.005, 0.1)),
        r_s_ohm=float(rng.uniform(0.005, 0.1)),
        r_t_ohm=float(rng.uniform(0.005, 0.1)),
    )


@pytest.mark.parametrize("seed", range(8))
def test_discrete_model_matches_circuit(seed: int) -> None:
    rng = np.random.default_rng(seed)
    p = random_params(rng)
    model = SaftRcModel(p)
    n = 120
    dts = rng.choice([0.01, 0.1, 0.5, 1.0, 7.3, 60.0], size=n - 1)  # variable dt
    times = np.concatenate([[0.0], np.cumsum(dts)])
    current = rng.choice([0.0, 2.0, 15.0, 40.0, -4.0], size=n) * rng.uniform(0.5, 1.0, size=n)
    ref = circuit_reference(p, 12.5, times, -current)  # circuit written charge-positive
    x = model.rested_state(12.5, current[0])
    err = [np.abs(x - ref[0])]
    for k in range(n - 1):
        x = model.step(x, current[k], current[k + 1], dts[k])
        err.append(np.abs(x - ref[k + 1]))
    assert np.max(err) < TOL_V
    # V_o also agrees with the circuit's algebraic output of the two capacitor voltages.
    assert abs(model.consistent_terminal_voltage(x, current[-1]) - x[2]) < TOL_V


def test_paper_b31_typo_is_detected() -> None:
    """Seed 000 eq. 5 as printed (R_s R_s term) leaves the circuit by far more than 0.1 mV."""
    p = RcModelParams(c_b_f=13300.0, c_s_f=270.0, r_b_ohm=0.0375, r_s_ohm=0.02, r_t_ohm=0.03)
    model = SaftRcModel(p)
    s = p.r_b_ohm + p.r_s_ohm
    b31_printed = (
        p.r_b_ohm**2 / (p.c_s_f * s**2)
        - p.r_s_ohm * p.r_s_ohm / (p.c_b_f * p.r_b_ohm * s)
        + p.r_t_ohm / (p.c_s_f * s)
        + p.r_s_ohm * p.r_b_ohm / (p.c_s_f * s**2)
    )
    assert b31_printed != pytest.approx(model.b_c_charge[2], rel=1e-6)
    times = np.arange(0.0, 3600.0, 1.0)
    current = np.full(times.size, 10.0)
    ref = circuit_reference(p, 12.5, times[:50:7], -current[:50:7])
    # Integrate the printed model with the same exact scheme.
    from scipy.linalg import expm

    m = np.zeros((4, 4))
    m[:3, :3] = model.a_c
    m[:3, 3] = model.b_c_charge
    m[2, 3] = b31_printed
    x_good = model.rested_state(12.5, 10.0)
    x_bad = x_good.copy()
    for _k in range(ref.shape[0] - 1):
        e = expm(m * 7.0)
        x_bad = e[:3, :3] @ x_bad - e[:3, 3] * 10.0
        x_good = model.step(x_good, 10.0, 10.0, 7.0)
    assert abs(x_good[2] - ref[-1, 2]) < TOL_V
    assert abs(x_bad[2] - ref[-1, 2]) > 10 * TOL_V


def test_a31_is_minus_a33_and_rest_is_equilibrium() -> None:
    model = SaftRcModel(RcModelParams(9000.0, 300.0, 0.03, 0.02, 0.01))
    assert model.a_c[2, 0] == pytest.approx(-model.a_c[2, 2])
    x = model.rested_state(13.0)
    assert np.allclose(model.step(x, 0.0, 0.0, 3600.0), x, atol=1e-12)


def test_current_sign_discharge_lowers_bulk_voltage() -> None:
    model = SaftRcModel(RcModelParams(9000.0, 300.0, 0.03, 0.02, 0.01))
    x = model.rested_state(13.0, 5.0)
    x1 = model.step(x, 5.0, 5.0, 60.0)  # 5 A discharge for a minute
    assert x1[0] < 13.0 and x1[2] < 13.0
    # Charge balance: C_b dV_cb + C_s dV_cs = -I dt (charge-positive current = -5 A).
    p = model.params
    dq = p.c_b_f * (x1[0] - 13.0) + p.c_s_f * (x1[1] - 13.0)
    assert dq == pytest.approx(-5.0 * 60.0, rel=1e-9)


def test_invalid_dt_raises() -> None:
    model = SaftRcModel(RcModelParams(9000.0, 300.0, 0.03, 0.02, 0.01))
    for dt in (0.0, -1.0, float("nan")):
        with pytest.raises(ValueError):
            model.discretize(dt)
