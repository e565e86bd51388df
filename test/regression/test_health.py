"""Battery health on the bundled aged pack's life (issue 26; docs/architecture.md#health): the
three missions of ``lfp_aged75`` (validation: nothing was tuned on them) replayed in order with
one state file, as ``soc_replay --state FILE`` does (benchmarks/studies/health.py prints the
same numbers for every pack of ``tools/make_bags.py --aged``). The issue's bounds stand; a
target missed today is a strict xfail with the measured numbers, so it flags the day it passes.
"""

from __future__ import annotations

from functools import cache
from types import ModuleType

import pytest
import yaml
from conftest import bag_path, load_benchmark

MISSIONS = ("lfp_aged75_m1", "lfp_aged75_m2", "lfp_aged75_m3")
#: Issue 26: the learned capacity within 3 % of the measured one after three missions.
CAPACITY_TOL = 0.03
#: Issue 26: SoC MAE on the third mission of every aged pack.
MAE_MAX = 0.015

#: Targets measured missed -> why (strict xfails; the bounds are the issue's). None today:
#: with the LFP file's law of the OCV's ageing (``health.ocv_ageing_exponent``, chosen on the
#: ``*_tuning`` packs) the capacity is 4.306 Ah (-1.5 %) and the third mission's MAE 0.33 %
#: (max 0.95 %); without it the end rests read 3.7-3.9 points low (4.150 Ah, -5.0 %; MAE
#: 1.80 %).
MISSED: dict[str, str] = {}


@cache
def study() -> ModuleType:
    return load_benchmark("studies/health")


@cache
def life():
    return study().life([bag_path(name) for name in MISSIONS], "hybrid")


def measured_capacity_ah() -> float:
    meta = yaml.safe_load((bag_path(MISSIONS[0]) / "bag.yaml").read_text())
    return float(meta["health"]["capacity_ah"])


def check(target: str, ok: bool, measured: str) -> None:
    if target in MISSED:
        if ok:
            pytest.fail(f"{target} now met ({measured}): remove its xfail")
        pytest.xfail(f"{MISSED[target]} (now: {measured})")
    assert ok, f"{target} missed: {measured}"


@pytest.mark.slow
def test_capacity_after_three_missions() -> None:
    learned, _ = life()
    q = learned[-1].capacity_ah
    err = q / measured_capacity_ah() - 1.0
    check("capacity", abs(err) <= CAPACITY_TOL, f"{q:.3f} Ah, {100 * err:+.1f} %")


@pytest.mark.slow
def test_third_mission_mae() -> None:
    _, last = life()
    acc = last["hybrid + health"]
    check("mae", acc.mae <= MAE_MAX, f"MAE {100 * acc.mae:.2f} %, max {100 * acc.max_abs:.2f} %")


@pytest.mark.slow
def test_health_does_better_than_without_and_no_harm() -> None:
    # Learning the health beats the file's fresh capacity and R_0 (MAE 0.33 against 7.22 %
    # measured), and does no harm against coulomb counting from the same start (the
    # do-no-harm rule: max error within coulomb's max + 1 point; measured 0.95 against
    # 18.98 %).
    _, last = life()
    health, plain, coulomb = last["hybrid + health"], last["hybrid"], last["coulomb"]
    assert health.mae < plain.mae
    assert health.max_abs <= coulomb.max_abs + 0.01


@pytest.mark.slow
def test_resistance_factor_learns_the_ageing() -> None:
    # The pack's 5-s resistance is 1.7 times the fresh one's (bag.yaml): the factor on the
    # file's R_0 must grow, and by more than that (R_0 is a small part of the LFP drop, the
    # film's growth all lands on it: docs/architecture.md#health).
    learned, _ = life()
    assert learned[-1].r0_factor > 1.7
