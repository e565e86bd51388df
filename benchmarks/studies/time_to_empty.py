"""Time to empty on the bundled field runs: what the node predicts against what the reference
took to reach ``limits.soc_min`` (issue 27; measured, not tuned on).

Each field run goes through the tracker as the node runs it (the hybrid; the runtime monitor
with its defaults: a 300-s load window, a prediction every second of sample time). Printed per
run, in minutes:

* at the first sample where the reference SoC is at or below 80, 50 and 30 % (those above
  ``soc_min``): the prediction with its std, the actual time, the error, and whether the
  error is within 1 and 2 std;
* over the run, one prediction a minute while the reference still has to reach ``soc_min``:
  the share within 1 std and within 2 std (68 % and 95 % for a calibrated std), the median
  |error| / actual, and how many were ``inf`` (the window saw no discharge load);
* the same with an oracle load, the actual mean power from that moment to the end of the run
  (no load spread; the std is the SoC's alone): what the model and the SoC estimate leave
  once the load forecast is right.

With ``--stationary`` (the target's missions: a load whose statistics do not change), the
runs are simulated here instead, by the simulator that made the bags (PyBaMM through
``tools/make_bags.PackSim``; run it with the sim venv of bags/README.md): the bundled pack at
an ambient temperature, rested at full, then a constant-power load of :data:`STATIONARY`
(10-s blocks, each block's power the mean times ``1 + 0.25 N(0, 1)``, the current the block's
power over the last voltage, as a DC-DC converter draws) down past ``soc_min``, sampled at
2 Hz through the bundled bags' sensors. Validation only: nothing was tuned on them (seeds
:data:`STATIONARY_SEED` + the case's index, fixed before the first run).

    .venv/bin/python benchmarks/studies/time_to_empty.py [--initial-soc ref|ocv] [--jobs 2]
    /tmp/sim/bin/python benchmarks/studies/time_to_empty.py --stationary
    .venv/bin/python benchmarks/studies/time_to_empty.py --corpus DIR [--split validation]

``--corpus DIR``: the scenario corpus' missions in ``DIR`` (``tools/make_bags.py --corpus``)
whose ``bag.yaml`` names the split (default: validation), as recorded: their loads are not
stationary (drive, idle and seeder phases, rests, opportunity and dock charges); a mission
whose reference does not reach ``soc_min`` is listed and not scored.

About 1-2 minutes per run on one core.
"""

from __future__ import annotations

import argparse
import math
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np
import yaml

ROOT = Path(__file__).resolve().parents[2]  # the checkout (its bags/)

from soc_estimator_ros.evaluation import (  # noqa: E402
    TimeToEmptyScore,
    remaining_time_s,
    score_time_to_empty,
    time_reaching,
)
from soc_estimator_ros.params import load_battery_params  # noqa: E402
from soc_estimator_ros.recordings import read_recording  # noqa: E402
from soc_estimator_ros.replay.run import battery_file_for, tracker_config  # noqa: E402
from soc_estimator_ros.resources import bundled_file  # noqa: E402
from soc_estimator_ros.runtime.prediction import LoadForecast, time_to_empty  # noqa: E402
from soc_estimator_ros.series import BatterySeries  # noqa: E402
from soc_estimator_ros.tracking import GateConfig, Sample, Tracker  # noqa: E402

BAGS = ROOT / "bags"
RUNS = [
    f"{c}_field_run_{r}" for c in ("sla", "lfp") for r in ("1_full_rest", "2_partial", "3_cold")
]
MARKS = (0.8, 0.5, 0.3)
#: Stationary-load runs (``--stationary``): chemistry, ambient degC, mean power in W (SLA 0.5 C,
#: LFP 0.7 C of the nominal capacity at 12.5 V: a robot cruising).
STATIONARY = (("lfp", 25.0, 52.0), ("lfp", 5.0, 52.0), ("sla", 25.0, 31.0), ("sla", 5.0, 31.0))
STATIONARY_SEED = 4200
STATIONARY_RATE_HZ = 2.0
STATIONARY_BLOCK_S = 10.0
STATIONARY_SPREAD = 0.25


def stationary_series(index: int) -> tuple[str, BatterySeries]:
    """Case ``index`` of :data:`STATIONARY`, simulated (module docstring)."""
    import sys

    sys.path.insert(0, str(ROOT / "tools"))
    import make_bags as mb

    chem, ambient_c, power_w = STATIONARY[index]
    rng = np.random.default_rng(STATIONARY_SEED + index)
    pack = mb.PACKS[chem]
    meta = yaml.safe_load((BAGS / f"{chem}_field_run_1_full_rest" / "bag.yaml").read_text())
    capacity_ah = float(meta["reference_capacity_ah"])  # the same pack's C/20 capacity
    sensors = mb.SensorModel.draw(rng)
    sim = mb.PackSim(pack, ambient_c)
    rec = mb.Recording()
    mb.run_segments(sim, [(300.0, mb.REST_A)], rec, STATIONARY_RATE_HZ)
    soc_end = load_battery_params(bundled_file(chem)).limits.soc_min - 0.03
    v_min = load_battery_params(bundled_file(chem)).limits.voltage_min_v
    while 1.0 - sim.discharged_ah / capacity_ah > soc_end and sim.last_v > v_min:
        p_w = power_w * max(0.1, 1.0 + STATIONARY_SPREAD * rng.normal())
        mb.run_segments(sim, [(STATIONARY_BLOCK_S, p_w / sim.last_v)], rec, STATIONARY_RATE_HZ)
    t, i, v, q = rec.arrays()
    i_m, v_m, temp_m = sensors.measure(rng, i, v, rec.temperatures())
    series = BatterySeries(
        t_s=t - t[0],
        stamp_ns=(1_700_000_000 * 10**9 + np.round(t * 1e9)).astype(np.int64),
        current_a=i_m,
        voltage_v=v_m,
        temperature_c=temp_m,
        soc_ref=1.0 - q / capacity_ah,
        reference_capacity_ah=capacity_ah,
    )
    return f"{chem}_stationary_{ambient_c:g}C_{power_w:g}W", series


def run_one(args: tuple[str | int, str]) -> dict:
    """One run (a field run's name, or a :data:`STATIONARY` index): the node's predictions and
    the oracle-load ones, per sample."""
    which, initial_soc = args
    if isinstance(which, int):
        name, series = stationary_series(which)
        battery = load_battery_params(bundled_file(name.split("_")[0]))
    else:
        path = Path(which) if Path(which).is_absolute() else BAGS / which
        name, series = path.name, read_recording(path)
        battery = load_battery_params(battery_file_for(series))
    config = tracker_config(series, "hybrid", initial_soc, runtime=True)
    tracker = Tracker(battery, GateConfig.from_limits(battery.limits), config)
    n = len(series)
    t = series.t_s
    power = series.current_a * series.voltage_v
    dt = np.diff(t, append=t[-1])
    energy_left = np.cumsum((power * dt)[::-1])[::-1]  # J from each sample to the end
    soc_min = battery.limits.soc_min
    assert series.soc_ref is not None
    t_end = time_reaching(t, series.soc_ref, soc_min)
    pred, std, oracle, oracle_std = (np.full(n, math.nan) for _ in range(4))
    report = None
    o = (math.nan, math.nan)
    for k in range(n):
        temp = float(series.temperature_c[k])
        r = tracker.process(
            Sample(
                int(series.stamp_ns[k]),
                float(series.current_a[k]),
                float(series.voltage_v[k]),
                temp,
            )
        )
        if r.runtime is not None:
            report = r.runtime
            if t_end is not None and t[k] < t_end and r.estimate is not None:
                remaining = t_end - t[k]
                end = int(np.searchsorted(t, t_end))
                mean_p = (energy_left[k] - energy_left[end]) / remaining
                mon = tracker.runtime
                state = mon.pack_state(r.estimate, tracker.estimator, temp)
                tte = time_to_empty(mon.model, state, soc_min, LoadForecast(mean_p, 0.0, 5, 60.0))
                o = (tte.time_s, tte.std_s)
        if report is not None:
            pred[k], std[k] = report.time_to_empty_s, report.time_to_empty_std_s
        oracle[k], oracle_std[k] = o
    window = score_time_to_empty(t, pred, std, series.soc_ref, soc_min, MARKS)
    ideal = score_time_to_empty(t, oracle, oracle_std, series.soc_ref, soc_min, MARKS)
    actual = remaining_time_s(t, series.soc_ref, soc_min)
    return {
        "name": name,
        "soc_min": soc_min,
        "reaches": t_end is not None,
        "end_ref": float(series.soc_ref[-1]),
        "window": window,
        "oracle": ideal,
        "duration_min": float(np.nanmax(actual)) / 60 if t_end is not None else math.nan,
    }


def corpus_missions(directory: Path, split: str) -> list[Path]:
    """The corpus missions in ``directory`` whose ``bag.yaml`` says ``split: <split>``."""
    out = []
    for d in sorted(p for p in directory.iterdir() if (p / "bag.yaml").is_file()):
        meta = yaml.safe_load((d / "bag.yaml").read_text()) or {}
        if meta.get("kind") == "mission" and meta.get("split") == split:
            out.append(d)
    return out


def fmt_marks(score: TimeToEmptyScore | None) -> list[str]:
    out = []
    for mark, p, s, a in score.marks if score else ():
        err = p - a
        within = "1σ" if abs(err) <= s else "2σ" if abs(err) <= 2 * s else "out"
        out.append(
            f"{100 * mark:.0f} %: {p / 60:6.1f} ± {s / 60:5.1f} vs {a / 60:5.1f} min "
            f"(error {err / 60:+6.1f} min, {100 * err / a:+5.0f} %, {within})"
        )
    return out


def fmt_cover(score: TimeToEmptyScore | None) -> str:
    if score is None or not score.n:
        return "no prediction scored"
    return (
        f"{score.n} predictions: within 1σ {100 * score.within_1sigma:.0f} %, within 2σ "
        f"{100 * score.within_2sigma:.0f} %, median |error| {100 * score.median_abs_rel_error:.0f} "
        f"% of the actual; inf {score.infinite}"
    )


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--initial-soc", default="ref", help="ref (the default) or ocv")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--runs", default=",".join(RUNS))
    ap.add_argument(
        "--stationary", action="store_true", help="simulated stationary-load runs instead"
    )
    ap.add_argument("--corpus", type=Path, help="a directory of corpus missions instead")
    ap.add_argument("--split", default="validation", help="with --corpus: this split only")
    args = ap.parse_args()
    which: list[str | int] = (
        list(range(len(STATIONARY))) if args.stationary else args.runs.split(",")
    )
    if args.corpus is not None:
        which = [str(d.resolve()) for d in corpus_missions(args.corpus, args.split)]
    runs = [(r, args.initial_soc) for r in which]
    with ProcessPoolExecutor(max_workers=args.jobs) as pool:
        results = list(pool.map(run_one, runs))
    print(f"hybrid, start {args.initial_soc}; node defaults (300-s window, 1 prediction/s)")
    pooled: dict[str, list[tuple[float, float, float]]] = {"window": [], "oracle": []}
    for res in results:
        print(f"\n{res['name']} (soc_min {res['soc_min']:g}):", end=" ")
        if not res["reaches"]:
            print(f"the reference never reaches soc_min (ends at {res['end_ref']:.4f})")
            continue
        print(f"the reference reaches it after {res['duration_min']:.1f} min")
        for kind in ("window", "oracle"):
            score = res[kind]
            print(f"  {kind}: {fmt_cover(score)}")
            for line in fmt_marks(score):
                print(f"    {line}")
            pooled[kind] += [(p, s, a) for _, p, s, a in (score.marks if score else ())]
    for kind, marks in pooled.items():
        if not marks:
            continue
        err = np.array([p - a for p, _, a in marks])
        sig = np.array([s for _, s, _ in marks])
        rel = np.abs(err) / np.array([a for _, _, a in marks])
        med = np.median(np.abs(err)) / 60
        print(
            f"\n{kind}, the {len(marks)} marks pooled: median |error| {med:.1f} "
            f"min ({100 * np.median(rel):.0f} %), within 1σ {np.mean(np.abs(err) <= sig):.0%}, "
            f"within 2σ {np.mean(np.abs(err) <= 2 * sig):.0%}"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
