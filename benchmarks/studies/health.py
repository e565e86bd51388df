"""Battery health over a pack's life: the learned capacity and R_0 factor mission by mission
(issue 26), and what the SoC gains from them.

Reads the health data ``tools/make_bags.py --aged`` (and ``--sized``) writes (``DIR/packs.yaml``,
the packs' measured C/20 capacity and 5-s resistance, and their missions ``DIR/<pack>_m<k>``;
every one is validation: nothing is tuned on them). For each pack, its missions are replayed
in order through the hybrid with one state file, as ``soc_replay --state FILE <pack>_m1
<pack>_m2 ...`` does, so the health learned on a mission starts the next; a pack of another
size than the chemistry's file (``--sized``) gets the file scaled to its cells and rated
capacity, as ``--cells-in-series`` and ``--capacity-ah`` do. Prints, per pack:

* the learned capacity (Ah) and its std after each mission, its error against the measured
  capacity (targets: within 3 % after three missions of an aged pack, within 2 % on the fresh
  one), and the R_0 factor;
* the last mission's SoC MAE and max error with the health learned, beside the hybrid without
  health and coulomb counting from the same start (the targets: MAE <= 1.5 % on the third
  mission of every aged pack; on a scaled pack MAE <= 1 % and a max within coulomb
  counting's + 1 point).

    python benchmarks/studies/health.py /work/health_corpus [--packs lfp_fresh lfp_aged75]
"""

from __future__ import annotations

import argparse
import math
import tempfile
from dataclasses import dataclass
from pathlib import Path

import yaml

from soc_estimator_ros.evaluation import Accuracy
from soc_estimator_ros.params import BatteryParams, load_battery_params
from soc_estimator_ros.recordings import read_recording
from soc_estimator_ros.replay.run import battery_file_for, replay_estimator
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


def pack_battery(series: BatterySeries, pack: dict | None) -> BatteryParams:
    """The battery file of a mission, scaled to ``pack`` (a ``packs.yaml`` entry: its
    ``cells_in_series`` and ``design_capacity_ah``) when given."""
    battery = load_battery_params(battery_file_for(series))
    if pack is None:
        return battery
    return scale_to_pack(battery, int(pack["cells_in_series"]), float(pack["design_capacity_ah"]))


def life(
    missions: list[Path], estimator: str, pack: dict | None = None
) -> tuple[list[Learned], dict[str, Accuracy]]:
    """The missions replayed in order with one state file; the health after each and the
    last mission's accuracy with health, without it, and by coulomb counting (``pack``: the
    ``packs.yaml`` entry the file is scaled to)."""
    learned: list[Learned] = []
    last: dict[str, Accuracy] = {}
    with tempfile.TemporaryDirectory() as tmp:
        state = Path(tmp) / "state.yaml"
        for k, path in enumerate(missions):
            series = read_recording(path)
            battery = pack_battery(series, pack)
            result = replay_estimator(
                series, battery, estimator, INITIAL_SOC, path.name, state=state
            )
            h = load_state(state).health
            assert h is not None  # replay_estimator with a state file writes the health
            learned.append(
                Learned(path.name, h.capacity_ah, math.sqrt(h.capacity_var_ah2), h.r0_factor)
            )
            if k == len(missions) - 1:
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
    args = ap.parse_args(argv)
    packs_file = args.data_dir / "packs.yaml"
    if not packs_file.exists():
        print(f"{packs_file}: not found (tools/make_bags.py --aged --out {args.data_dir})")
        return 1
    packs = yaml.safe_load(packs_file.read_text())
    names = args.packs or list(packs)
    print("| pack | measured Ah | learned Ah after each mission (std) | error | R0 factor |")
    print("|---|---|---|---|---|")
    accuracy_rows = []
    for name in names:
        missions = missions_of(args.data_dir, name)
        if not missions:
            print(f"| {name} | no missions in {args.data_dir} | | | |")
            continue
        measured = float(packs[name]["capacity_ah"])
        learned, last = life(missions, args.estimator, packs[name])
        steps = ", ".join(f"{h.capacity_ah:.3f} ({h.capacity_std_ah:.3f})" for h in learned)
        err = 100.0 * (learned[-1].capacity_ah / measured - 1.0)
        print(f"| {name} | {measured:.3f} | {steps} | {err:+.1f} % | {learned[-1].r0_factor:.2f} |")
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
