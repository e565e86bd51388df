"""The OCV's charge/discharge hysteresis on a hysteretic LFP pack (issue 24, item 4).

The pack is ``tools/make_bags.py --hysteresis``'s: the bundled LFP pack with PyBaMM's own
hysteresis on its LFP electrode. Its battery files are identified from its own tests, as a
robot owner would (``soc_identify``): **without** the hysteresis (its discharge pulse test and
slow discharge: what the tests hold today) and **with** it (the same, plus
``--hysteresis-test`` on its two-way pulse test). Each mission (``lfp_hysteresis_mission_*``,
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

    python benchmarks/studies/hysteresis.py [--bags /work/hyst_bags]
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import yaml

from soc_estimator_ros.identification.cli import identify_tests
from soc_estimator_ros.identification.hysteresis import fit_hysteresis
from soc_estimator_ros.params import BatteryParams, load_battery_params
from soc_estimator_ros.recordings import read_recording
from soc_estimator_ros.replay.run import track_series_runtime
from soc_estimator_ros.resources import bundled_file
from soc_estimator_ros.series import BatterySeries
from soc_estimator_ros.tracking import GateConfig, Tracker, TrackerConfig

ROOT = Path(__file__).resolve().parents[2]
WINDOW_S = 600.0
INITIAL_SOC_STD = 0.1


def identified(bags: Path) -> tuple[BatteryParams, BatteryParams, str]:
    """The pack's file without and with the hysteresis, and the fit's report line."""
    pulse = read_recording(bags / "lfp_hysteresis_pulse_test")
    slow = read_recording(bags / "lfp_hysteresis_slow_discharge")
    template = load_battery_params(bundled_file("lfp"))
    plain, results = identify_tests([pulse], None, template, None, slow, None)
    two_way = read_recording(_two_way(bags))
    fit = fit_hysteresis(plain, two_way, results[0].notes)
    if fit.hysteresis is None:
        raise SystemExit(f"hysteresis not identified: {fit.why}")
    h = fit.hysteresis
    line = (
        f"identified: gap {1000 * h.gap_v:.1f} mV (se {1000 * fit.gap_se_v:.1f}), rate "
        f"{h.rate_per_soc:.0f}/SoC; rests' residual {1000 * fit.rms_before_v:.1f} -> "
        f"{1000 * fit.rms_after_v:.1f} mV RMS"
    )
    return plain, replace(plain, hysteresis=h), line


def _two_way(bags: Path) -> Path:
    """The two-way test: beside the missions, else the bundled one."""
    here = bags / "lfp_hysteresis_test"
    return here if here.exists() else ROOT / "bags" / "lfp_hysteresis_test"


def run(
    battery: BatteryParams, series: BatterySeries, estimator: str, branch: float | None
) -> tuple[np.ndarray, np.ndarray]:
    """SoC and std through the tracker from the true start (std 0.1)."""
    assert series.soc_ref is not None
    config = TrackerConfig(
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


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--bags", type=Path, default=Path("/work/hyst_bags"))
    args = ap.parse_args()
    missions = sorted(args.bags.glob("lfp_hysteresis_mission_*"))
    if not missions:
        print(f"no lfp_hysteresis_mission_* under {args.bags}", file=sys.stderr)
        return 2
    plain, hyst, line = identified(args.bags)
    print(line)
    print(
        "| Mission | coulomb MAE / max | no hysteresis: MAE / max / margin / coverage | "
        "hysteresis, start unknown | hysteresis, start known |"
    )
    print("|---|---|---|---|---|")
    for path in missions:
        series = read_recording(path)
        meta = yaml.safe_load((path / "bag.yaml").read_text()) or {}
        branch = meta.get("hysteresis", {}).get("initial_branch")
        cc = scores(series, *run(plain, series, "coulomb", None))
        cells = [f"{cc[0]:.2f} / {cc[1]:.2f}"]
        for battery, b in ((plain, None), (hyst, None), (hyst, branch)):
            mae, mx, cov = scores(series, *run(battery, series, "hybrid", b))
            cells.append(f"{mae:.2f} / {mx:.2f} / {mx - cc[1]:+.2f} / {cov:.0f}")
        print(f"| {path.name} | " + " | ".join(cells) + " |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
