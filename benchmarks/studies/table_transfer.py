"""Is a field run's voltage error the 2RC's structure or its identification? The tables fitted
on some bags, evaluated on others.

The battery file's Thevenin model runs open loop on each bag's current with its SoC set to the
bag's reference at every sample (as ``simulate_voltage(..., gap_s=-1)``). The OCV, its offset
with temperature, the Butler-Volmer drop, the surface lag and the branches' saturation are held;
the five tables R0, R1, C1, R2, C2 get one factor per SoC point (within 0.1-10 of the file's, the
same factor at every temperature row), fitted by ``least_squares`` to the voltage of the
``--fit`` bags (each bag weighed by its sample count, so each counts as one RMS), then every
``--evaluate`` bag's RMSE is printed, with the file's own for comparison. A diagnosis, not an
identification: the fit uses the bags' true SoC. docs/identification.md (issue 5) has what it
showed on the LFP bags.

    python benchmarks/studies/table_transfer.py [--config config/lfp_12v6ah.yaml]
        [--fit lfp_field_run_1_full_rest [--fit lfp_pulse_test,lfp_load_test ...]]
        [--evaluate lfp_field_run_1_full_rest,lfp_field_run_2_partial,...]

A bag is a name in ``bags/`` or a path. Each fit takes 0.5-3 minutes here.
"""

from __future__ import annotations

import argparse
import math
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.optimize import least_squares

ROOT = Path(__file__).resolve().parents[2]  # the checkout (its bags/ and config/)

from soc_estimator_ros.models.tables import ParamTable  # noqa: E402
from soc_estimator_ros.params import BatteryParams, load_battery_params  # noqa: E402
from soc_estimator_ros.recordings import BatterySeries, read_battery_bag  # noqa: E402

#: The factors' bounds, as a log: the tables move within a decade of the file's either way.
LOG_BOUND = math.log(10.0)
#: The tables that get factors, in the order of the factor rows.
TABLES = ("r0", "r1", "c1", "r2", "c2")
DEFAULT_FITS = (
    "lfp_field_run_1_full_rest",
    "lfp_field_run_2_partial",
    "lfp_field_run_1_full_rest,lfp_pulse_test,lfp_load_test",
    "lfp_pulse_test,lfp_load_test",
)
DEFAULT_EVALUATE = (
    "lfp_field_run_1_full_rest,lfp_field_run_2_partial,lfp_field_run_3_cold,"
    "lfp_pulse_test,lfp_load_test"
)


@dataclass(frozen=True)
class Prepared:
    """What the fit varies nothing of, per sample of one bag."""

    name: str
    dt_s: np.ndarray  # to the next sample
    current_a: np.ndarray
    soc: np.ndarray  # the reference
    voltage_v: np.ndarray  # measured
    base_v: np.ndarray  # OCV at the lagged surface SoC (+ offset) - the Butler-Volmer drop
    drive_a: np.ndarray  # (branches, samples): the current that charges each branch
    # Each table as (samples, SoC points): its SoC points' values at the sample's temperature
    # times the sample's linear interpolation weight (held beyond the ends), so that the table
    # with the points scaled by f is ``tables[name] @ f``.
    tables: dict[str, np.ndarray]


def bag_path(name: str) -> Path:
    path = Path(name)
    return path if path.exists() else ROOT / "bags" / name


def _weights(table: ParamTable, soc: np.ndarray, temperature_c: np.ndarray) -> np.ndarray:
    """(samples, SoC points): ``table.at(soc[k], temperature_c[k]) == row k summed``."""
    points = np.asarray(table.soc, dtype=float)
    clipped = np.clip(soc, points[0], points[-1])
    j = np.clip(np.searchsorted(points, clipped) - 1, 0, points.size - 2)
    w = (clipped - points[j]) / (points[j + 1] - points[j])
    weights = np.zeros((soc.size, points.size))
    weights[np.arange(soc.size), j] = 1.0 - w
    weights[np.arange(soc.size), j + 1] += w
    rows = np.asarray(table.values, dtype=float)
    if rows.shape[0] == 1:
        return weights * rows[0]
    temps = np.asarray(table.temperature_c, dtype=float)
    t = np.where(np.isnan(temperature_c), 25.0, temperature_c)  # as ParamTable.at
    pos = np.interp(t, temps, np.arange(temps.size))
    lo = np.minimum(np.floor(pos).astype(int), temps.size - 2)
    frac = (pos - lo)[:, None]
    return weights * (rows[lo] * (1.0 - frac) + rows[lo + 1] * frac)


def prepare(battery: BatteryParams, series: BatterySeries, name: str) -> Prepared:
    """``series`` (with its reference SoC) ready for :func:`simulate` on ``battery``'s 2RC."""
    if series.soc_ref is None:
        raise SystemExit(f"{name}: no reference SoC topic")
    model = battery.thevenin_model()
    th = battery.thevenin
    if th is None or len(th.branches) != 2:
        raise SystemExit("the battery file needs a 2-RC Thevenin model")
    soc = series.soc_ref
    current = series.current_a
    temps = series.temperature_c
    temp = temps.tolist()  # NaN reads as 25 degC in every table, as None does (ParamTable.at)
    dt = np.append(np.diff(series.t_s), 0.0)
    z = np.zeros(soc.size)
    modes = model.surface_rest()
    for k in range(1, soc.size):
        modes = model.surface_step(
            modes, float(current[k - 1]), float(dt[k - 1]), float(soc[k - 1])
        )
        z[k] = sum(modes)
    base = np.array([model.ocv.ocv(float(x)) for x in soc - z])  # the scalar cubic, as the model
    if model.ocv_offset is not None:
        base = base + np.array(
            [model.ocv_offset.at(float(s), t) for s, t in zip(soc, temp, strict=True)]
        )
    kinetic_v = [
        model.series_drop_v(float(s), float(i), t) - float(i) * th.r0_ohm.at(float(s), t)
        for s, i, t in zip(soc, current, temp, strict=True)
    ]
    # The step from sample k to k + 1 reads the branches at the SoC of k and the temperature of
    # k + 1, as simulate_voltage does (models/thevenin.py's step takes the new sample's).
    temps_next = np.append(temps[1:], temps[-1])
    drive = np.array(
        [
            [
                b.drive_a(float(s), float(i), t)
                for s, i, t in zip(soc, current, temps_next.tolist(), strict=True)
            ]
            for b in th.branches
        ]
    )
    tables = {"r0": _weights(th.r0_ohm, soc, temps)}
    for n, b in enumerate(th.branches, start=1):
        tables[f"r{n}"] = _weights(b.r_ohm, soc, temps_next)
        tables[f"c{n}"] = _weights(b.c_f, soc, temps_next)
    return Prepared(
        name, dt, current, soc, series.voltage_v, base - np.array(kinetic_v), drive, tables
    )


def n_factors(bag: Prepared) -> int:
    return len(TABLES) * bag.tables["r0"].shape[1]


def simulate(bag: Prepared, log_factors: np.ndarray) -> np.ndarray:
    """The model's voltage with the tables' SoC points times ``exp(log_factors)`` (one row of
    factors per table of :data:`TABLES`); zeros give the file's model (``simulate_voltage``
    with the SoC imposed at every sample)."""
    f = np.exp(log_factors.reshape(len(TABLES), -1))
    table = {name: bag.tables[name] @ f[row] for row, name in enumerate(TABLES)}
    v = bag.base_v - bag.current_a * table["r0"]
    for n in (1, 2):
        r, c = table[f"r{n}"], table[f"c{n}"]
        a = np.exp(-bag.dt_s / (r * c))
        gain = (r * (1.0 - a) * bag.drive_a[n - 1]).tolist()
        out = np.empty(a.size)
        x = 0.0
        for k, ak in enumerate(a.tolist()):
            out[k] = x
            x = ak * x + gain[k]
        v = v - out
    return v


def rmse_mv(bag: Prepared, log_factors: np.ndarray) -> float:
    return 1000.0 * math.sqrt(float(np.mean((simulate(bag, log_factors) - bag.voltage_v) ** 2)))


def fit(bags: list[Prepared]) -> np.ndarray:
    """The log factors that fit ``bags`` (each bag's residual over the root of its size)."""

    def residual(theta: np.ndarray) -> np.ndarray:
        return np.concatenate(
            [(simulate(b, theta) - b.voltage_v) / math.sqrt(b.voltage_v.size) for b in bags]
        )

    sol = least_squares(
        residual,
        np.zeros(n_factors(bags[0])),
        bounds=(-LOG_BOUND, LOG_BOUND),
        diff_step=1e-3,
        max_nfev=60,
    )
    return sol.x


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--config", type=Path, default=ROOT / "config" / "lfp_12v6ah.yaml")
    ap.add_argument("--fit", action="append", help="comma-separated bags fitted together")
    ap.add_argument("--evaluate", default=DEFAULT_EVALUATE)
    args = ap.parse_args(argv)
    battery = load_battery_params(args.config)
    cache: dict[str, Prepared] = {}

    def get(name: str) -> Prepared:
        if name not in cache:
            cache[name] = prepare(battery, read_battery_bag(bag_path(name)), Path(name).name)
        return cache[name]

    evaluate = [get(n) for n in args.evaluate.split(",")]
    zero = np.zeros(n_factors(evaluate[0]))
    width = max(len(b.name) for b in evaluate)
    print(f"voltage RMSE, mV ({args.config.name}; SoC the bags' reference)")
    print("the file's tables: " + ", ".join(f"{b.name} {rmse_mv(b, zero):.1f}" for b in evaluate))
    for spec in args.fit or list(DEFAULT_FITS):
        bags = [get(n) for n in spec.split(",")]
        t0 = time.perf_counter()
        theta = fit(bags)
        fitted = {b.name for b in bags}
        print(f"\nfitted on {spec} ({time.perf_counter() - t0:.0f} s):")
        for b in evaluate:
            mark = " (fitted)" if b.name in fitted else ""
            print(f"  {b.name:<{width}} {rmse_mv(b, theta):6.1f}{mark}")
        factors = np.exp(theta.reshape(len(TABLES), -1))
        at_bound = int(np.sum(np.abs(theta) > 0.99 * LOG_BOUND))
        print(
            f"  factors at a bound: {at_bound} of {theta.size}; range "
            f"{factors.min():.2f}-{factors.max():.2f}"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
