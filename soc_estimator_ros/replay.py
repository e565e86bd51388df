"""``soc_replay``: run recorded data through the estimators, with metrics, tables and plots.

    soc_replay INPUT [INPUT ...] [--params FILE] [--estimator NAME | --all]
               [--initial-soc X|ref] [--output est.csv] [--plot fig.png | --plot-dir DIR]

INPUT is a rosbag2 bag (MCAP or sqlite3; ``--topic``, default ``/battery/state``), a CSV
(``time_s,current_a,voltage_v[,temperature_c][,soc_ref]`` with ``--current-sign``), or a
directory of bags (processed in parallel over the cores). Without ``--params`` the battery file
is chosen from the bag's ``power_supply_technology`` (LIFE -> LFP, VRLA -> SLA). With a reference
SoC in the input, MAE, RMSE, max error (after a 10-minute window) and the convergence time are
printed.
"""

from __future__ import annotations

import argparse
import csv
import math
import os
import sys
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .bag_io import (
    TECHNOLOGY_BY_CHEMISTRY,
    BagError,
    BatterySeries,
    add_recording_arguments,
    read_recording,
)
from .conventions import CurrentSign
from .estimators import DEFAULT_ESTIMATOR, ESTIMATORS, make_estimator
from .evaluation import Accuracy, EstimateSeries, accuracy, run_estimator
from .params import BatteryParams, ParamFileError, load_battery_params

CONFIG_DIR = Path(__file__).resolve().parents[1] / "config"
INITIAL_SOC_STD = 0.1


class InputError(ValueError):
    """An input file that cannot be replayed."""


def default_battery_file(series: BatterySeries) -> Path:
    """The bundled battery file matching the bag's technology."""
    files = {"lfp": "lfp_12v6ah.yaml", "sla": "sla_12v5ah.yaml"}
    for chemistry, technology in TECHNOLOGY_BY_CHEMISTRY.items():
        if series.technology == technology and chemistry in files:
            return CONFIG_DIR / files[chemistry]
    raise InputError(
        f"power_supply_technology {series.technology} matches no bundled battery file "
        "(LIFE -> lfp_12v6ah.yaml, VRLA -> sla_12v5ah.yaml): pass --params"
    )


@dataclass(frozen=True)
class ReplayResult:
    """One estimator on one input."""

    input_name: str
    estimates: EstimateSeries
    accuracy: Accuracy | None
    initial_soc: float


def replay_one(
    series: BatterySeries,
    battery: BatteryParams,
    estimator: str,
    initial_soc: float | None,
    input_name: str,
) -> ReplayResult:
    """Run one estimator; ``initial_soc=None`` starts from the reference SoC (or 1.0)."""
    if initial_soc is None:
        has_ref = series.soc_ref is not None and math.isfinite(series.soc_ref[0])
        initial_soc = float(series.soc_ref[0]) if has_ref else 1.0
    est = make_estimator(estimator, battery, initial_soc, INITIAL_SOC_STD)
    out = run_estimator(est, series)
    acc = None
    if series.soc_ref is not None and series.t_s[-1] > 600.0:
        acc = accuracy(out.t_s, out.soc, series.soc_ref)
    return ReplayResult(input_name, out, acc, initial_soc)


def write_csv(path: Path, result: ReplayResult) -> None:
    """``time_s, soc, soc_std, voltage_v, voltage_pred_v, current_a`` per sample."""
    e = result.estimates
    with path.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["time_s", "soc", "soc_std", "voltage_v", "voltage_pred_v", "current_a"])
        for row in zip(
            e.t_s, e.soc, e.soc_std, e.voltage_v, e.voltage_pred_v, e.current_a, strict=True
        ):
            w.writerow([f"{v:.6g}" if k else f"{v:.3f}" for k, v in enumerate(row)])


def plot_results(path: Path, series: BatterySeries, results: list[ReplayResult]) -> None:
    """SoC vs reference with +-2 sigma, the error, and measured vs predicted voltage
    (seed 000 Figs. 11-13), one colour per estimator."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(3, 1, figsize=(10, 10), sharex=True)
    t_h = series.t_s / 3600.0
    if series.soc_ref is not None:
        axes[0].plot(t_h, 100 * series.soc_ref, "k", lw=1.5, label="reference")
    axes[2].plot(t_h, series.voltage_v, color="0.6", lw=0.5, label="measured")
    for r in results:
        e = r.estimates
        (line,) = axes[0].plot(t_h, 100 * e.soc, lw=1, label=e.estimator)
        axes[0].fill_between(
            t_h,
            100 * (e.soc - 2 * e.soc_std),
            100 * (e.soc + 2 * e.soc_std),
            color=line.get_color(),
            alpha=0.15,
        )
        if series.soc_ref is not None:
            axes[1].plot(t_h, 100 * (e.soc - series.soc_ref), lw=1, color=line.get_color())
        if np.any(np.isfinite(e.voltage_pred_v)):
            axes[2].plot(
                t_h,
                e.voltage_pred_v,
                lw=0.7,
                color=line.get_color(),
                label=f"{e.estimator} predicted",
            )
    axes[0].set_ylabel("SoC (%)")
    axes[0].legend(fontsize=8, ncol=3)
    axes[1].set_ylabel("SoC error (points)")
    axes[1].axhline(2, color="k", ls=":", lw=0.8)
    axes[1].axhline(-2, color="k", ls=":", lw=0.8)
    axes[2].set_ylabel("voltage (V)")
    axes[2].set_xlabel("time (h)")
    axes[2].legend(fontsize=8, ncol=3)
    fig.suptitle(results[0].input_name)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _fmt(acc: Accuracy | None) -> str:
    if acc is None:
        return f"{'-':>7} {'-':>7} {'-':>7} {'-':>9}"
    conv = f"{acc.t_converge_s:9.0f}" if math.isfinite(acc.t_converge_s) else f"{'never':>9}"
    return f"{100 * acc.mae:7.2f} {100 * acc.rmse:7.2f} {100 * acc.max_abs:7.2f} {conv}"


def _job(args: tuple) -> tuple[str, list[ReplayResult], str | None]:
    path, topic, sign, params, estimators, initial_soc, plot_dir = args
    series = read_recording(Path(path), topic, sign)
    battery = load_battery_params(params or default_battery_file(series))
    name = Path(path).name
    results = [replay_one(series, battery, e, initial_soc, name) for e in estimators]
    plot = None
    if plot_dir is not None:
        plot = str(Path(plot_dir) / f"{name}.png")
        plot_results(Path(plot), series, results)
    return name, results, plot


def expand_inputs(paths: list[Path]) -> list[Path]:
    """A directory holding bags (sub-directories with metadata.yaml) expands to them."""
    out: list[Path] = []
    for p in paths:
        if p.is_dir() and not (p / "metadata.yaml").exists():
            bags = sorted(q for q in p.iterdir() if (q / "metadata.yaml").exists())
            if not bags:
                raise InputError(f"{p}: neither a bag nor a directory of bags")
            out += bags
        else:
            out.append(p)
    return out


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(
        prog="soc_replay", description="Replay recorded battery data through the estimators."
    )
    ap.add_argument("inputs", nargs="+", type=Path, help="bag, CSV, or directory of bags")
    ap.add_argument("--params", type=Path, help="battery parameter file (default: by technology)")
    group = ap.add_mutually_exclusive_group()
    group.add_argument(
        "--estimator",
        default=DEFAULT_ESTIMATOR,
        choices=sorted(ESTIMATORS),
        help=f"default {DEFAULT_ESTIMATOR}",
    )
    group.add_argument("--all", action="store_true", help="compare every estimator")
    ap.add_argument(
        "--initial-soc",
        default="ref",
        help="initial SoC in [0, 1], or 'ref' for the input's reference (default)",
    )
    add_recording_arguments(ap)
    ap.add_argument("--output", type=Path, help="CSV of the estimates (one input, one estimator)")
    ap.add_argument("--plot", type=Path, help="PNG plot (one input)")
    ap.add_argument("--plot-dir", type=Path, help="one PNG per input in this directory")
    ap.add_argument("--jobs", type=int, default=os.cpu_count() or 1)
    return ap


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        initial_soc = None if args.initial_soc == "ref" else float(args.initial_soc)
        if initial_soc is not None and not 0.0 <= initial_soc <= 1.0:
            raise InputError(f"--initial-soc {args.initial_soc}: expected a value in [0, 1]")
        inputs = expand_inputs(args.inputs)
        estimators = sorted(ESTIMATORS) if args.all else [args.estimator]
        if args.output and (len(inputs) > 1 or len(estimators) > 1):
            raise InputError("--output needs one input and one estimator")
        if args.plot and len(inputs) > 1:
            raise InputError("--plot needs one input; use --plot-dir for several")
        plot_dir = args.plot_dir
        if plot_dir is not None:
            plot_dir.mkdir(parents=True, exist_ok=True)
        sign = CurrentSign(args.current_sign)
        jobs = [
            (
                str(p),
                args.topic,
                sign,
                args.params,
                estimators,
                initial_soc,
                str(plot_dir) if plot_dir else None,
            )
            for p in inputs
        ]
        if len(jobs) > 1 and args.jobs > 1:
            with ProcessPoolExecutor(max_workers=min(args.jobs, len(jobs))) as pool:
                done = list(pool.map(_job, jobs))
        else:
            done = [_job(j) for j in jobs]
    except (InputError, BagError, ParamFileError, OSError) as exc:
        print(f"soc_replay: error: {exc}", file=sys.stderr)
        return 2
    print(f"{'input':<30} {'estimator':<10} {'MAE%':>7} {'RMSE%':>7} {'max%':>7} {'conv_s':>9}")
    for name, results, plot in done:
        for r in results:
            print(f"{name:<30} {r.estimates.estimator:<10} {_fmt(r.accuracy)}")
        if plot:
            print(f"  plot: {plot}")
    if args.output:
        write_csv(args.output, done[0][1][0])
        print(f"estimates: {args.output}")
    if args.plot:
        series = read_recording(inputs[0], args.topic, CurrentSign(args.current_sign))
        plot_results(args.plot, series, done[0][1])
        print(f"plot: {args.plot}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
