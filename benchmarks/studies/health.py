"""Battery health over a pack's life: the learned capacity and R_0 factor mission by mission
(issue 26), and what the SoC gains from them.

Reads the health data ``tools/make_bags.py --aged`` (and ``--sized``) writes (``DIR/packs.yaml``,
the packs' measured C/20 capacity and 5-s resistance, and their missions ``DIR/<pack>_m<k>``;
every one is validation but the ``*_tuning`` packs, on which the OCV's ageing law is
chosen). For each pack, its missions are replayed in order through the hybrid with one state
file, as ``soc_replay --state FILE <pack>_m1 <pack>_m2 ...`` does, so the health learned on a
mission starts the next; a pack of another size than the chemistry's file (``--sized``) gets
the file scaled to its cells and rated capacity, as ``--cells-in-series`` and ``--capacity-ah``
do. Prints, per pack:

* the learned capacity (Ah) and its std after each mission, its error against the measured
  capacity (targets: within 3 % after three missions of an aged pack, within 2 % on the fresh
  one), and the R_0 factor;
* the last mission's SoC MAE and max error with the health learned, beside the hybrid without
  health and coulomb counting from the same start (the targets: MAE <= 1.5 % on the third
  mission of every aged pack; on a scaled pack MAE <= 1 % and a max within coulomb
  counting's + 1 point).

With ``--readings``, per pack instead: every rest reading the capacity's pairs were made of,
as read (through the file's rested OCV) against the reference SoC at the same sample; the
exponent of the OCV's ageing law (``health.capacity.OcvAgeing``) each reading below the file's
``ocv_ageing_below_soc`` implies (``ln((s_true - p) / (s_read - p)) / ln(Q_file / Q_measured)``,
``p`` the pivot) and their least-squares value; and the capacity the same pairs give with the
reference's SoC in place of the readings (the pack's own prior, all pairs in one fit): the
floor the charge count (its sensor's gain and offset) sets under any reading of the rests.
The exponent is chosen on the ``*_tuning`` packs only.

    python benchmarks/studies/health.py /work/health_corpus [--packs lfp_fresh lfp_aged75]
    python benchmarks/studies/health.py /work/health_corpus --readings --packs lfp_aged82_tuning
    python benchmarks/studies/health.py /work/health_corpus --readings --pivot 1 --packs sla_...
"""

from __future__ import annotations

import argparse
import math
import tempfile
from collections.abc import Iterator
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import yaml
from scipy.optimize import minimize_scalar

from soc_estimator_ros.evaluation import Accuracy
from soc_estimator_ros.health import CapacityPair, fit_capacity
from soc_estimator_ros.health.monitor import capacity_ageing
from soc_estimator_ros.params import BatteryParams, load_battery_params
from soc_estimator_ros.recordings import read_recording
from soc_estimator_ros.replay.run import ReplayResult, battery_file_for, replay_estimator
from soc_estimator_ros.scaling import scale_to_pack
from soc_estimator_ros.series import BatterySeries
from soc_estimator_ros.tracking.persistence import load_state

#: The estimate's start: the missions begin rested at full (``tools/make_bags.py``), so the
#: OCV reads it; the state file carries the health, not the SoC (docs/replay.md).
INITIAL_SOC = "ocv"


@dataclass(frozen=True)
class Learned:
    mission: str
    capacity_ah: float
    capacity_std_ah: float
    r0_factor: float


def missions_of(data_dir: Path, pack: str) -> list[Path]:
    """The pack's missions in order (``<pack>_m1``, ``_m2``, ...)."""
    found = sorted(data_dir.glob(f"{pack}_m*"), key=lambda p: int(p.name.rsplit("_m", 1)[1]))
    return [p for p in found if (p / "bag.yaml").exists()]


def split_of(missions: list[Path]) -> str:
    """The pack's split as its first mission's bag.yaml states it (tuning or validation)."""
    meta = yaml.safe_load((missions[0] / "bag.yaml").read_text())
    return str(meta.get("split", "unknown"))


def pack_battery(series: BatterySeries, pack: dict | None) -> BatteryParams:
    """The battery file of a mission, scaled to ``pack`` (a ``packs.yaml`` entry: its
    ``cells_in_series`` and ``design_capacity_ah``) when given."""
    battery = load_battery_params(battery_file_for(series))
    if pack is None:
        return battery
    return scale_to_pack(battery, int(pack["cells_in_series"]), float(pack["design_capacity_ah"]))


@dataclass(frozen=True)
class Reading:
    mission: str
    t_s: float
    soc_read: float
    soc_std: float
    soc_ref: float


def ref_soc_at(series: BatterySeries, t_s: float) -> float:
    """The reference SoC at the sample nearest ``t_s``."""
    k = int(np.argmin(np.abs(np.asarray(series.t_s, dtype=float) - t_s)))
    return float(np.asarray(series.soc_ref)[k])


def replayed(
    missions: list[Path], estimator: str, pack: dict | None
) -> Iterator[tuple[Path, BatterySeries, BatteryParams, ReplayResult, Path]]:
    """The missions replayed in order through ``estimator`` with one state file, as
    ``soc_replay --state FILE`` does (``pack``: the ``packs.yaml`` entry the file is scaled
    to): each mission's path, recording, battery file, result and the state file after it."""
    with tempfile.TemporaryDirectory() as tmp:
        state = Path(tmp) / "state.yaml"
        for path in missions:
            series = read_recording(path)
            battery = pack_battery(series, pack)
            result = replay_estimator(
                series, battery, estimator, INITIAL_SOC, path.name, state=state
            )
            yield path, series, battery, result, state


def readings_of(
    missions: list[Path], estimator: str, pack: dict | None
) -> tuple[list[Reading], list[CapacityPair], list[CapacityPair], BatteryParams]:
    """Every reading of the capacity's pairs over the pack's life (:func:`replayed`) against
    the reference SoC, the pairs as made and the same pairs with the reference's SoC in place
    of the readings, and the battery file."""
    readings: dict[tuple[str, float], Reading] = {}
    made: list[CapacityPair] = []
    truth: list[CapacityPair] = []
    battery: BatteryParams | None = None
    for path, series, mission_battery, result, _ in replayed(missions, estimator, pack):
        battery = mission_battery  # the same file for every mission of one pack
        for p in result.health_pairs:
            for t_s, s, var in (
                (p.t_from_s, p.soc_from, p.soc_from_var),
                (p.t_to_s, p.soc_to, p.soc_to_var),
            ):
                readings[(path.name, t_s)] = Reading(
                    path.name, t_s, s, math.sqrt(var), ref_soc_at(series, t_s)
                )
            made.append(p)
            truth.append(
                replace(
                    p,
                    soc_from=ref_soc_at(series, p.t_from_s),
                    soc_to=ref_soc_at(series, p.t_to_s),
                )
            )
    assert battery is not None  # missions is not empty (missions_of)
    return list(readings.values()), made, truth, battery


def exponent_fit(points: list[tuple[float, float, float]], pivot: float) -> float:
    """The exponent ``k`` of the OCV's ageing law by least squares of ``p + (s_read - p)
    ratio^k`` against ``s_ref`` over ``points`` ``(s_read, s_ref, Q_file / Q_measured)``."""
    fit = minimize_scalar(
        lambda k: sum((pivot + (s - pivot) * x**k - ref) ** 2 for s, ref, x in points),
        bounds=(-2.0, 2.0),
        method="bounded",
    )
    return float(fit.x)


def print_readings(
    data_dir: Path, names: list[str], packs: dict, estimator: str, pivot_soc: float | None
) -> None:
    """``--readings`` (module docstring); ``pivot_soc`` the law's pivot (None: the file's)."""
    pooled: dict[str, list[tuple[float, float, float]]] = {}
    pivots: dict[str, float] = {}
    for name in names:
        missions = missions_of(data_dir, name)
        if not missions:
            print(f"{name}: no missions in {data_dir}")
            continue
        measured = float(packs[name]["capacity_ah"])
        readings, made, truth, battery = readings_of(missions, estimator, packs[name])
        h = battery.health
        ratio = battery.capacity_ah / measured
        print(
            f"{name} ({split_of(missions)}): measured {measured:.3f} Ah, "
            f"file {battery.capacity_ah:.3f} Ah"
        )
        print("| mission | t s | read % (std) | reference % | read - reference | exponent |")
        print("|---|---|---|---|---|---|")
        below: list[tuple[float, float, float]] = []
        pivot = h.ocv_ageing_pivot_soc if pivot_soc is None else pivot_soc
        pivots[battery.chemistry] = pivot
        for r in sorted(readings, key=lambda r: (r.mission, r.t_s)):
            k = "-"
            # a reading at the pivot carries no exponent (the law leaves it where it is)
            informative = abs(r.soc_read - pivot) > 1e-3 and abs(r.soc_ref - pivot) > 1e-3
            if r.soc_read < h.ocv_ageing_below_soc and informative and abs(math.log(ratio)) > 1e-3:
                k = f"{math.log((r.soc_ref - pivot) / (r.soc_read - pivot)) / math.log(ratio):.2f}"
                below.append((r.soc_read, r.soc_ref, ratio))
            print(
                f"| {r.mission} | {r.t_s:.0f} | {100 * r.soc_read:.2f} ({100 * r.soc_std:.2f}) | "
                f"{100 * r.soc_ref:.2f} | {100 * (r.soc_read - r.soc_ref):+.2f} | {k} |"
            )
        if below:
            print(
                f"exponent, least squares over the {len(below)} readings below "
                f"{h.ocv_ageing_below_soc:g}: {exponent_fit(below, pivot):.3f}"
            )
            pooled.setdefault(battery.chemistry, []).extend(below)
        prior_var = (h.capacity_std_frac * battery.capacity_ah) ** 2
        fits = (("as read", made, capacity_ageing(battery)), ("at the reference SoC", truth, None))
        for label, pairs, ageing in fits:
            q, var = fit_capacity(pairs, battery.capacity_ah, prior_var, ageing)
            print(
                f"capacity from the {len(pairs)} pairs {label}: {q:.3f} +- {math.sqrt(var):.3f} Ah"
                f" ({100 * (q / measured - 1):+.1f} %)"
            )
        print()
    for chemistry, points in pooled.items():
        print(
            f"{chemistry}: exponent, least squares over the {len(points)} readings of these "
            f"packs: {exponent_fit(points, pivots[chemistry]):.3f}"
        )


def life(
    missions: list[Path], estimator: str, pack: dict | None = None
) -> tuple[list[Learned], dict[str, Accuracy]]:
    """The pack's life (:func:`replayed`): the health after each mission and the last
    mission's accuracy with health, without it, and by coulomb counting."""
    learned: list[Learned] = []
    last: dict[str, Accuracy] = {}
    for path, series, battery, result, state in replayed(missions, estimator, pack):
        h = load_state(state).health
        assert h is not None  # replay_estimator with a state file writes the health
        learned.append(
            Learned(path.name, h.capacity_ah, math.sqrt(h.capacity_var_ah2), h.r0_factor)
        )
        if path == missions[-1]:
            last[f"{estimator} + health"] = result.accuracy
            for name in (estimator, "coulomb"):
                plain = replay_estimator(series, battery, name, INITIAL_SOC, path.name)
                last[name] = plain.accuracy
    return learned, last


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("data_dir", type=Path, help="tools/make_bags.py --aged --out DIR")
    ap.add_argument("--packs", nargs="*", default=None, help="default: every pack in packs.yaml")
    ap.add_argument("--estimator", default="hybrid")
    ap.add_argument("--readings", action="store_true", help="the rest readings (docstring)")
    ap.add_argument("--pivot", type=float, help="--readings: the law's pivot SoC (the file's)")
    args = ap.parse_args(argv)
    packs_file = args.data_dir / "packs.yaml"
    if not packs_file.exists():
        print(f"{packs_file}: not found (tools/make_bags.py --aged --out {args.data_dir})")
        return 1
    packs = yaml.safe_load(packs_file.read_text())
    names = args.packs or list(packs)
    if args.readings:
        print_readings(args.data_dir, names, packs, args.estimator, args.pivot)
        return 0
    print(
        "| pack | split | measured Ah | learned Ah after each mission (std) | error | R0 factor |"
    )
    print("|---|---|---|---|---|---|")
    accuracy_rows = []
    for name in names:
        missions = missions_of(args.data_dir, name)
        if not missions:
            print(f"| {name} | | no missions in {args.data_dir} | | | |")
            continue
        measured = float(packs[name]["capacity_ah"])
        learned, last = life(missions, args.estimator, packs[name])
        steps = ", ".join(f"{h.capacity_ah:.3f} ({h.capacity_std_ah:.3f})" for h in learned)
        err = 100.0 * (learned[-1].capacity_ah / measured - 1.0)
        print(
            f"| {name} | {split_of(missions)} | {measured:.3f} | {steps} | {err:+.1f} % | "
            f"{learned[-1].r0_factor:.2f} |"
        )
        accuracy_rows.append((name, missions[-1].name, last))
    print()
    print("| mission | " + " | ".join(f"{k} MAE / max %" for k in accuracy_rows[0][2]) + " |")
    print("|---|" + "---|" * len(accuracy_rows[0][2]))
    for _, mission, last in accuracy_rows:
        cells = [
            "n/a" if a is None else f"{100 * a.mae:.2f} / {100 * a.max_abs:.2f}"
            for a in last.values()
        ]
        print(f"| {mission} | " + " | ".join(cells) + " |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
