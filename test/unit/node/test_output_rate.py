"""The node's publish rate (``node/output_rate.py``): which samples of a stream are published."""

import pytest

from soc_estimator_ros.node.output_rate import OutputRate
from soc_estimator_ros.tracking.decimation import Decimator


def seconds(stamps_ns: list[int]) -> list[float]:
    """The samples' time as the tracker computes it from their stamps."""
    return [(ns - stamps_ns[0]) * 1e-9 for ns in stamps_ns]


def published(rate: OutputRate, t_s: list[float], steps: set[int] | None = None) -> list[int]:
    """Indices of the samples published; ``steps``: the filter steps' (None: every sample)."""
    return [k for k, t in enumerate(t_s) if rate.due(t, steps is None or k in steps)]


def test_100hz_input_at_10hz_publishes_every_tenth_sample():
    # 10 s of 100 Hz stamps in ns, a step on every sample: the float seconds land a few ulp
    # either side of a period after the last output, and the slack keeps the tenth sample on
    # it (never the eleventh).
    t_s = seconds([1_700_000_000_000_000_000 + k * 10_000_000 for k in range(1000)])
    assert published(OutputRate(10.0), t_s) == list(range(0, 1000, 10))


def test_at_the_filter_rate_each_step_goes_out_with_the_next_sample():
    # Jittered stamps (0-3 ms late, drawn), filter and outputs at 10 Hz: the first sample is a
    # step and goes out (no sample between steps before it); then every output is the sample
    # after a step, so no output waits on a step's time and no step's estimate is skipped.
    late_ns = [(k * 7919) % 3_000_000 for k in range(1000)]
    t_s = seconds([k * 10_000_000 + late_ns[k] for k in range(1000)])
    decimator = Decimator(0.1)
    steps = [k for k, t in enumerate(t_s) if decimator.add(t, 1.0, 12.0, ()) is not None]
    out = published(OutputRate(10.0), t_s, set(steps))
    assert out[0] == 0
    assert [k - 1 for k in out[1:]] == steps[1:]  # each later step, one sample on: none missed
    assert all(t_s[b] - t_s[a] >= 0.1 - 1e-6 for a, b in zip(out, out[1:], strict=False))


def test_input_no_faster_than_the_rate_publishes_every_sample():
    t_s = seconds([k * 500_000_000 for k in range(20)])  # 2 Hz input, a step on each
    assert published(OutputRate(10.0), t_s) == list(range(20))


def test_after_a_gap_the_next_sample_is_published():
    rate = OutputRate(10.0)
    assert [rate.due(t, True) for t in (0.0, 0.05, 0.1)] == [True, False, True]
    assert rate.due(5.03, True)  # after 4.9 s of silence
    assert [rate.due(t, True) for t in (5.08, 5.12, 5.13)] == [False, False, True]


@pytest.mark.parametrize("rate_hz", [0.0, -1.0, float("nan"), float("inf")])
def test_a_rate_that_is_not_positive_is_refused(rate_hz):
    with pytest.raises(ValueError, match="publish rate"):
        OutputRate(rate_hz)
