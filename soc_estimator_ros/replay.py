"""``soc_replay``: run recorded data through the estimators, with metrics, tables and plots.

    soc_replay INPUT [INPUT ...] [--params FILE] [--estimator NAME | --all]
               [--initial-soc X|ref] [--output est.csv] [--plot fig.png | --plot-dir DIR]
               [--output-bag DIR] [--progress] [--live [--rate X]]

INPUT is a rosbag2 bag (MCAP or sqlite3; ``--topic``, default ``/battery/state``), a CSV
(``time_s,current_a,voltage_v[,temperature_c][,soc_ref]`` with ``--current-sign``), or a
directory of bags (processed in parallel over the cores). Without ``--params`` the battery file
is chosen from the bag's ``power_supply_technology`` (LIFE -> LFP, VRLA -> SLA). With a reference
SoC in the input, MAE, RMSE, max error (after a 10-minute window) and the convergence time are
printed.

``--output-bag DIR`` writes a new bag (MCAP) with the input (``/battery/state`` and
``/battery/soc_reference`` when present) and the estimates on the node's own topics and types
(``/battery/soc`` BatteryState, ``/battery/soc_estimate`` labelled Float64MultiArray, see
``outputs.py``), at the input's stamps, to look at beside the input in PlotJuggler or
``ros2 bag``; with ``--all`` each estimator's topics are under ``/<estimator>/``.
``--progress`` (on by default when stderr is a terminal) draws a progress bar on stderr.
``--live`` sends the samples through a running ``soc_estimator_node`` on sim time instead of
the estimator object (live_replay.py: loopback DDS, a namespace of its own), lock-step by
default or at ``--rate`` times the recorded pace; its outputs are scored the same way.
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
from typing import Any

import numpy as np

from .bag_io import (
    BATTERY_STATE,
    FLOAT64_ARRAY,
    REFERENCE_TOPIC,
    STATE_TOPIC,
    TECHNOLOGY_BY_CHEMISTRY,
    BagError,
    BatterySeries,
    add_recording_arguments,
    battery_state_message,
    float64_array_message,
    read_recording,
    write_bag,
)
from .conventions import CurrentSign
from .estimators import DEFAULT_ESTIMATOR, ESTIMATORS, make_estimator
from .evaluation import Accuracy, EstimateSeries, accuracy, run_estimator
from .outputs import estimate_row, layout_label
from .params import BatteryParams, ParamFileError, load_battery_params

CONFIG_DIR = Path(__file__).resolve().parents[1] / "config"
INITIAL_SOC_STD = 0.1


class InputError(ValueError):
    """An input file that cannot be replayed."""


def default_battery_file(series: BatterySeries) -> Path:
    """The bundled battery file matching the bag's technology."""
    files = {"lfp": "lfp_12v6ah.yaml", "sla": "sla_12v5ah.yaml", "li_ion": "li_ion_ncr18650pf.yaml"}
    for chemistry, technology in TECHNOLOGY_BY_CHEMISTRY.items():
        if series.technology == technology and chemistry in files:
            return CONFIG_DIR / files[chemistry]
    raise InputError(
        f"power_supply_technology {series.technology} matches no bundled battery file "
        "(LIFE -> lfp_12v6ah.yaml, VRLA -> sla_12v5ah.yaml, LION -> li_ion_ncr18650pf.yaml): "
        "pass --params"
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
    progress: bool = False,
    live: LiveOptions | None = None,
) -> ReplayResult:
    """Run one estimator; ``initial_soc=None`` starts from the reference SoC (or 1.0).

    With ``live``, the samples go through a running ``soc_estimator_node`` (live_replay.py)
    instead of the estimator object.
    """
    if initial_soc is None:
        has_ref = series.soc_ref is not None and math.isfinite(series.soc_ref[0])
        initial_soc = float(series.soc_ref[0]) if has_ref else 1.0
    bar = ProgressBar(f"{input_name} {estimator}{' (live)' if live else ''}") if progress else None
    if live is None:
        est = make_estimator(estimator, battery, initial_soc, INITIAL_SOC_STD)
        out = run_estimator(est, series, bar)
    else:
        from .live_replay import replay_live  # rclpy only for --live

        out = replay_live(
            series, live.battery_file, estimator, initial_soc, INITIAL_SOC_STD, live.rate, bar
        )
    acc = None
    if series.soc_ref is not None and series.t_s[-1] > 600.0:
        acc = accuracy(out.t_s, out.soc, series.soc_ref)
    return ReplayResult(input_name, out, acc, initial_soc)


@dataclass(frozen=True)
class LiveOptions:
    """``--live``: the battery file the node loads and the pace (None: lock-step)."""

    battery_file: Path
    rate: float | None = None


class ProgressBar:
    """A text progress bar on stderr: ``soc_replay: NAME [#####.....]  50 %``."""

    def __init__(self, label: str, width: int = 30) -> None:
        self.label, self.width = label, width

    def __call__(self, done: int, total: int) -> None:
        filled = self.width * done // max(total, 1)
        bar = "#" * filled + "." * (self.width - filled)
        end = "\n" if done >= total else ""
        sys.stderr.write(
            f"\rsoc_replay: {self.label} [{bar}] {100 * done // max(total, 1):3d} %{end}"
        )
        sys.stderr.flush()


def write_output_bag(
    path: Path, series: BatterySeries, battery: BatteryParams, results: list[ReplayResult]
) -> None:
    """The input and the estimates as a new bag (see the module docstring)."""
    if path.exists():
        raise InputError(f"--output-bag {path}: exists; give a new directory")
    tech = TECHNOLOGY_BY_CHEMISTRY.get(battery.chemistry, 0)

    def state(k: int, **extra: float) -> Any:
        return battery_state_message(
            int(series.stamp_ns[k]),
            float(series.voltage_v[k]),
            float(series.current_a[k]),
            temperature_c=float(series.temperature_c[k]),
            design_capacity_ah=battery.nominal_capacity_ah,
            technology=tech,
            **extra,
        )

    n = len(series)
    topics: list[tuple[str, str, Any]] = [
        (STATE_TOPIC, BATTERY_STATE, ((int(series.stamp_ns[k]), state(k)) for k in range(n)))
    ]
    if series.soc_ref is not None:
        ref = series.soc_ref
        topics.append(
            (
                REFERENCE_TOPIC,
                BATTERY_STATE,
                (
                    (int(series.stamp_ns[k]), state(k, percentage=float(ref[k])))
                    for k in range(n)
                    if math.isfinite(ref[k])
                ),
            )
        )
    for r in results:
        e = r.estimates
        prefix = f"/{e.estimator}" if len(results) > 1 else ""
        label = layout_label(e.state_names)

        def soc_msgs(e: EstimateSeries = e) -> Any:
            for k in range(n):
                soc = float(e.soc[k])
                yield (
                    int(series.stamp_ns[k]),
                    state(
                        k,
                        percentage=soc,
                        charge_ah=soc * battery.capacity_ah,
                        capacity_ah=battery.capacity_ah,
                    ),
                )

        def est_msgs(e: EstimateSeries = e, label: str = label) -> Any:
            for k in range(n):
                row = estimate_row(
                    float(series.stamp_ns[k]) * 1e-9,
                    float(e.soc[k]),
                    float(e.soc_std[k]) ** 2,
                    float(e.voltage_pred_v[k]),
                    float(e.innovation_v[k]),
                    float(e.nis[k]),
                    e.x[k],
                    e.p[k],
                )
                yield int(series.stamp_ns[k]), float64_array_message(label, row)

        topics.append((f"{prefix}/battery/soc", BATTERY_STATE, soc_msgs()))
        topics.append((f"{prefix}/battery/soc_estimate", FLOAT64_ARRAY, est_msgs()))
    write_bag(path, topics)


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
    path, topic, sign, params, estimators, initial_soc, plot_dir, progress, out_bag, live = args
    series = read_recording(Path(path), topic, sign)
    battery_file = Path(params or default_battery_file(series))
    battery = load_battery_params(battery_file)
    name = Path(path).name
    opts = LiveOptions(battery_file.resolve(), live[1]) if live[0] else None
    results = [
        replay_one(series, battery, e, initial_soc, name, progress, opts) for e in estimators
    ]
    if out_bag is not None:
        write_output_bag(Path(out_bag), series, battery, results)
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
    ap.add_argument("--output-bag", type=Path, help="new bag: the input plus the estimates")
    ap.add_argument(
        "--live", action="store_true", help="replay through a running soc_estimator_node"
    )
    ap.add_argument(
        "--rate",
        type=float,
        help="--live pace, times the recorded pace (default: as fast as the node answers)",
    )
    ap.add_argument(
        "--progress",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="progress bar on stderr (default: when stderr is a terminal)",
    )
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
        if args.output_bag is not None:
            if len(inputs) > 1:
                raise InputError("--output-bag needs one input")
            if args.output_bag.exists():
                raise InputError(f"--output-bag {args.output_bag}: exists; give a new directory")
        progress = sys.stderr.isatty() if args.progress is None else args.progress
        if args.rate is not None and (not args.live or not args.rate > 0):
            raise InputError("--rate needs --live and a value > 0")
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
                progress,
                str(args.output_bag) if args.output_bag else None,
                (args.live, args.rate),
            )
            for p in inputs
        ]
        if len(jobs) > 1 and args.jobs > 1 and not args.live:
            with ProcessPoolExecutor(max_workers=min(args.jobs, len(jobs))) as pool:
                done = list(pool.map(_job, jobs))
        else:
            done = [_job(j) for j in jobs]
    except (InputError, BagError, ParamFileError, OSError, RuntimeError) as exc:
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
    if args.output_bag:
        print(f"bag: {args.output_bag}")
    if args.plot:
        series = read_recording(inputs[0], args.topic, CurrentSign(args.current_sign))
        plot_results(args.plot, series, done[0][1])
        print(f"plot: {args.plot}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
