"""When the node publishes ``battery/soc`` at a ``publish_rate_hz``: once per period
``1 / publish_rate_hz`` of the samples' time, on an accepted sample, right after its estimate;
with a filter rate below the input rate, not on a filter step's own sample but on the next.

The periods are a grid started at the first sample, and a sample is due from half a period
before its tick: a source's clock jitter, a sample a millisecond early, then never costs an
output (a 10 Hz bridge at ``publish_rate_hz: 10`` has every sample published), and over a
stream the outputs come at the rate, never faster on average. A sample past its tick's window
(after a gap in the input) restarts the grid from itself.

No timer of its own: an output is as fresh as one per sample (its latency is its sample's, not
up to a period more) and the executor's wait set holds one timer less; the samples between two
outputs cost the node no publish, the largest share of its CPU per message beyond its filter
(docs/benchmarks.md, "Where the time goes in the node"). Driven by the samples' time, so a
replay at any speed publishes the same outputs.

**An output is not a filter step's sample** where the stream has samples between steps (a
``filter_rate_hz`` below the input rate): a step that is due hands its output to the next
sample, one input period later (10 ms at 100 Hz), which carries the step's estimate moved by
that sample's counted charge; so the step's time (a UKF step: several times a message's
handling) is in no output's latency, as no runtime prediction is (below). Where every
sample is a step (no filter rate, or input no faster than it), the due sample itself is
published.

**Deferred work goes on a sample without an output** (:attr:`OutputRate.takes_deferred_work`):
the runtime prediction due once a second (``RuntimeMonitor.flush``, about 1 ms) run right after
an output's publish still made that output arrive about 1 ms later (in a benchmark round here
the six latest outputs all carried it, their callbacks 1.2-1.3 ms against 0.26 ms;
docs/benchmarks.md). So it runs on the next sample that publishes nothing,
10 ms later at 100 Hz, or, where every sample is published (input no faster than the rate),
after the output as before. ROS-free: the node passes the tracker's sample time
(``Estimate.t_s``) and ``StepResult.filtered``.
"""

from __future__ import annotations

import math

#: Slack on the start of a tick's window (s): the grid's ticks are sums of periods, and 0.1
#: added twice and less 0.05 is 0.15000000000000002, not the 0.15 a stamp lands on.
WINDOW_SLACK_S = 1e-6


class OutputRate:
    """Which accepted samples are published, at ``rate_hz`` a second of sample time at most."""

    def __init__(self, rate_hz: float) -> None:
        if not (rate_hz > 0.0 and math.isfinite(rate_hz)):
            raise ValueError(f"publish rate {rate_hz!r}: expected a positive number of Hz")
        self.period_s = 1.0 / rate_hz
        self._tick_s: float | None = None  # the next output's tick on the grid
        self._after_between = False  # the last sample was between filter steps
        self._published = (False, False)  # whether the last two samples were, oldest first

    def due(self, t_s: float, filter_step: bool) -> bool:
        """True when the sample at ``t_s`` (s, the tracker's time base, increasing; every
        accepted sample, in order) is to be published: the first sample, then the first one
        from half a period before each tick, but for a filter step (``filter_step``) that
        follows a sample between steps, whose output is the next sample's."""
        publish = self._due(t_s, filter_step)
        self._published = (self._published[1], publish)
        return publish

    @property
    def takes_deferred_work(self) -> bool:
        """Whether work kept off the outputs (a due runtime prediction) runs after the sample
        :meth:`due` was last asked about: one not published, or an output that follows
        another (a stream with no sample between outputs, where waiting would wait for
        ever)."""
        before, last = self._published
        return not last or before

    def _due(self, t_s: float, filter_step: bool) -> bool:
        after_between, self._after_between = self._after_between, not filter_step
        tick = self._tick_s
        if tick is not None and t_s < tick - 0.5 * self.period_s - WINDOW_SLACK_S:
            return False
        if filter_step and after_between:
            return False
        if tick is None or t_s >= tick + 0.5 * self.period_s:  # the first sample, or a gap
            self._tick_s = t_s + self.period_s
        else:
            self._tick_s = tick + self.period_s
        return True
