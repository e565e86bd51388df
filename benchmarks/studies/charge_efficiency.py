"""The coulomb efficiency on charge that recordings with a reference SoC show (issue 24, item 4).

A battery file's ``coulomb_efficiency_charge`` is not identified by ``soc_identify`` (its
pulse, rate and slow-discharge tests hold no charge to speak of); this measures it where a
reference SoC is known: the corpus' missions (their dock CC-CV charges and opportunity
charges, ``tools/make_bags.py --corpus``). Per recording with at least ``--min-charge-ah``
charged, :func:`soc_estimator_ros.evaluation.charge_efficiency` (the counting equation's least
squares with a scale per direction, so the current sensor's gain and the pack's capacity cancel
in the ratio), then the median over the recordings and the efficiency the battery file holds.
Read only the tuning half to set a file's value; the validation half checks it. The corpus'
directory names carry the split and the chemistry, so a glob selects them (as for soc_tune):

    python benchmarks/studies/charge_efficiency.py /work/corpus/sla_tuning_*
    python benchmarks/studies/charge_efficiency.py bags/sla_validation_1003 ...
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from soc_estimator_ros.evaluation import ChargeEfficiency, charge_efficiency
from soc_estimator_ros.params import load_battery_params
from soc_estimator_ros.recordings import read_recording
from soc_estimator_ros.replay.run import battery_file_for

#: A recording charged less than this (Ah) tells the efficiency no better than its noise: a
#: reference SoC to 1e-4 and a 20 mA sensor offset over an hour are 0.02 Ah on a 5 Ah pack.
MIN_CHARGE_AH = 0.2


@dataclass(frozen=True)
class Measured:
    name: str
    fit: ChargeEfficiency
    file_efficiency: float  # what the recording's battery file holds


def measure(path: Path) -> Measured | None:
    """The recording's efficiency on charge, or None without a reference SoC."""
    series = read_recording(path)
    if series.soc_ref is None:
        return None
    capacity_ah = series.reference_capacity_ah
    battery = load_battery_params(battery_file_for(series))
    if capacity_ah is None:
        capacity_ah = battery.capacity_ah
    try:
        fit = charge_efficiency(series.t_s, series.current_a, series.soc_ref, capacity_ah)
    except ValueError:
        return None
    return Measured(path.name, fit, battery.coulomb_efficiency_charge)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("recordings", nargs="+", type=Path)
    ap.add_argument("--min-charge-ah", type=float, default=MIN_CHARGE_AH)
    args = ap.parse_args(argv)
    rows = [m for m in map(measure, args.recordings) if m is not None]
    rows = [m for m in rows if m.fit.charge_ah >= args.min_charge_ah]
    print("| recording | discharged Ah | charged Ah | eta | file's eta |")
    print("|---|---|---|---|---|")
    for m in rows:
        f = m.fit
        print(
            f"| {m.name} | {f.discharge_ah:.2f} | {f.charge_ah:.2f} | {f.efficiency:.4f} "
            f"| {m.file_efficiency:.3f} |"
        )
    if not rows:
        print(f"no recording with a reference SoC and >= {args.min_charge_ah} Ah charged")
        return 1
    eta = np.array([m.fit.efficiency for m in rows])
    print(
        f"median eta over {len(rows)} recordings: {np.median(eta):.4f} "
        f"(range {eta.min():.4f}-{eta.max():.4f})"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
