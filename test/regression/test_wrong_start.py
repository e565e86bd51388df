"""From a wrong start (issue 24): benchmarks/studies/wrong_start.py on a bundled corpus
mission, ``bags/lfp_validation_1001`` (validation half: nothing was tuned on it).

The issue's target: from +-30 %, within 2 % within 10 minutes wherever the OCV can tell, and
where it cannot, sigma >= |error| / 2. The study reads "can tell" on the truth and the file
(the OCV resolving the true SoC to 1 point under the model's persistent error); the mission
starts unrested at 60 % on LFP's plateau and reaches the step below it after 30 minutes.
"""

from __future__ import annotations

from functools import cache

import numpy as np
import pytest
from conftest import REPO_ROOT, load_benchmark

BAG = REPO_ROOT / "bags" / "lfp_validation_1001"
#: The start's std: the +-30 % error at 2 sigma, so sigma >= |error| / 2 holds at the start.
START_STD = 0.15

pytestmark = pytest.mark.skipif(not BAG.is_dir(), reason=f"no {BAG.name} under bags/")


@cache
def case():
    study = load_benchmark("studies/wrong_start")
    (found,) = [c for c in study.corpus_cases(BAG.parent) if c.name == BAG.name]
    return study, found


def test_the_ocv_can_tell_where_it_resolves_the_true_soc_to_a_point() -> None:
    """tell_index: the first sample whose true SoC the OCV resolves to 1 point under the
    file's bias_std_v, none before it (the definition, checked on the truth directly)."""
    study, c = case()
    k = study.tell_index(c)
    assert k is not None and k > 0
    ocv = c.battery.thevenin_model().ocv
    bias_v = 0.020402541293514393  # the LFP file's filters.hybrid.bias_std_v
    resolves = [bias_v <= 0.01 * abs(ocv.slope(float(s))) for s in c.soc_ref[: k + 1]]
    assert resolves[-1] and not any(resolves[:-1])


@pytest.mark.slow
@pytest.mark.parametrize("offset", [0.3, -0.3])
def test_a_wrong_start_is_within_two_points_ten_minutes_after_the_ocv_can_tell(offset) -> None:
    """Measured 0.9 and 0.7 points (+30 and -30 %) from 10 minutes after the step; the bound
    is the issue's 2 points."""
    study, c = case()
    row = study.score(c, offset, START_STD)
    assert row is not None and np.isfinite(row["after"])
    assert row["after"] < 2.0, row


@cache
def held() -> tuple[float, float]:
    """% of the samples before the judged ones with sigma >= |error| / 2, from +30 and -30 %."""
    study, c = case()
    ref = study.true_start_after(c)
    return tuple(study.score(c, off, START_STD, ref=ref)["held"] for off in (0.3, -0.3))


@pytest.mark.slow
def test_the_grids_sigma_holds_half_the_error_but_at_the_first_readings() -> None:
    """Hybrid item 12 (the grid posterior's floor on the published variance): measured 99.8 %
    (+30 %) and 99.1 % (-30 %) of the samples; without it 37.4 and 71.9 % (sigma fell below
    half the error on the plateau before the step corrected the SoC). What is left is the
    first 0.5-2 s (next test); the 1 % the bound allows is 24 s of the 40 minutes judged."""
    assert min(held()) >= 99.0, held()


@pytest.mark.slow
@pytest.mark.xfail(
    strict=True,
    reason="measured sigma >= |error| / 2 on 99.8 % (+30 %) and 99.1 % (-30 %) of the samples "
    "before: the first readings narrow a start placed 2 sigma from the truth, which then lies "
    "beyond 2 std of the exact posterior too (+30 %: 2.1 std of the grid's, docs/accuracy.md)",
)
def test_until_then_sigma_holds_half_the_error() -> None:
    assert min(held()) == 100.0, held()


def test_the_summary_sorts_the_misses_by_cause() -> None:
    """summary(): a miss within SAME_AS_REF of the true start's run (ref) is the true start's;
    of the others, those more than FAR_OUTSIDE_C outside the file's temperatures are counted
    apart. Rows made up to sit on each side of both thresholds."""
    study, _ = case()
    same, far = study.SAME_AS_REF, study.FAR_OUTSIDE_C

    def row(after: float, ref: float, out: float, held: float = 100.0) -> dict:
        return {
            "split": "validation",
            "after": after,
            "ref": ref,
            "out": out,
            "held": held,
        }

    rows = [
        row(1.0, 0.5, 0.0),  # within 2 points
        row(3.0, 3.0 - same, 0.0),  # as far off as the true start: the true start's
        row(3.0, 3.0 - same - 0.1, far + 0.1),  # beyond it, far outside
        row(3.0, 0.5, far),  # beyond it, not far outside
        row(float("nan"), float("nan"), 0.0, 90.0),  # the OCV never told
    ]
    first, second = study.summary(rows)
    assert "could tell on 4, within 2 points from 10 minutes after on 1" in first
    assert "every sample on 4 of 5, on 95 % of them on 4" in first
    assert "of the 3 beyond 2 points, 1 within" in second
    assert "of the other 2, 1 more than" in second
