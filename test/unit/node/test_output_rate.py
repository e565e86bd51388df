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


def jittered_stamps(n: int, period_ns: int) -> list[int]:
    """``n`` stamps ``period_ns`` apart, each 0-3 ms late (drawn, fixed): a bridge's clock."""
    return [k * period_ns + (k * 7919) % 3_000_000 for k in range(n)]


def test_100hz_input_at_10hz_publishes_one_sample_in_ten():
    # 10 s of 100 Hz stamps in ns, a step on every sample: the first sample, then the first
    # from half a period before each tick of the grid (0.05 s, then 0.15 s, ...).
    t_s = seconds([1_700_000_000_000_000_000 + k * 10_000_000 for k in range(1000)])
    assert published(OutputRate(10.0), t_s) == [0, *range(5, 1000, 10)]


def test_a_jittered_bridge_at_the_rate_has_every_sample_published():
    # A 10 Hz bridge whose samples come up to 3 ms late (so some intervals are under 0.1 s)
    # at publish_rate_hz 10: none is lost to its jitter.
    t_s = seconds(jittered_stamps(600, 100_000_000))
    assert published(OutputRate(10.0), t_s) == list(range(600))


def test_the_rate_holds_over_a_stream_of_any_input_rate():
    # 15 Hz input at 10 Hz: one output in each tick's window, so 10 a second (and the first
    # sample's), never faster on average.
    t_s = seconds([k * 66_666_667 for k in range(1500)])  # 100 s
    assert len(published(OutputRate(10.0), t_s)) == 1 + round(t_s[-1] * 10.0)


def test_at_the_filter_rate_no_output_is_a_step_and_every_step_goes_out():
    # Jittered 100 Hz stamps, filter and outputs at 10 Hz: no output but the first is a filter
    # step's own sample (so none waits on a step's time), and every step's estimate reaches
    # an output before the next step, or with it on the sample after the next step.
    t_s = seconds(jittered_stamps(3000, 10_000_000))
    decimator = Decimator(0.1)
    steps = [k for k, t in enumerate(t_s) if decimator.add(t, 1.0, 12.0, ()) is not None]
    out = published(OutputRate(10.0), t_s, set(steps))
    assert out[0] == 0 and not set(out[1:]) & set(steps)
    assert all(any(a < k <= b + 1 for k in out) for a, b in zip(steps, steps[1:], strict=False))
    assert len(out) == 1 + round(t_s[-1] * 10.0)  # one a tick: 10 a second


def test_input_slower_than_the_rate_publishes_every_sample():
    t_s = seconds([k * 500_000_000 for k in range(20)])  # 2 Hz input, a step on each
    assert published(OutputRate(10.0), t_s) == list(range(20))


def test_after_a_gap_the_grid_restarts_from_the_next_sample():
    rate = OutputRate(10.0)
    assert [rate.due(t, True) for t in (0.0, 0.04, 0.05, 0.1, 0.15)] == [
        True, False, True, False, True,
    ]  # fmt: skip
    assert rate.due(5.03, True)  # after 4.9 s of silence: the next tick is 5.13
    assert [rate.due(t, True) for t in (5.07, 5.08, 5.12)] == [False, True, False]


def deferred_work(rate: OutputRate, t_s: list[float]) -> tuple[list[int], list[int]]:
    """The samples published and those deferred work runs after (a step on every sample)."""
    out, work = [], []
    for k, t in enumerate(t_s):
        if rate.due(t, True):
            out.append(k)
        if rate.takes_deferred_work:
            work.append(k)
    return out, work


def test_deferred_work_runs_on_samples_without_an_output():
    # 100 Hz at 10 Hz: on every sample but the outputs, so a prediction due on an output's
    # sample is computed 10 ms later, on the next one, and never delays an output.
    t_s = seconds([k * 10_000_000 for k in range(1000)])
    out, work = deferred_work(OutputRate(10.0), t_s)
    assert work == [k for k in range(1000) if k not in set(out)]


def test_deferred_work_with_every_sample_published_follows_the_outputs():
    # 2 Hz input at 10 Hz: no sample without an output, so the work follows each output but
    # the first (a prediction due on the first sample is computed on the second).
    t_s = seconds([k * 500_000_000 for k in range(20)])
    out, work = deferred_work(OutputRate(10.0), t_s)
    assert out == list(range(20)) and work == list(range(1, 20))


@pytest.mark.parametrize("rate_hz", [0.0, -1.0, float("nan"), float("inf")])
def test_a_rate_that_is_not_positive_is_refused(rate_hz):
    with pytest.raises(ValueError, match="publish rate"):
        OutputRate(rate_hz)
