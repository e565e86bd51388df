"""``soc_tune``: tune a battery file's ``filters`` block on recordings, with cross-validation.

    soc_tune RECORDING [RECORDING ...] --params FILE --output FILE [--estimator hybrid]
             [--space KEY=LO:HI[:log] ...] [--search random|local] [--trials 32]
             [--step 0.15] [--rounds 1] [--folds 3] [--seed 0] [--wrong-start 0.3] [--jobs N]
             [--scheduler ADDRESS|local] [--cache FILE]

RECORDING: bags or CSVs with a reference SoC, or directories of bags (as ``soc_replay``).
Every candidate tuning (the file's own, then ``--trials`` random draws from the space, or with
``--search local`` the file's tuning moved by ``--step`` of each dimension's range either way,
``search.py``, repeated from the best move for up to ``--rounds`` rounds, ``compass.py``) is
scored on every recording (``objective.py``); the folds choose and judge as ``crossval.py``
says (a fold walks the whole local search on its training recordings). Printed: each fold's
held-out recordings, the tuning chosen on the others and its held-out score beside the file's;
then the tuning chosen on all recordings. ``--cache FILE`` keeps every score on disk
(``cache.py``): the same command run again, after a stop or with more ``--rounds``, reads the
scores it has and computes only the rest.
It is written to ``--output`` (the input file with that estimator's block updated) only when
its held-out score is no worse than the file's; otherwise nothing is written and the exit
status is 3. The same inputs and seed give the same tuning (exit 0) or the same refusal.
"""

from __future__ import annotations

import argparse
import math
import os
import shlex
import sys
from collections.abc import Callable, Iterable
from concurrent.futures import ProcessPoolExecutor
from functools import cache
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import SocEstimatorError
from ..estimators import DEFAULT_ESTIMATOR, ESTIMATORS, make_estimator
from ..params import (
    BatteryParams,
    battery_params_to_dict,
    load_battery_params,
    output_dir_error,
    write_battery_file,
)
from ..recordings import read_recording
from ..replay.cli import expand_inputs
from ..replay.fleet import run_on_dask
from ..replay.outputs import ProgressBar
from .cache import ScoreCache, context_of
from .compass import ScoreTable, compass_cross_validate
from .crossval import CrossValidation, cross_validate, folds
from .objective import (
    COVERAGE_BAND,
    COVERAGE_WEIGHT,
    HARM_ALLOWANCE_PCT,
    HARM_WEIGHT,
    coulomb_max_pct,
    score_recording,
)
from .search import (
    DEFAULT_SPACES,
    Dimension,
    apply,
    candidates,
    describe,
    parse_dimension,
)

#: Exit status when the tuning is refused (its held-out score is worse than the file's).
REFUSED = 3

Task = tuple[str, str, str, dict[str, float], float]  # recording, file, estimator, values, wrong


@cache
def _recording(path: str):  # one read per process: each recording is scored many times
    return read_recording(Path(path))


@cache
def _battery(path: str):
    return load_battery_params(Path(path))


@cache
def _baseline_max_pct(recording: str, params: str) -> float:  # once per recording and process
    return coulomb_max_pct(_recording(recording), _battery(params))


def _score(task: Task) -> float:
    """One candidate on one recording (a task for the pool or a Dask worker)."""
    recording, params, estimator, values, wrong = task
    battery = _battery(params)
    base = make_estimator(estimator, battery, 0.5, 0.1, battery.filters.get(estimator)).tuning
    tuning = apply(base, values)
    try:
        baseline = _baseline_max_pct(recording, params)
        series = _recording(recording)
        return score_recording(series, battery, estimator, tuning, wrong, baseline).total
    except (FloatingPointError, np.linalg.LinAlgError):
        return math.inf  # a tuning that breaks the filter is the worst


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(
        prog="soc_tune", description="Tune a battery file's filter block with cross-validation."
    )
    ap.add_argument("recordings", nargs="+", help="recordings with a reference SoC, or dirs")
    ap.add_argument("--params", type=Path, required=True, help="the battery file to tune")
    ap.add_argument("--output", type=Path, required=True, help="the tuned battery file")
    ap.add_argument(
        "--estimator",
        default=DEFAULT_ESTIMATOR,
        choices=sorted(ESTIMATORS),
        help=f"whose filters block (default {DEFAULT_ESTIMATOR})",
    )
    ap.add_argument(
        "--space",
        action="append",
        default=[],
        metavar="KEY=LO:HI[:log]",
        help="a searched entry (repeat; KEY.i for element i of a tuple entry); default: the "
        f"estimator's ({', '.join(sorted(DEFAULT_SPACES))})",
    )
    ap.add_argument(
        "--search",
        choices=("random", "local"),
        default="random",
        help="random: --trials draws from the space; local: the file's tuning moved by "
        "--step either way, one dimension at a time (default random)",
    )
    ap.add_argument("--trials", type=int, default=32, help="random candidates (default 32)")
    ap.add_argument(
        "--step",
        type=float,
        default=0.15,
        help="local search: the move, as a fraction of each dimension's range (default 0.15)",
    )
    ap.add_argument(
        "--rounds",
        type=int,
        default=1,
        help="local search: repeat the step from the best move up to this many times, "
        "stopping when no move improves (default 1)",
    )
    ap.add_argument("--folds", type=int, default=3, help="cross-validation folds (default 3)")
    ap.add_argument("--seed", type=int, default=0, help="candidates and folds (default 0)")
    ap.add_argument(
        "--wrong-start",
        type=float,
        default=0.3,
        help="SoC error of the convergence run (default 0.3; 0: none)",
    )
    ap.add_argument("--jobs", type=int, default=os.cpu_count() or 1)
    ap.add_argument("--scheduler", metavar="ADDRESS", help="a Dask cluster, or 'local'")
    ap.add_argument("--progress", action=argparse.BooleanOptionalAction, default=None)
    ap.add_argument(
        "--cache",
        type=Path,
        metavar="FILE",
        help="keep every score in FILE and read the ones it has: a stopped or longer search "
        "resumes (made for other inputs: refused)",
    )
    return ap


def _space(args: argparse.Namespace) -> tuple[Dimension, ...]:
    if args.space:
        return tuple(parse_dimension(t) for t in args.space)
    if args.estimator not in DEFAULT_SPACES:
        raise ValueError(f"{args.estimator} has no default space: give --space KEY=LO:HI")
    return DEFAULT_SPACES[args.estimator]


def _evaluate(
    tasks: list[Task], args: argparse.Namespace, done: Callable[[int, float], None]
) -> None:
    """Score every task: ``done(k, score)`` for each, in order, as it arrives (from a Dask
    cluster, all once the last has)."""
    bar = ProgressBar(f"{len(tasks)} runs", prog="soc_tune")
    show = sys.stderr.isatty() if args.progress is None else args.progress
    if args.scheduler is not None:
        for k, value in enumerate(run_on_dask(_score, tasks, args.scheduler, args.jobs)):
            done(k, value)
        return
    if args.jobs <= 1:
        results: Iterable[float] = map(_score, tasks)
        _collect(results, len(tasks), done, bar if show else None)
        return
    with ProcessPoolExecutor(max_workers=args.jobs) as pool:
        _collect(pool.map(_score, tasks, chunksize=1), len(tasks), done, bar if show else None)


def _collect(
    results: Iterable[float],
    n: int,
    done: Callable[[int, float], None],
    bar: Callable[[int, int], None] | None,
) -> None:
    for k, value in enumerate(results):
        done(k, value)
        if bar is not None:
            bar(k + 1, n)


def _note(line: str) -> None:
    """A progress line on stderr (the report goes to stdout)."""
    print(f"soc_tune: {line}", file=sys.stderr, flush=True)


def report(
    cv: CrossValidation, names: list[str], cands: list[dict[str, float]], moves: list[int]
) -> str:
    """The folds and the verdict; ``moves``: each local walk's moves (folds', then all's)."""
    walked = [f" after {m} move{'s' if m != 1 else ''}" for m in moves]
    walked = walked or [""] * (len(cv.folds) + 1)
    lo, hi = COVERAGE_BAND
    lines = [
        f"objective J = MAE + max/2 + {COVERAGE_WEIGHT:g} x distance of the ±2σ coverage from "
        f"[{lo:g}, {hi:g}] + min(t_converge / 600 s, 3) + {HARM_WEIGHT:g} x max(0, max - "
        f"coulomb max - {HARM_ALLOWANCE_PCT:g}), % SoC (lower is better)"
    ]
    for k, f in enumerate(cv.folds, 1):
        held = ", ".join(names[i] for i in f.held_out)
        lines += [
            f"fold {k}: held out {held}",
            f"  chosen on the others{walked[k - 1]}: {describe(cands[f.chosen])} "
            f"(J {f.train_score:.3f})",
            f"  held out: tuned J {f.held_out_score:.3f}, file's J {f.file_held_out_score:.3f}",
        ]
    lines += [
        f"held-out mean: tuned J {cv.held_out_score:.3f}, file's J {cv.file_held_out_score:.3f}",
        f"chosen on all{walked[-1]}: {describe(cands[cv.chosen])} (J {cv.chosen_score:.3f}; file's "
        f"{cv.file_score:.3f})",
    ]
    return "\n".join(lines)


def _provenance(path: Path) -> list[str]:
    """The leading comment lines of a battery file (how it was made: ``soc_identify``'s
    regenerate command, an earlier ``soc_tune``'s), without the schema pointer; kept in the
    tuned file below its own, so the file says every step that made it."""
    lines = []
    for line in path.read_text().splitlines():
        if not line.startswith("#"):
            break
        if not line.startswith("# Schema:"):
            lines.append(line)
    return lines


def _checked_inputs(
    args: argparse.Namespace,
) -> tuple[list[str], BatteryParams, tuple[Dimension, ...], dict[str, Any]]:
    """The recordings (each with a reference SoC), the battery file, the search space and the
    estimator's tuning as the file gives it; every fault raised before any run."""
    inputs = expand_inputs(args.recordings)
    if any(isinstance(p, str) for p in inputs):
        raise ValueError("soc_tune reads local recordings (fetch URLs first)")
    paths = [str(p) for p in inputs]
    battery = load_battery_params(args.params)
    space = _space(args)
    block0 = battery.filters.get(args.estimator)
    base = make_estimator(args.estimator, battery, 0.5, 0.1, block0).tuning
    for d in space:
        if d.key not in base:
            raise ValueError(
                f"--space {d.label}: {args.estimator} has no tuning entry {d.key!r} "
                f"(known: {', '.join(sorted(base))})"
            )
    apply(base, {d.label: d.lo for d in space})  # a tuple entry's element exists
    folds(len(paths), args.folds, args.seed)  # before any run: k fits the recordings
    for p in paths:
        if read_recording(Path(p)).soc_ref is None:
            raise ValueError(f"{p}: no reference SoC to tune on")
    return paths, battery, space, base


def _scorer(
    args: argparse.Namespace, paths: list[str], store: ScoreCache | None
) -> Callable[[list[dict[str, float]]], np.ndarray]:
    """Scores a batch of tunings on every recording (a row each), from ``store`` where it
    holds the tuning, else by running them (``--jobs`` or ``--dask``), storing each whole row."""

    def evaluate(batch: list[dict[str, float]]) -> np.ndarray:
        rows = np.empty((len(batch), len(paths)))
        todo = []
        for i, c in enumerate(batch):
            cached = None if store is None else store.get(c)
            if cached is None:
                todo.append(i)
            else:
                rows[i] = cached
        tasks: list[Task] = [
            (p, str(args.params), args.estimator, batch[i], args.wrong_start)
            for i in todo
            for p in paths
        ]

        def done(k: int, value: float) -> None:
            i, r = todo[k // len(paths)], k % len(paths)
            rows[i, r] = value
            if store is not None and r == len(paths) - 1:
                store.put(batch[i], rows[i])  # its last recording: the row is whole

        if tasks:
            _evaluate(tasks, args, done)
        return rows

    return evaluate


def _search(
    args: argparse.Namespace,
    table: ScoreTable,
    space: tuple[Dimension, ...],
    base: dict[str, Any],
    recordings: int,
) -> tuple[CrossValidation, list[int]]:
    """The cross-validated search, and each walk's moves: a compass search (``local``), or
    random candidates (no walk)."""
    if args.search == "local":
        return compass_cross_validate(
            table,
            space,
            base,
            args.step,
            args.rounds,
            recordings,
            args.folds,
            args.seed,
            log=_note,
        )
    if args.trials < 1:
        raise ValueError("--trials must be >= 1")
    table.indices(candidates(space, args.trials, args.seed))
    return cross_validate(table.scores, args.folds, args.seed), []


def _tuned_file(
    args: argparse.Namespace,
    battery: BatteryParams,
    space: tuple[Dimension, ...],
    base: dict[str, Any],
    chosen_candidate: dict[str, float],
) -> dict[str, Any]:
    """The battery file with the chosen tuning. Only what the search changed: an entry it left
    as it was stays as the file had it (given, or the code default), so soc_identify, which
    keeps its template's tunings, rewrites the same file from a tuned template."""
    data = battery_params_to_dict(battery)
    block = dict(battery.filters.get(args.estimator, {}))
    chosen = apply(base, chosen_candidate)
    touched = {d.key for d in space if d.label in chosen_candidate}
    block.update({k: chosen[k] for k in sorted(touched) if chosen[k] != base[k]})
    data.setdefault("filters", {})[args.estimator] = {
        k: list(v) if isinstance(v, tuple) else v for k, v in block.items()
    }
    return data


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    if (why := output_dir_error(args.output)) is not None:
        print(f"soc_tune: error: {why}", file=sys.stderr)
        return 2
    try:
        paths, battery, space, base = _checked_inputs(args)
        provenance = _provenance(args.params)
        store = None
        if args.cache is not None:
            context = context_of(args.estimator, args.params, paths, args.wrong_start)
            store = ScoreCache(args.cache, context)
            unread = f" ({store.skipped} unreadable lines skipped)" if store.skipped else ""
            _note(f"--cache {args.cache}: {len(store)} tunings scored before{unread}")
        table = ScoreTable(_scorer(args, paths, store))
        cv, moves = _search(args, table, space, base, len(paths))
        cands = table.candidates
    except (SocEstimatorError, ValueError, KeyError, IndexError, TypeError, OSError) as exc:
        print(f"soc_tune: error: {exc}", file=sys.stderr)
        return 2
    names = [Path(p).name for p in paths]
    print(report(cv, names, cands, moves))
    if not cv.accepted:
        print(
            f"soc_tune: refused: the tuning's held-out J {cv.held_out_score:.3f} is worse than "
            f"the file's {cv.file_held_out_score:.3f}; nothing written",
            file=sys.stderr,
        )
        return REFUSED
    data = _tuned_file(args, battery, space, base, cands[cv.chosen])
    command = shlex.join(["soc_tune", *(argv if argv is not None else sys.argv[1:])])
    header = (
        f"# Tuned by soc_tune ({args.estimator}) on {', '.join(names)}: held-out J "
        f"{cv.held_out_score:.3f} vs the file's {cv.file_held_out_score:.3f}.\n"
        f"# Regenerate: {command}\n"
        + "".join(f"# From {args.params.name}: {line[1:].lstrip()}\n" for line in provenance)
    )
    try:  # a tuning the battery files' rules refuse writes nothing
        write_battery_file(args.output, data, header)
    except (SocEstimatorError, OSError) as exc:
        print(f"soc_tune: error: {exc}", file=sys.stderr)
        return 2
    print(f"wrote {args.output}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
