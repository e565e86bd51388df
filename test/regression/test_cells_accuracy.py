"""Per-cell SoC on the bundled 4S LFP missions (issue 25; docs/cells.md), replayed as the node
runs them (hybrid, started from the OCV of the first sample): the issue's targets, each
mission on its own. ``lfp4s_cells_1_full`` is the mission the cell filter's settings were
chosen on (tuning); the others validate. A target a mission misses is a strict xfail whose
reason holds the measured numbers (benchmarks/studies/cells_accuracy.py prints them); the
bounds are the issue's and are never loosened here.
"""

from __future__ import annotations

from functools import cache
from types import ModuleType

import pytest
from conftest import bag_path, load_benchmark

#: Per-cell and usable SoC MAE after the 10-minute window (issue 25's targets).
MAE_MAX = 0.015
#: The usable SoC reaches 0 within 1 point of the first cell's cut-off (issue 25): the true
#: usable SoC where the estimate first reads 0, against the true one at the cut-off.
CUTOFF_MAX = 0.01

MISSIONS = ("lfp4s_cells_1_full", "lfp4s_cells_2_partial", "lfp4s_cells_3_cold")

#: Targets measured missed, (mission, target) -> the measured numbers (strict xfails: a target
#: met again fails until its entry goes). The misses are the pack's own: a cell's SoC is the
#: pack's plus its deviation (docs/cells.md). The part-charged mission starts from the OCV
#: under load 7 points below the pack's SoC on LFP's plateau, with std 22 %, and the pack's
#: hybrid reads no load there while it is that wide (item 9); the cold one starts 4.9 points
#: above it on the flat top, where nothing corrects it before the step near 0.75.
MISSED: dict[tuple[str, str], str] = {
    ("lfp4s_cells_2_partial", "per-cell MAE"): "measured cell MAE % 1.59 2.04 1.00 1.57: "
    "cells 1, 2 and 4 above 1.5 (the pack's hybrid from a wide OCV start 7 points low)",
    ("lfp4s_cells_2_partial", "usable MAE"): "measured usable MAE 1.77 %: the pack's hybrid "
    "from a wide OCV start 7 points low on the plateau (1.56 % of it), and 0 from the first "
    "cut-off, where the C/20 reference still counts 8.5 % (0.19 %)",
    ("lfp4s_cells_3_cold", "per-cell MAE"): "measured cell MAE % 1.39 0.86 1.82 0.90: cell 3 "
    "above 1.5 (the pack's hybrid off the cells' mean, cold OCV start)",
}


@cache
def study() -> ModuleType:
    return load_benchmark("studies/cells_accuracy")


@cache
def score(name: str):
    return study().score_bag(bag_path(name))


def check(name: str, target: str, ok: bool, measured: str) -> None:
    if (name, target) in MISSED:
        if ok:
            pytest.fail(f"{name}: {target} now met ({measured}): remove its xfail")
        pytest.xfail(f"{MISSED[(name, target)]} (now: {measured})")
    assert ok, f"{name}: {target} missed: {measured}"


@pytest.mark.slow
@pytest.mark.parametrize("name", MISSIONS)
def test_per_cell_mae(name: str) -> None:
    s = score(name)
    measured = "cell MAE % " + " ".join(f"{100 * v:.2f}" for v in s.cell_mae)
    check(name, "per-cell MAE", bool(max(s.cell_mae) <= MAE_MAX), measured)


@pytest.mark.slow
@pytest.mark.parametrize("name", MISSIONS)
def test_usable_mae(name: str) -> None:
    s = score(name)
    check(name, "usable MAE", s.usable_mae <= MAE_MAX, f"usable MAE {100 * s.usable_mae:.2f} %")


@pytest.mark.slow
@pytest.mark.parametrize("name", MISSIONS)
def test_weakest_cell_identified_at_the_end(name: str) -> None:
    s = score(name)
    check(
        name,
        "weakest cell",
        s.weakest_est == s.weakest_true,
        f"estimated {s.weakest_est}, true {s.weakest_true}",
    )


@pytest.mark.slow
def test_usable_soc_reaches_zero_at_the_first_cut_off() -> None:
    # The mission whose weakest cell reaches its cut-off voltage (the simulator's true cell
    # voltage at or below 2.5 V: under the 4-A limp-home load, 8.5 % of its C/20 charge left).
    name = "lfp4s_cells_2_partial"
    s = score(name)
    assert s.usable_at_cutoff_est is not None and s.zero_gap is not None
    # The estimate's first 0 within 1 point of true usable SoC of the cut-off's, either side.
    check(
        name,
        "cut-off",
        abs(s.zero_gap) <= CUTOFF_MAX,
        f"usable SoC {100 * s.usable_at_cutoff_est:.2f} % at the cut-off, its first 0 "
        f"{100 * s.zero_gap:+.2f} points from it",
    )
