"""``soc_replay``: run recorded data through the estimators, with metrics, tables and plots.

    soc_replay INPUT [INPUT ...] [--params FILE] [--estimator NAME | --all]
               [--initial-soc ocv|ref|X] [--output est.csv] [--plot fig.png | --plot-dir DIR]
               [--output-bag DIR] [--progress] [--live [--rate X]] [--jobs N]
               [--scheduler ADDRESS|local]
               [--batch auto|always|never]

INPUT is a rosbag2 bag (MCAP or sqlite3; ``--topic``, default ``/battery/state``), a CSV
(``time_s,current_a,voltage_v[,temperature_c][,soc_ref]`` with ``--current-sign``), or a
directory of bags (processed in parallel over the cores, or on a Dask cluster with
``--scheduler``), or an fsspec URL of any of them (``fleet.py``). Without ``--params`` the bundled
battery file is chosen from the recording's ``power_supply_technology``. Every sample goes
through the node's own tracker (input gate, initialization; ``run.py``); the start used and
the rejected samples are printed. With a reference SoC in the input, MAE, RMSE, max error
(after a 10-minute window) and the convergence time are printed. With many recordings of one
battery (``--batch``), t2rc_ukf runs through the batch engine (``batch.py``). docs/replay.md has
the rest.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
from concurrent.futures import ProcessPoolExecutor
from dataclasses import replace
from pathlib import Path

from ..errors import SocEstimatorError
from ..estimators import DEFAULT_ESTIMATOR, ESTIMATORS
from ..estimators.t2rc_ukf import T2rcUkf
from ..evaluation import Accuracy
from ..recordings import add_recording_arguments
from ..units import CurrentSign
from .batch import BATCH_MIN_LANES, batch_eligible, replay_jobs_batched
from .fleet import LOCAL, expand_url, is_url, local_copy, run_on_dask
from .outputs import plot_results, write_csv, write_output_bag
from .run import ReplayError, ReplayJob, ReplayResult, run_job


def expand_inputs(inputs: list[str]) -> list[Path | str]:
    """A directory holding bags (sub-directories with metadata.yaml) expands to them; a URL
    (``fleet.py``) stays a string, its directory of bags expanded the same way."""
    out: list[Path | str] = []
    for text in inputs:
        if is_url(text):
            out += expand_url(text)
            continue
        p = Path(text)
        if p.is_dir() and not (p / "metadata.yaml").exists():
            bags = sorted(q for q in p.iterdir() if (q / "metadata.yaml").exists())
            if not bags:
                raise ReplayError(f"{p}: neither a bag nor a directory of bags")
            out += bags
        else:
            out.append(p)
    return out


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(
        prog="soc_replay", description="Replay recorded battery data through the estimators."
    )
    ap.add_argument(
        "inputs",
        nargs="+",
        help="bag, CSV, or directory of bags; or an fsspec URL of one (s3://..., file://...)",
    )
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
        default="ocv",
        help="start: 'ocv' (the node's own start: the OCV of the first accepted sample; "
        "default), 'ref' (the input's reference SoC) or a fraction in [0, 1]",
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
    ap.add_argument(
        "--cells-in-series",
        type=int,
        default=0,
        help="scale the battery file to a pack of this many cells in series "
        "(docs/battery_files.md; 0: the file's)",
    )
    ap.add_argument(
        "--capacity-ah",
        type=float,
        default=0.0,
        help="scale the battery file to this rated capacity (Ah; 0: the file's)",
    )
    ap.add_argument(
        "--learn-health",
        action="store_true",
        help="learn the pack's capacity and R0 factor (the node's learn_health)",
    )
    ap.add_argument(
        "--filter-rate-hz",
        type=float,
        default=0.0,
        help="filter steps per second, the samples between counted as charge (the node's "
        "filter_rate_hz; 0 = a step on every sample); offline",
    )
    ap.add_argument(
        "--state",
        type=Path,
        help="state file: start from the health it holds (if any, for this battery), write it "
        "back at the end; the inputs are replayed in order as one battery's life "
        "(implies --learn-health)",
    )
    ap.add_argument(
        "--batch",
        choices=("auto", "always", "never"),
        default="auto",
        help="t2rc_ukf over many recordings through the batch engine (results within 1e-9 of "
        f"the per-sample path): auto from {BATCH_MIN_LANES} recordings of one battery file, "
        "offline, without --output/--plot/--plot-dir/--output-bag/--state/--learn-health",
    )
    ap.add_argument(
        "--jobs",
        type=int,
        default=os.cpu_count() or 1,
        help="parallel jobs: the process pool's, or --scheduler local's workers",
    )
    ap.add_argument(
        "--scheduler",
        metavar="ADDRESS",
        help="run the jobs on a Dask cluster: its scheduler's address (tcp://HOST:8786), or "
        "'local' for a local cluster of --jobs workers (docs/replay.md, 'A fleet')",
    )
    return ap


def _fmt(acc: Accuracy | None) -> str:
    if acc is None:
        return f"{'-':>7} {'-':>7} {'-':>7} {'-':>9}"
    conv = f"{acc.t_converge_s:9.0f}" if acc.t_converge_s != float("inf") else f"{'never':>9}"
    return f"{100 * acc.mae:7.2f} {100 * acc.rmse:7.2f} {100 * acc.max_abs:7.2f} {conv}"


def _batched(mode: str, jobs: list[ReplayJob]) -> dict[int, ReplayResult]:
    """t2rc_ukf of the eligible jobs through the batch engine (``--batch``), by job index."""
    eligible = [i for i, j in enumerate(jobs) if batch_eligible(j)]
    if mode == "never" or not eligible or (mode == "auto" and len(eligible) < BATCH_MIN_LANES):
        return {}
    done = replay_jobs_batched([jobs[i] for i in eligible])
    return {eligible[k]: r for k, r in done.items()}


def _merge(
    job: ReplayJob, done: tuple[str, list[ReplayResult], str | None], batched: ReplayResult | None
) -> tuple[str, list[ReplayResult], str | None]:
    """The job's results in its estimators' order, t2rc_ukf's from the batch engine."""
    if batched is None:
        return done
    name, results, plot = done
    rest = iter(results)
    merged = [batched if e == T2rcUkf.name else next(rest) for e in job.estimators]
    return name, merged, plot


def _job(job: ReplayJob) -> tuple[str, list[ReplayResult], str | None]:
    """A job for the process pool or a Dask worker: replay, then write what it asks for."""
    if not job.estimators:  # every estimator replayed elsewhere (the batch engine)
        return job.name, [], None
    with local_copy(job) as local:
        series, battery, results = run_job(local)
    out_bag = job.extras.get("output_bag")
    if out_bag:
        write_output_bag(Path(out_bag), series, battery, results)
    plot = None
    if job.extras.get("plot_dir"):
        plot = str(Path(job.extras["plot_dir"]) / f"{job.name}.png")
        plot_results(Path(plot), series, results)
    if job.extras.get("plot"):
        plot = job.extras["plot"]
        plot_results(Path(plot), series, results)
    return job.name, results, plot


def _check(args: argparse.Namespace, inputs: list[Path | str], estimators: list[str]) -> None:
    if args.scheduler is not None:
        if args.live or args.state is not None:
            raise ReplayError("--scheduler runs offline jobs in any order (not --live, --state)")
        if args.scheduler != LOCAL and (args.plot or args.plot_dir or args.output_bag):
            raise ReplayError(
                "--plot, --plot-dir and --output-bag write where a job runs: with a remote "
                "--scheduler, on the workers; use --scheduler local or the process pool"
            )
    if args.live and any(isinstance(i, str) for i in inputs):
        raise ReplayError("--live reads local recordings (not URLs)")
    if args.output and (len(inputs) > 1 or len(estimators) > 1):
        raise ReplayError("--output needs one input and one estimator")
    if args.plot and len(inputs) > 1:
        raise ReplayError("--plot needs one input; use --plot-dir for several")
    if args.output_bag is not None:
        if len(inputs) > 1:
            raise ReplayError("--output-bag needs one input")
        if args.output_bag.exists():
            raise ReplayError(f"--output-bag {args.output_bag}: exists; give a new directory")
    if args.state is not None and len(estimators) > 1:
        raise ReplayError("--state needs one estimator")
    if args.live and (args.state is not None or args.learn_health):
        raise ReplayError("--state and --learn-health replay offline (not --live)")
    if not (args.filter_rate_hz >= 0.0 and math.isfinite(args.filter_rate_hz)):
        raise ReplayError(f"--filter-rate-hz {args.filter_rate_hz}: expected >= 0")
    if args.live and args.filter_rate_hz > 0.0:
        raise ReplayError("--filter-rate-hz replays offline (not --live)")
    if args.rate is not None and (not args.live or not args.rate > 0):
        raise ReplayError("--rate needs --live and a value > 0")


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        inputs = expand_inputs(args.inputs)
        estimators = sorted(ESTIMATORS) if args.all else [args.estimator]
        _check(args, inputs, estimators)
        if args.plot_dir is not None:
            args.plot_dir.mkdir(parents=True, exist_ok=True)
        extras = {
            "plot_dir": str(args.plot_dir) if args.plot_dir else "",
            "plot": str(args.plot) if args.plot else "",
            "output_bag": str(args.output_bag) if args.output_bag else "",
        }
        base = ReplayJob(
            path=Path(),
            estimators=tuple(estimators),
            params=args.params,
            initial_soc=str(args.initial_soc),
            topic=args.topic,
            sign=CurrentSign(args.current_sign),
            progress=sys.stderr.isatty() if args.progress is None else args.progress,
            live=args.live,
            live_rate=args.rate,
            extras=extras,
            runtime=bool(args.output or args.plot or args.plot_dir),
            health=args.learn_health or args.state is not None,
            state=args.state,
            cells_in_series=args.cells_in_series,
            capacity_ah=args.capacity_ah,
            filter_rate_hz=args.filter_rate_hz,
        )
        jobs = [
            replace(base, path=Path(), url=p) if isinstance(p, str) else replace(base, path=p)
            for p in inputs
        ]
        batched = _batched("never" if args.scheduler is not None else args.batch, jobs)
        rest = [
            replace(j, estimators=tuple(e for e in j.estimators if e != T2rcUkf.name))
            if i in batched
            else j
            for i, j in enumerate(jobs)
        ]
        if args.scheduler is not None:
            done = run_on_dask(_job, rest, args.scheduler, args.jobs)
        elif len(rest) > 1 and args.jobs > 1 and not args.live and args.state is None:
            with ProcessPoolExecutor(max_workers=min(args.jobs, len(rest))) as pool:
                done = list(pool.map(_job, rest))
        else:
            done = [_job(j) for j in rest]
        done = [_merge(jobs[i], d, batched.get(i)) for i, d in enumerate(done)]
    except (SocEstimatorError, OSError, RuntimeError) as exc:
        print(f"soc_replay: error: {exc}", file=sys.stderr)
        return 2
    print(f"{'input':<30} {'estimator':<10} {'MAE%':>7} {'RMSE%':>7} {'max%':>7} {'conv_s':>9}")
    for name, results, plot in done:
        for r in results:
            print(f"{name:<30} {r.estimates.estimator:<10} {_fmt(r.accuracy)}")
        for r in results:
            rejected = ", ".join(f"{k} {v}" for k, v in sorted(r.counts.items())) or "none"
            print(f"  {r.estimates.estimator}: start {r.start}; rejected: {rejected}")
        if plot:
            print(f"  plot: {plot}")
    if args.output:
        write_csv(args.output, done[0][1][0])
        print(f"estimates: {args.output}")
    if args.output_bag:
        print(f"bag: {args.output_bag}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
