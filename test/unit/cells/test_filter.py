"""The bar-delta cell filters (cells/filter.py): convergence where the OCV tells the cells
apart, an honest variance where it does not, and the predict step's equations."""

from __future__ import annotations

import numpy as np

from soc_estimator_ros.cells import CellDeltaFilter, CellFilterConfig
from soc_estimator_ros.models.ocv import OcvCurve

#: A cell OCV with a steep, even slope (0.5 V per unit SoC: a Li-ion cell's mid range).
STEEP = OcvCurve([0.0, 1.0], [3.3, 3.8])
#: A flat one: 2 mV over the whole range (LFP's plateau at its flattest, cells/README).
FLAT = OcvCurve([0.0, 1.0], [3.300, 3.302])


def config(**kw: float) -> CellFilterConfig:
    base = dict(cells=4, capacity_ah=6.0, soc_std=0.05, capacity_std=0.03)
    base.update(kw)
    return CellFilterConfig(**base)  # type: ignore[arg-type]


def test_converges_on_a_steep_curve_at_rest() -> None:
    cfg = config()
    f = CellDeltaFilter(cfg, STEEP)
    d_true = np.array([0.0, -0.03, 0.02, 0.01])
    soc_bar = 0.5
    rng = np.random.default_rng(1)
    for _ in range(1800):  # 30 min at rest, 1 Hz
        f.predict(0.0, 1.0)
        v = STEEP.ocv_array(soc_bar + d_true) + rng.normal(0.0, 0.001, 4)
        f.update(soc_bar, 0.0, v, np.ones(4, dtype=bool), 1.0)
    # y_i = v_i - mean(v): the filter reads deviations from the mean cell (here 0.0).
    d_rel = d_true - d_true.mean()
    std = np.sqrt(f.soc_offset_var)
    err = f.soc_offset - d_rel
    # 1 mV noise on 0.5 V/SoC is 0.002 SoC a reading; read as one reading per 300 s
    # (error_corr_s) for 30 min, with the 1 % OCV term: std near 0.004. Within 3 std.
    assert np.all(np.abs(err) < 3.0 * std), (err, std)
    assert np.all(std < 0.01)


def test_flat_curve_variance_grows_with_the_charge_moved() -> None:
    """On a plateau nothing tells the cells apart: d's std must grow as the capacity's
    considered std times the charge moved (eq. (1)), never collapse."""
    cfg = config(soc_walk_per_hour=0.0)
    f = CellDeltaFilter(cfg, FLAT)
    soc_bar = 0.9
    current_a = 6.0  # 1 C
    dt_s = 1.0
    moved = 0.0
    for _ in range(1800):  # half an hour at 1 C: half the charge
        f.predict(current_a, dt_s)
        moved += current_a * dt_s / 3600.0 / cfg.capacity_ah
        soc_bar -= current_a * dt_s / 3600.0 / cfg.capacity_ah
        v = FLAT.ocv_array(np.full(4, soc_bar))
        f.update(soc_bar, current_a, v, np.ones(4, dtype=bool), dt_s)
    var = f.soc_offset_var
    # Linear propagation of the prior (no information): var = soc_std^2 + (capacity_std * moved)^2
    # exactly, less what 2 mV over the range (0.002 V/SoC against >= 3 mV noise) can tell
    # (measured: 7e-5 relative); the tolerance 1e-3 leaves room for that and no more.
    expected = cfg.soc_std**2 + (cfg.capacity_std * moved) ** 2
    np.testing.assert_allclose(var, expected, rtol=1e-3)
    assert np.all(var > cfg.soc_std**2)


def test_predict_is_equation_1() -> None:
    cfg = config()
    f = CellDeltaFilter(cfg, STEEP)
    f.x[:, 1] = [0.03, -0.03, 0.0, 0.01]
    u = 6.0 * 10.0 / 3600.0 / cfg.capacity_ah
    p_before = f.p.copy()
    f.predict(6.0, 10.0)
    np.testing.assert_allclose(f.x[:, 0], u * np.array([0.03, -0.03, 0.0, 0.01]), rtol=1e-12)
    fm = np.array([[1.0, u, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
    expected = fm @ p_before @ fm.T
    expected[:, 0, 0] += cfg.soc_walk_per_hour**2 * 10.0 / 3600.0
    np.testing.assert_allclose(f.p, expected, rtol=1e-12, atol=1e-18)


def test_capacity_is_estimated_only_where_the_ocv_resolves_it() -> None:
    """Half a 6 Ah pack's charge at 6 A, cells 1-3 % off in capacity, noise-free readings. On
    the steep curve a reading tells the SoC finer than the OCV's own offset (4.2 mV over 0.5
    V/SoC: 0.85 % against ``ocv_soc_std`` 1 %): the capacity deviations are estimated, each
    within 3 std of the truth and surer than the prior. On the flat one (4.2 mV over 2 mV/SoC)
    they are considered (Schmidt): state and variance keep the prior exactly. Measured on the
    steep one: 2.4, -2.4, 0.8, -0.8 % (the truth 3, -3, 1, -1), std 1.34 % (prior 3)."""
    cfg = config()
    e_true = np.array([0.03, -0.03, 0.01, -0.01])
    u = 6.0 / 3600.0 / cfg.capacity_ah
    for curve in (STEEP, FLAT):
        f = CellDeltaFilter(cfg, curve)
        d, soc_bar = np.zeros(4), 0.9
        for _ in range(3000):
            f.predict(6.0, 1.0)
            soc_bar -= u
            d += u * e_true  # eq. (1)
            f.update(soc_bar, 6.0, curve.ocv_array(soc_bar + d), np.ones(4, dtype=bool), 1.0)
        if curve is STEEP:
            std = np.sqrt(f.p[:, 1, 1])
            err = f.capacity_factor - 1.0 - e_true
            assert np.all(np.abs(err) < 3.0 * std), (err, std)
            assert np.all(std < cfg.capacity_std), std
        else:
            np.testing.assert_array_equal(f.x[:, 1], 0.0)
            np.testing.assert_allclose(f.p[:, 1, 1], cfg.capacity_std**2, rtol=1e-12)


def test_a_missing_cell_is_only_predicted() -> None:
    cfg = config()
    f = CellDeltaFilter(cfg, STEEP)
    valid = np.array([True, False, True, True])
    for _ in range(50):
        f.predict(0.0, 1.0)
        v = STEEP.ocv_array(0.5 + np.array([0.0, 0.04, 0.01, 0.0]))
        v[1] = np.nan
        f.update(0.5, 0.0, v, valid, 1.0)
    assert np.isnan(f.innovation_v[1]) and np.all(np.isfinite(f.innovation_v[valid]))
    assert f.x[1, 0] == 0.0
    assert f.soc_offset_var[1] >= cfg.soc_std**2  # untouched by any update
