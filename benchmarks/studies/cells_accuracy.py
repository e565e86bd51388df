"""Per-cell SoC on the bundled 4S missions (issue 25, docs/cells.md): replay each
``bags/lfp4s_cells_*`` as the node runs it (hybrid, started from the OCV of the first sample)
and print, after the 10-minute window, every cell's SoC MAE and max, the usable SoC's MAE
and max, the weakest cell at the end (estimated and true), and at the first cell's cut-off
(the mission's end, where a mission ran a cell empty) the usable SoC estimated and true.

    PYTHONPATH=. .venv/bin/python benchmarks/studies/cells_accuracy.py [bag ...] [--initial-soc ref]
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml

from soc_estimator_ros.params import load_battery_params
from soc_estimator_ros.recordings import read_battery_bag
from soc_estimator_ros.replay.run import replay_estimator

ROOT = Path(__file__).resolve().parents[2]
WINDOW_S = 600.0
#: The mission the cell filter's settings were chosen on (docs/cells.md); the others validate.
TUNING = ("lfp4s_cells_1_full",)


@dataclass(frozen=True)
class CellScore:
    name: str
    cell_mae: np.ndarray  # fraction, per cell
    cell_max: np.ndarray
    usable_mae: float
    usable_max: float
    weakest_est: int  # 1-based
    weakest_true: int
    usable_at_cutoff_est: float | None  # None: the mission ran no cell empty
    usable_at_cutoff_true: float | None
    coverage_2sigma: float  # cells within 2 std after the window


def score_bag(bag: Path, initial_soc: str = "ocv") -> CellScore:
    """One mission through the replay's tracker (the node's path), started as
    ``soc_replay --initial-soc`` (``ocv``: the node's boot; ``ref``: the true start)."""
    series = read_battery_bag(bag)
    meta = yaml.safe_load((bag / "bag.yaml").read_text())
    battery = load_battery_params(ROOT / "config" / "lfp_12v6ah.yaml")
    assert series.cell_soc_ref is not None
    if initial_soc == "ref":  # the pack's filter estimates the average cell: start it there
        initial_soc = repr(float(np.mean(series.cell_soc_ref[0])))
    r = replay_estimator(series, battery, "hybrid", initial_soc, bag.name)
    e = r.estimates
    assert e.cell_soc is not None and e.cell_soc_std is not None
    assert series.cell_soc_ref is not None and series.soc_ref is not None
    win = series.t_s >= WINDOW_S
    err = e.cell_soc - series.cell_soc_ref
    caps = np.asarray(meta["cells"]["capacity_ah"])
    weakest_true = int(np.argmin(series.cell_soc_ref[-1] * caps)) + 1
    # The estimate's weakest: the least remaining charge, as cells/bank.py ranks it.
    weakest_est = int(np.argmin(e.cell_soc[-1])) + 1
    cut = meta["cells"].get("first_cutoff_s") is not None
    return CellScore(
        bag.name,
        np.mean(np.abs(err[win]), axis=0),
        np.max(np.abs(err[win]), axis=0),
        float(np.mean(np.abs(e.soc - series.soc_ref)[win])),
        float(np.max(np.abs(e.soc - series.soc_ref)[win])),
        weakest_est,
        weakest_true,
        float(e.soc[-1]) if cut else None,
        float(series.soc_ref[-1]) if cut else None,
        float(np.mean(np.abs(err[win]) <= 2.0 * e.cell_soc_std[win])),
    )


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("bags", nargs="*", type=Path)
    ap.add_argument(
        "--initial-soc",
        default="ocv",
        help="ocv (the node's boot, default) or ref (the cells' true mean, std 0.1)",
    )
    args = ap.parse_args(argv)
    bags = args.bags or sorted((ROOT / "bags").glob("lfp4s_cells_*"))
    print(
        "| Mission | set | cell MAE % (1..N) | cell max % | usable MAE / max % | "
        "weakest est / true | usable at cut-off est / true % | 2 sigma |"
    )
    print("|---|---|---|---|---|---|---|---|")
    for bag in bags:
        s = score_bag(bag, args.initial_soc)
        cut = (
            "-"
            if s.usable_at_cutoff_est is None or s.usable_at_cutoff_true is None
            else f"{100 * s.usable_at_cutoff_est:.2f} / {100 * s.usable_at_cutoff_true:.2f}"
        )
        print(
            f"| {s.name} | {'tuning' if s.name in TUNING else 'validation'} | "
            f"{' '.join(f'{100 * v:.2f}' for v in s.cell_mae)} | "
            f"{' '.join(f'{100 * v:.2f}' for v in s.cell_max)} | "
            f"{100 * s.usable_mae:.2f} / {100 * s.usable_max:.2f} | "
            f"{s.weakest_est} / {s.weakest_true} | {cut} | {100 * s.coverage_2sigma:.0f} % |"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
