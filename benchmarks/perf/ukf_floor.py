"""The floor under any numpy UKF here: t2rc_ukf's step with the fewest numpy calls.

``replay_throughput.py`` measures the package's t2rc_ukf (filterpy's UKF, batched). This script
runs the same filter on the same bag as one hand-fused function: every parameter table read by
a single ``np.interp`` over concatenated grids, the sigma points, transform and update inline,
no filterpy dispatch, no Estimate objects, no covariance conditioning. It is a measurement, not
an estimator: it checks that it computes what t2rc_ukf computes (the largest SoC difference
over the run is printed) and reports how fast that arithmetic can go in numpy on this machine.
With the replay loop's own cost per sample (``coulomb`` in ``replay_throughput.py``), it bounds
the replay throughput any filterpy/numpy UKF can reach here (docs/benchmarks.md).

    python benchmarks/perf/ukf_floor.py [--bag sla_field_run_1_full_rest] [--repeat 3]
"""

from __future__ import annotations

import argparse
import math
import time
from pathlib import Path

import numpy as np
from scipy.linalg.lapack import dpotrf

ROOT = Path(__file__).resolve().parents[2]  # the checkout (its bags/ and config/)

from soc_estimator_ros.estimators import make_estimator  # noqa: E402
from soc_estimator_ros.evaluation import run_estimator  # noqa: E402
from soc_estimator_ros.models.tables import fast_interp  # noqa: E402
from soc_estimator_ros.params import load_battery_params  # noqa: E402
from soc_estimator_ros.recordings import read_battery_bag  # noqa: E402

FILES = {"sla": "sla_12v5ah.yaml", "lfp": "lfp_12v6ah.yaml"}
SHIFT = 100.0  # table k's SoC grid is moved to k * SHIFT; guard points hold its end values
GUARD = 45.0  # so any sigma point's SoC within +-45 of the grid reads its own table


class Stack:
    """Tables read at once: one np.interp over the shifted, guarded, concatenated grids."""

    def __init__(self, tables) -> None:
        self.tables = tables
        self.shift = (SHIFT * np.arange(len(tables)))[:, np.newaxis]
        grid = []
        for k, t in enumerate(tables):
            soc = np.array(t.soc)
            grid.append(np.concatenate([[soc[0] - GUARD], soc, [soc[-1] + GUARD]]) + SHIFT * k)
        self.grid = np.concatenate(grid)
        self.rows: dict[float | None, np.ndarray] = {}

    def values(self, temp_c: float | None) -> np.ndarray:
        row = self.rows.get(temp_c)
        if row is None:
            parts = []
            for t in self.tables:
                r = t.at_array(np.array(t.soc), temp_c)
                parts.append(np.concatenate([[r[0]], r, [r[-1]]]))
            row = self.rows[temp_c] = np.concatenate(parts)
        return row

    def at(self, soc: np.ndarray, temp_c: float | None) -> np.ndarray:
        x = (soc + self.shift).ravel()
        return fast_interp(x, self.grid, self.values(temp_c), None, None).reshape(
            len(self.tables), -1
        )


def fused_run(battery, est, series) -> np.ndarray:
    """t2rc_ukf over ``series`` (no gaps, dt > 0), fused; returns the SoC after each sample."""
    th = battery.thevenin
    n_rc = len(th.branches)
    sat = [i for i, b in enumerate(th.branches) if b.i_sat_a is not None]
    step_tables = Stack(
        [b.r_ohm for b in th.branches]
        + [b.c_f for b in th.branches]
        + [th.branches[i].i_sat_a for i in sat]
    )
    kin = th.kinetic
    offset = battery.ocv.offset_table()
    out_tables = Stack(
        [th.r0_ohm]
        + ([kin.a_v, kin.i0_a] if kin is not None else [])
        + ([offset] if offset is not None else [])
    )
    curve = battery.ocv_curve()
    pts = est.kf.points_fn
    wm, wc = pts.Wm, pts.Wc
    scale = pts.lambda_ + pts.n
    offsets = np.hstack([np.zeros((pts.n, 1)), np.eye(pts.n), -np.eye(pts.n)])
    q = np.diag(np.asarray(est.tuning["q_diag"], dtype=float))
    r = float(est.tuning["r"])
    eff = battery.coulomb_efficiency_charge
    cap_as = 3600.0 * battery.capacity_ah
    x, p = est.kf.x.copy(), est.kf.P.copy()
    t, cur, volt, temps = series.t_s, series.current_a, series.voltage_v, series.temperature_c
    soc_out = np.empty(t.size)
    i_prev = 0.0
    for k in range(t.size):
        temp = float(temps[k])
        temp = None if math.isnan(temp) else temp
        i_k = float(cur[k])
        if k:
            dt = float(t[k] - t[k - 1])
            s = x[:, None] + dpotrf(scale * p, lower=1, clean=1)[0] @ offsets
            soc = s[0]
            v = step_tables.at(soc, temp)
            rr = v[:n_rc]
            a = np.exp(-dt / (rr * v[n_rc : 2 * n_rc]))
            f = np.empty_like(s)
            f[0] = soc - (eff if i_prev < 0.0 else 1.0) * i_prev * dt / cap_as
            drive = np.full_like(rr, i_prev)
            if sat and i_prev != 0.0:
                si = v[2 * n_rc :]
                drive[sat] = si * np.arcsinh(i_prev / si)
            f[1:] = a * s[1:] + rr * (1.0 - a) * drive
            x = f @ wm
            d = f - x[:, None]
            p = (d * wc) @ d.T + q * dt
        s = x[:, None] + dpotrf(scale * p, lower=1, clean=1)[0] @ offsets
        soc = s[0]
        v = out_tables.at(soc, temp)
        h = curve.ocv_array(soc) - i_k * v[0] - s[1:].sum(axis=0)
        if kin is not None and i_k != 0.0:
            h = h - v[1] * np.arcsinh(i_k / v[2])
        if offset is not None:
            h = h + v[-1]
        zp = h @ wm
        dz = h - zp
        wdz = dz * wc
        s_var = wdz @ dz + r
        kg = ((s - x[:, None]) @ wdz) / s_var
        x = x + kg * (float(volt[k]) - zp)
        p = p - np.outer(kg, kg) * s_var
        clipped = min(max(x[0], 0.0), 1.0)
        if clipped != x[0]:  # as Estimator._clip_soc: the clipped amount goes to the variance
            p[0, 0] += min((x[0] - clipped) ** 2, max(1.0 - p[0, 0], 0.0))
            x[0] = clipped
        soc_out[k] = x[0]
        i_prev = i_k
    return soc_out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--bag", default="sla_field_run_1_full_rest")
    ap.add_argument("--repeat", type=int, default=3, help="runs; the best counts")
    args = ap.parse_args()
    series = read_battery_bag(ROOT / "bags" / args.bag)
    battery = load_battery_params(ROOT / "config" / FILES[args.bag[:3]])
    dts = np.diff(series.t_s)
    if not (np.all(dts > 0.0) and np.all(dts <= 5.0)):
        raise SystemExit("the floor covers runs without gaps or out-of-order stamps only")
    soc0 = float(series.soc_ref[0])
    ref = run_estimator(make_estimator("t2rc_ukf", battery, soc0, 0.1), series).soc
    span_s = float(series.t_s[-1] - series.t_s[0])
    best = math.inf
    for _ in range(args.repeat):
        est = make_estimator("t2rc_ukf", battery, soc0, 0.1)
        t0 = time.perf_counter()
        soc = fused_run(battery, est, series)
        best = min(best, time.perf_counter() - t0)
    n = series.t_s.size
    print(
        f"{args.bag}: fused t2rc_ukf step {1e6 * best / n:.1f} us, {span_s / best:.0f}x real time"
    )
    print(f"largest SoC difference to t2rc_ukf over the run: {np.max(np.abs(soc - ref)):.2e}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
