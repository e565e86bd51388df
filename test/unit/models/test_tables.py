"""LaneTables (many tables, per-lane temperatures) against ParamTable.at, element by element.

Tolerance 1e-13 relative: the same bilinear interpolant in another rounding order (hinge
sums, LaneTables' docstring), a few ulp of values of order 1 summed over a few hinges.
"""

from __future__ import annotations

import math

import numpy as np
from conftest import REPO_ROOT

from soc_estimator_ros.models.tables import LaneTables, ParamTable
from soc_estimator_ros.params import load_battery_params


def _tables() -> list[ParamTable]:
    lfp = load_battery_params(REPO_ROOT / "config" / "lfp_12v6ah.yaml")
    th = lfp.thevenin
    assert th.kinetic is not None
    offset = lfp.ocv.offset_table()
    assert offset is not None  # 41 SoC points: read by np.interp, not hinges
    three_rows = ParamTable(
        soc=(0.0, 0.3, 0.7, 1.0),
        values=((1.0, 2.0, 1.5, 3.0), (2.0, 2.5, 0.5, 1.0), (0.1, 0.2, 0.3, 0.4)),
        temperature_c=(-10.0, 10.0, 40.0),
    )
    one_row = ParamTable.from_arrays([0.2, 0.5, 0.9], [0.03, 0.01, 0.02])
    single = ParamTable(soc=(0.5,), values=((7.0,),))
    return [th.r0_ohm, *(b.r_ohm for b in th.branches), th.kinetic.i0_a, offset, three_rows] + [
        one_row,
        single,
    ]


def test_lane_tables_equal_param_table_at() -> None:
    tables = _tables()
    rng = np.random.default_rng(3)
    k = 200
    temps = rng.uniform(-25.0, 50.0, k)
    temps[:10] = math.nan  # unknown: 25 degC
    temps[10:20] = [5.0, 25.0, -10.0, 10.0, 40.0, 2.0, 28.0, 4.99, 25.01, 0.0]  # on rows
    soc = rng.uniform(-0.3, 1.3, (3, k))  # beyond the grids: held at the edges
    soc[0, :20] = np.linspace(0.0, 1.0, 20)
    got = LaneTables(tables).at(soc, temps)
    assert got.shape == (len(tables), 3, k)
    for n, table in enumerate(tables):
        want = np.array(
            [[table.at(float(soc[i, j]), float(temps[j])) for j in range(k)] for i in range(3)]
        )
        np.testing.assert_allclose(got[n], want, rtol=1e-13, atol=1e-15, err_msg=f"table {n}")
