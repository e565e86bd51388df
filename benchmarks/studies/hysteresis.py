"""The OCV's charge/discharge hysteresis on a hysteretic LFP pack (issue 24, item 4).

The pack is ``tools/make_bags.py --hysteresis``'s: the bundled LFP pack with PyBaMM's own
hysteresis on its LFP electrode. Two battery files for it, alike but for the hysteresis
(:func:`identified`): **without** it (what discharge tests give today) and **with** it, fitted
on its two-way pulse test (``lfp_hysteresis_test``) as ``soc_identify --hysteresis-test``
fits it. Each mission (``lfp_hysteresis_mission_*``,
none of them seen by the identification or by any tuning: the hybrid's tunings are the
bundled LFP file's) is replayed through the tracker (where the hysteresis lives) from the true
SoC (std 0.1, as ``do_no_harm.py``), beside coulomb counting from the same start:

* ``no hysteresis``: the file without it;
* ``hysteresis, start unknown``: the file with it, the branch unknown at the start (a node
  without its state file);
* ``hysteresis, start known``: the branch the mission starts on (its ``bag.yaml``), as a node
  resuming its state file knows it.

Error after the 10-minute window, points of SoC; margin = hybrid max - coulomb max (issue
24's do-no-harm rule: <= 1); coverage = % of samples within +-2 sigma.

    python benchmarks/studies/hysteresis.py [--bags /work/hyst_bags /work/hyst_corpus] [--jobs 2]

``--bags``: directories of the hysteretic pack's missions (``tools/make_bags.py --hysteresis``,
and ``--corpus --hysteresis --chemistry lfp``: the scenario corpus's draws on this pack, split
by seed as the corpus is); the summary counts issue 24's targets per split.
"""

from __future__ import annotations

import argparse
import sys
from concurrent.futures import ProcessPoolExecutor
from dataclasses import replace
from pathlib import Path

import numpy as np
import yaml

from soc_estimator_ros.identification.hysteresis import fit_hysteresis
from soc_estimator_ros.params import BatteryParams, load_battery_params
from soc_estimator_ros.recordings import read_recording
from soc_estimator_ros.replay.run import track_series_runtime
from soc_estimator_ros.resources import bundled_file
from soc_estimator_ros.runtime.monitor import RuntimeConfig
from soc_estimator_ros.series import BatterySeries
from soc_estimator_ros.tracking import GateConfig, Tracker, TrackerConfig

sys.path.insert(0, str(Path(__file__).resolve().parent))

from do_no_harm import summary  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
WINDOW_S = 600.0
INITIAL_SOC_STD = 0.1


def shifted(battery: BatteryParams, offset_v: float) -> BatteryParams:
    """``battery`` with its OCV tables (``ocv``, ``rest_ocv``) moved by ``offset_v``."""

    def move(table):
        return replace(table, voltage_v=tuple(v + offset_v for v in table.voltage_v))

    rest = None if battery.rest_ocv is None else move(battery.rest_ocv)
    return replace(battery, ocv=move(battery.ocv), rest_ocv=rest)


def identified(two_way: BatterySeries) -> tuple[BatteryParams, BatteryParams, list[str]]:
    """The pack's file without and with the hysteresis, and what the fits said.

    The hysteretic pack is the bundled LFP pack's cell with its LFP OCP split into two
    branches; its discharge tests (pulse, rate, load, slow discharge) would give the bundled
    file's tables but for the OCV, which they read on the discharge branch. So the file
    without hysteresis is the bundled one with its OCV moved by what the two-way test's rests
    say both branches share (the fit's ``c``), the file with it that plus the fitted hysteresis
    (``c`` takes the common offset out of the fit, so the gap and rate are those the moved
    file gives: the same to the last bit, measured)."""
    bundled = load_battery_params(bundled_file("lfp"))
    fit = fit_hysteresis(bundled, two_way, [])
    if fit.hysteresis is None:
        raise SystemExit(f"hysteresis not identified: {fit.why}")
    plain = shifted(bundled, fit.offset_v)
    h = fit.hysteresis
    lines = [
        f"the bundled file's OCV against the two-way test's rests: {1000 * fit.offset_v:+.1f}"
        " mV off both branches alike: moved by it",
        f"identified: gap {1000 * h.gap_v:.1f} mV (se {1000 * fit.gap_se_v:.1f}), rate "
        f"{h.rate_per_soc:.0f}/SoC; rests' residual with c {1000 * fit.rms_after_v:.1f} mV RMS",
    ]
    return plain, replace(plain, hysteresis=h), lines


def run(
    battery: BatteryParams, series: BatterySeries, estimator: str, branch: float | None
) -> tuple[np.ndarray, np.ndarray]:
    """SoC and std through the tracker from the true start (std 0.1)."""
    assert series.soc_ref is not None
    config = TrackerConfig(
        runtime=RuntimeConfig(predict_period_s=0.0),  # no predictions: not scored here
        estimator=estimator,
        initial_soc=float(np.clip(series.soc_ref[0], 0.0, 1.0)),
        initial_soc_std=INITIAL_SOC_STD,
        initial_branch=branch,
    )
    tracker = Tracker(battery, GateConfig.from_limits(battery.limits), config)
    est, _, _ = track_series_runtime(series, tracker)
    return est.soc, est.soc_std


def scores(series: BatterySeries, soc: np.ndarray, std: np.ndarray) -> tuple[float, ...]:
    """MAE, max (points) and 2-sigma coverage (%) after the window."""
    assert series.soc_ref is not None
    after = (series.t_s >= WINDOW_S) & np.isfinite(series.soc_ref) & np.isfinite(soc)
    err = np.abs(soc[after] - series.soc_ref[after])
    return (
        100 * float(np.mean(err)),
        100 * float(np.max(err)),
        100 * float(np.mean(err <= 2.0 * std[after])),
    )


def missions_in(roots: list[Path]) -> list[Path]:
    """The hysteretic pack's missions under ``roots``: ``kind: mission`` with a ``hysteresis``
    block in bag.yaml (``--hysteresis``'s and ``--corpus --hysteresis``'s)."""
    out = []
    for root in roots:
        for meta_path in sorted(root.glob("*/bag.yaml")):
            meta = yaml.safe_load(meta_path.read_text()) or {}
            if meta.get("kind") == "mission" and "hysteresis" in meta:
                out.append(meta_path.parent)
    return out


def row(args: tuple[Path, BatteryParams, BatteryParams]) -> tuple[str, str, list[float]]:
    """One mission: its split and, in the table's order, coulomb MAE and max, then MAE, max,
    margin and coverage of the three hybrid runs."""
    path, plain, hyst = args
    series = read_recording(path)
    meta = yaml.safe_load((path / "bag.yaml").read_text()) or {}
    h0 = meta["hysteresis"].get("state_start")  # PyBaMM's h: -1 .. +1
    branch = None if h0 is None else (float(h0) + 1.0) / 2.0
    cc = scores(series, *run(plain, series, "coulomb", None))
    values = [cc[0], cc[1]]
    for battery, b in ((plain, None), (hyst, None), (hyst, branch)):
        mae, mx, cov = scores(series, *run(battery, series, "hybrid", b))
        values += [mae, mx, mx - cc[1], cov]
    return path.name, str(meta.get("split", "?")), values


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--bags", type=Path, nargs="+", default=[Path("/work/hyst_bags")])
    ap.add_argument("--jobs", type=int, default=1)
    args = ap.parse_args()
    missions = missions_in(args.bags)
    if not missions:
        print(f"no missions of the hysteretic pack under {args.bags}", file=sys.stderr)
        return 2
    two_way = ROOT / "bags" / "lfp_hysteresis_test"
    plain, hyst, lines = identified(read_recording(two_way))
    print("\n".join(lines))
    print(
        "| Mission | split | coulomb MAE / max | no hysteresis: MAE / max / margin / coverage | "
        "hysteresis, start unknown | hysteresis, start known |"
    )
    print("|---|---|---|---|---|---|")
    jobs = [(path, plain, hyst) for path in missions]
    with ProcessPoolExecutor(max_workers=args.jobs) as pool:
        rows = list(pool.map(row, jobs))
    for name, split, v in rows:
        runs = [
            f"{v[k]:.2f} / {v[k + 1]:.2f} / {v[k + 2]:+.2f} / {v[k + 3]:.0f}" for k in (2, 6, 10)
        ]
        print(f"| {name} | {split} | {v[0]:.2f} / {v[1]:.2f} | " + " | ".join(runs) + " |")
    print()
    # Issue 24's targets counted as do_no_harm.py counts them, one "estimator" per run.
    names = ("no hysteresis", "hysteresis, start unknown", "hysteresis, start known")
    scored = [
        {
            "estimator": name,
            "split": split,
            "mae": v[k],
            "max": v[k + 1],
            "margin": v[k + 2],
            "coverage": v[k + 3],
            "cc_mae": v[0],
        }
        for _, split, v in rows
        for name, k in zip(names, (2, 6, 10), strict=True)
    ]
    for line in summary(scored):
        print(line)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
