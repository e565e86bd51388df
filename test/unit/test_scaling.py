"""Scaling a chemistry's file to another pack (scaling.py): the scaled file's models and
estimators are the file's pack divided into (or multiplied by) cells, exactly."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from conftest import REPO_ROOT

from soc_estimator_ros.estimators import ESTIMATORS, make_estimator
from soc_estimator_ros.models.rc_saft import RcModelParams, SaftRcModel
from soc_estimator_ros.models.thevenin import TheveninModel
from soc_estimator_ros.params import (
    BatteryParams,
    ChargeSettings,
    HealthSettings,
    Limits,
    battery_params_to_dict,
    load_battery_params,
    parse_battery_params,
)
from soc_estimator_ros.scaling import (
    CHARGE_UNITS,
    HEALTH_UNITS,
    LIMITS_UNITS,
    RC_MODEL_UNITS,
    TUNING_UNITS,
    scale_battery,
)

CONFIG = REPO_ROOT / "config"

# (file, cells, rated Ah): n = 2, q = 2 (powers of two: exact); n = 2, q = 4; n = 1/4,
# q = 1.1/6 (not a power of two: every product rounds).
CASES = [
    ("lfp_12v6ah.yaml", 8, 12.0),
    ("sla_12v5ah.yaml", 12, 20.0),
    ("lfp_12v6ah.yaml", 1, 1.1),
]

# Float rounding: each scaled value is the file's times n or q, rounded once (half an ulp,
# 1.1e-16 relative); a model sample adds a few dozen such operations, so 1e-12 relative is a
# thousand-fold margin over the rounding and far below any real (unit) mistake (a factor
# n or q off).
REL_MODEL = 1e-12


def _factors(battery: BatteryParams, cells: int, rated_ah: float) -> tuple[float, float]:
    return cells / battery.cells_in_series, rated_ah / battery.nominal_capacity_ah


def _profile() -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Times (s), currents in C (discharge positive), temperatures (degC): 1 Hz, a wrong start
    at rest, light and heavy loads (above the hybrids' 6 C gate), a 22 min rest (past
    rest_min_s), a charge, a gap and a cold part outside the identified 5-25 degC (+3 margin)."""
    segments = [  # (seconds, C-rate, degC)
        (60, 0.0, 25.0),
        (400, 1.0, 25.0),
        (20, 7.0, 25.0),
        (120, 0.1, 25.0),
        (1320, 0.0, 25.0),
        (300, -0.5, 25.0),
        (200, 2.0, 0.0),
        (100, 0.05, 0.0),
    ]
    c_rate = np.concatenate([np.full(s, c) for s, c, _ in segments])
    temps = np.concatenate([np.full(s, t) for s, _, t in segments])
    t_s = np.arange(c_rate.size, dtype=float)
    t_s[2000:] += 30.0  # a 31 s gap (above the estimators' 5 s max step)
    dt = np.diff(t_s, prepend=t_s[:1])
    return t_s, dt, c_rate, temps


def _run_thevenin(
    model: TheveninModel, soc0: float, current_a: np.ndarray, dt: np.ndarray, temps: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Open loop from rest: SoC and terminal voltage at every sample (the filters' loop)."""
    x = model.rested_state(soc0)
    z = model.surface_rest()
    soc, v = np.empty(current_a.size), np.empty(current_a.size)
    for k in range(current_a.size):
        if k:
            z = model.surface_step(z, current_a[k - 1], dt[k], float(x[0]))
            x = model.step(x, current_a[k - 1], dt[k], temps[k])
        soc[k] = x[0]
        v[k] = model.terminal_voltage(x, current_a[k], temps[k], sum(z))
    return soc, v


def _run_rc(
    params: RcModelParams, ocv_v: float, current_a: np.ndarray, dt: np.ndarray
) -> np.ndarray:
    model = SaftRcModel(params)
    x = model.rested_state(ocv_v, current_a[0])
    v = [model.terminal_voltage(x)]
    for k in range(1, current_a.size):
        x = model.step(x, current_a[k - 1], current_a[k], dt[k])
        v.append(model.terminal_voltage(x))
    return np.array(v)


@pytest.mark.parametrize(("file", "cells", "rated_ah"), CASES)
def test_scaled_models_are_the_pack_in_cells(file: str, cells: int, rated_ah: float) -> None:
    b = load_battery_params(CONFIG / file)
    s = scale_battery(b, cells, rated_ah)
    n, q = _factors(b, cells, rated_ah)
    _, dt, c_rate, temps = _profile()
    amps = c_rate * b.nominal_capacity_ah
    soc_b, v_b = _run_thevenin(b.thevenin_model(), 0.9, amps, dt, temps)
    soc_s, v_s = _run_thevenin(s.thevenin_model(), 0.9, amps * q, dt, temps)
    np.testing.assert_allclose(v_s, n * v_b, rtol=REL_MODEL, atol=0.0)
    # The SoC count: I q / (3600 Q q) rounds at most once more per sample than I / (3600 Q),
    # 1e-16 per sample over 2520 samples.
    np.testing.assert_allclose(soc_s, soc_b, rtol=0.0, atol=1e-12)
    # The vectorized path (identification's) along the same SoC.
    along_b = b.thevenin_model().voltage_along(soc_b, amps, dt, temps)
    along_s = s.thevenin_model().voltage_along(soc_s, amps * q, dt, temps)
    np.testing.assert_allclose(along_s, n * along_b, rtol=REL_MODEL, atol=0.0)

    curve_b, curve_s = b.ocv_curve(), s.ocv_curve()
    grid = np.linspace(-0.05, 1.05, 221)
    ocv_b = np.array([curve_b.ocv(x) for x in grid])
    ocv_s = np.array([curve_s.ocv(x) for x in grid])
    np.testing.assert_allclose(ocv_s, n * ocv_b, rtol=REL_MODEL, atol=0.0)
    # Its inverse: Newton stops at 1e-13 in SoC (models/ocv.py), so 1e-12 is its tolerance.
    soc_back = np.array([curve_s.soc_at(n * v) for v in ocv_b[20:-20]])
    np.testing.assert_allclose(soc_back, grid[20:-20], rtol=0.0, atol=1e-12)

    # The Saft RC model: its exact discretization (expm) of matrices whose entries are the
    # file's to rounding; expm's Pade result keeps that to ~1e-14, within REL_MODEL.
    rc_b = _run_rc(b.rc_model, curve_b.ocv(0.9), amps, dt)
    rc_s = _run_rc(s.rc_model, curve_s.ocv(0.9), amps * q, dt)
    np.testing.assert_allclose(rc_s, n * rc_b, rtol=REL_MODEL, atol=0.0)


# The estimators' SoC on the scaled file against the file's. The states in volts are n times
# the file's and every variance is scaled to match, so each filter runs the file's arithmetic
# up to rounding (measured: 0 for the powers of two; for n = 1/4, q = 1.1/6 at most 2e-15,
# and 8e-11 for dcc_ekf, whose EKF phase amplifies the rounding the way the EKF below does):
# 1e-9 is over ten times that. Two exceptions, each with its cause:
SOC_ATOL = 1e-9
# rc_kf adds an absolute 1e-10 V^2 to its P0 (rc_kf.py), not scaled with the pack's volts; on
# LFP's plateau its SoC readout OCV^-1(V_cb) turns that into 7e-8 (n = 2) and 1.4e-6 (n = 1/4)
# of SoC (measured), well within 1e-5, still far below a unit mistake (a factor n in a variance
# moves this SoC by whole percent).
RC_KF_ATOL = 1e-5
# The EKF on the LFP file in this profile is chaotic: on the file itself, inputs changed by one
# ulp move its SoC by 1.9e-2 by the end (measured), so the rounding of q = 1.1/6 does the same.
# There the scaled run must stay within twice that sensitivity, measured in the test: scaling
# adds nothing the filter does not do to its own rounding.
CHAOTIC = {("ekf", "lfp_12v6ah.yaml", 1)}


def _run_estimator(
    name: str, battery: BatteryParams, amps: np.ndarray, volts: np.ndarray
) -> np.ndarray:
    t_s, _, _, temps = _profile()
    est = make_estimator(name, battery, 0.6, 0.1)  # a wrong start: 0.6 for a pack at 0.9
    return np.array([est.step(t_s[k], amps[k], volts[k], temps[k]).soc for k in range(t_s.size)])


@pytest.mark.parametrize(("file", "cells", "rated_ah"), CASES)
@pytest.mark.parametrize("name", sorted(ESTIMATORS))
def test_estimators_see_the_same_pack(name: str, file: str, cells: int, rated_ah: float) -> None:
    b = load_battery_params(CONFIG / file)
    s = scale_battery(b, cells, rated_ah)
    n, q = _factors(b, cells, rated_ah)
    _, dt, c_rate, temps = _profile()
    amps = c_rate * b.nominal_capacity_ah
    _, true_v = _run_thevenin(b.thevenin_model(), 0.9, amps, dt, temps)
    # Sensor noise (10 mV, 1 % of 1 C), seeded, so the filters have innovations to weigh.
    rng = np.random.default_rng(26)
    volts = true_v + rng.normal(0.0, 0.01, true_v.size)
    amps = amps + rng.normal(0.0, 0.01 * b.nominal_capacity_ah, amps.size)
    soc_b = _run_estimator(name, b, amps, volts)
    soc_s = _run_estimator(name, s, q * amps, n * volts)
    # The filter moved (the start was 0.3 off): the comparison is not of two idle counts.
    assert np.max(np.abs(soc_b - 0.6)) > 0.05
    atol = RC_KF_ATOL if name == "rc_kf" else SOC_ATOL
    if (name, file, cells) in CHAOTIC:
        ulp = 1.0 + 2.0**-52
        own = np.max(np.abs(_run_estimator(name, b, amps * ulp, volts * ulp) - soc_b))
        assert own > 1e-3  # still chaotic: else this exception must go
        atol = 2.0 * own
    np.testing.assert_allclose(soc_s, soc_b, rtol=0.0, atol=atol)


# The battery files (the node's ROS parameters file lives beside them).
BATTERY_FILES = sorted(p.name for p in CONFIG.glob("*.yaml") if "schema_version" in p.read_text())


@pytest.mark.parametrize("file", BATTERY_FILES)
def test_the_files_own_pack_is_the_file(file: str) -> None:
    b = load_battery_params(CONFIG / file)
    assert scale_battery(b) == b
    assert scale_battery(b, b.cells_in_series, b.nominal_capacity_ah) == b
    assert scale_battery(b, capacity_ah=b.nominal_capacity_ah) is not b  # a new object


def test_a_scaled_file_names_its_pack_and_keeps_the_rest() -> None:
    b = load_battery_params(CONFIG / "lfp_12v6ah.yaml")
    s = scale_battery(b, 8, 12.0)
    assert s.name == "RoyPow 12 V 6 Ah LFP (seed 000) scaled to 8S 12 Ah"
    assert s.source.startswith(b.source) and "from 4S 6 Ah to 8S 12 Ah" in s.source
    assert (s.cells_in_series, s.nominal_capacity_ah) == (8, 12.0)
    assert s.capacity_ah == pytest.approx(2.0 * b.capacity_ah, rel=1e-15)
    assert s.limits.voltage_max_v == 29.2 and s.limits.current_max_discharge_a == 120.0
    assert s.limits.soc_min == b.limits.soc_min and s.limits.temperature_min_c == -20.0
    assert s.health.voltage_noise_std_v == 0.008 and s.health.current_noise_std_a == 0.1
    assert s.health.rest_min_s == b.health.rest_min_s
    assert s.filters["hybrid"]["r_per_a"] == 0.1  # V/A: x n / q = 1
    assert s.filters["hybrid"]["bias_std_v"] == 2.0 * b.filters["hybrid"]["bias_std_v"]
    assert s.filters["hybrid"]["update_c_rate_max"] == 6.2  # a C-rate: kept
    assert s.filters["t2rc_ukf"]["r"] == 16.0  # V^2: x n^2
    assert s.filters["coulomb"]["current_std_a"] == 0.1  # the default 0.05 A, x q
    lag_b, lag_s = b.thevenin.surface_lag, s.thevenin.surface_lag
    assert lag_b is not None and lag_s is not None
    assert lag_s.gain_soc_per_a == tuple(g / 2.0 for g in lag_b.gain_soc_per_a)
    assert lag_s.tau_s == lag_b.tau_s
    # The charge section (not in the bundled files): volts x n, the rest kept.
    charged = dataclasses.replace(b, charge=ChargeSettings(14.4, 0.1, 0.05, 60.0))
    assert scale_battery(charged, 8, 12.0).charge == ChargeSettings(28.8, 0.2, 0.05, 60.0)
    assert b == load_battery_params(CONFIG / "lfp_12v6ah.yaml")  # not mutated


@pytest.mark.parametrize(("file", "cells", "rated_ah"), CASES)
def test_round_trip_through_the_file_form(file: str, cells: int, rated_ah: float) -> None:
    s = scale_battery(load_battery_params(CONFIG / file), cells, rated_ah)
    assert parse_battery_params(battery_params_to_dict(s), "scaled") == s


def test_one_cell_file_scaled_to_a_pack_round_trips() -> None:
    """The NCR18650PF cell as a 4S 2P pack (n = 4, q = 2): its one-cell hybrid tuning scaled."""
    b = load_battery_params(CONFIG / "li_ion_ncr18650pf.yaml")
    s = scale_battery(b, 4, 5.8)
    assert s.filters["hybrid"]["ocv_std_v"] == 4.0 * b.filters["hybrid"]["ocv_std_v"]
    assert s.filters["hybrid"]["rest_current_a"] == 2.0 * b.filters["hybrid"]["rest_current_a"]
    assert s.filters["hybrid"]["r"] == 16.0 * b.filters["hybrid"]["r"]
    assert parse_battery_params(battery_params_to_dict(s), "scaled") == s


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"cells_in_series": 0}, "cells_in_series must be an integer >= 1, got 0"),
        ({"cells_in_series": 2.0}, "cells_in_series must be an integer >= 1, got 2.0"),
        ({"cells_in_series": True}, "cells_in_series must be an integer >= 1, got True"),
        ({"capacity_ah": 0.0}, "capacity_ah must be a finite number > 0, got 0.0"),
        ({"capacity_ah": -3.0}, "capacity_ah must be a finite number > 0, got -3.0"),
        ({"capacity_ah": float("nan")}, "capacity_ah must be a finite number > 0, got nan"),
        ({"capacity_ah": float("inf")}, "capacity_ah must be a finite number > 0, got inf"),
        ({"capacity_ah": "12"}, "capacity_ah must be a finite number > 0, got '12'"),
    ],
)
def test_bad_pack_is_refused(kwargs: dict, message: str) -> None:
    b = load_battery_params(CONFIG / "lfp_12v6ah.yaml")
    with pytest.raises(ValueError) as err:
        scale_battery(b, **kwargs)
    assert str(err.value) == message


def test_unknown_tuning_key_or_block_is_refused() -> None:
    b = load_battery_params(CONFIG / "lfp_12v6ah.yaml")
    filters = {**b.filters, "hybrid": {**b.filters["hybrid"], "drift_v": 0.01}}
    with pytest.raises(ValueError, match=r"filters\.hybrid\.drift_v: a tuning key of unknown"):
        scale_battery(dataclasses.replace(b, filters=filters), 8, 12.0)
    filters = {**b.filters, "my_block": {"r": 1.0}}
    with pytest.raises(ValueError, match=r"filters\.my_block: not an estimator or preset"):
        scale_battery(dataclasses.replace(b, filters=filters), 8, 12.0)


def test_a_pack_outside_the_schema_is_refused() -> None:
    # 300 cells: the health section's 4 mV per 4 cells becomes 0.3 V (bound 1 V), the OCV
    # std 1.5 V: above the schema's 1 V bound for health.ocv_std_v.
    b = load_battery_params(CONFIG / "lfp_12v6ah.yaml")
    with pytest.raises(ValueError, match=r"not a valid battery file: .*health\.ocv_std_v"):
        scale_battery(b, 300)


def test_every_tuning_key_has_a_unit() -> None:
    """A key an estimator gains must be given its unit in TUNING_UNITS (else the scaler
    refuses every file, rather than mis-scale it)."""
    keys = {k for cls in ESTIMATORS.values() for k in cls.default_tuning}
    assert keys == set(TUNING_UNITS)


@pytest.mark.parametrize(
    ("section", "units"),
    [
        (Limits, LIMITS_UNITS),
        (ChargeSettings, CHARGE_UNITS),
        (HealthSettings, HEALTH_UNITS),
        (RcModelParams, RC_MODEL_UNITS),
    ],
)
def test_every_field_with_a_unit_is_scaled(section: type, units: dict) -> None:
    """Names carry units (docs/battery_files.md): every field named in volts, amperes, ohms
    or farads is in its section's table."""
    suffixes = ("_v", "_a", "_ohm", "_f", "_ah")
    named = {f.name for f in dataclasses.fields(section) if f.name.endswith(suffixes)}
    assert named == set(units)
