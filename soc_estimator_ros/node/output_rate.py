"""When the node publishes ``battery/soc`` at a ``publish_rate_hz``: on the first accepted
sample at least ``1 / publish_rate_hz`` seconds of sample time after the last output, right
after that sample's estimate; with a filter rate below the input rate, on the sample after a
filter step rather than on the step.

No timer of its own: an output is as fresh as one per sample (its latency is its sample's, not
up to a period more) and the executor's wait set holds one timer less; the samples between two
outputs cost the node no publish, the largest share of its CPU per message beyond its filter
(docs/benchmarks.md, "Where the time goes in the node"). The period rule is the filter rate's
(:func:`~soc_estimator_ros.tracking.decimation.period_elapsed`) on the same samples' time, so a
replay at any speed publishes the same outputs.

**An output is not a filter step's sample** where the stream has samples between steps (a
``filter_rate_hz`` below the input rate): the step's estimate goes out with the next sample,
one input period later (10 ms at 100 Hz) and moved by that sample's counted charge, so the
step's time (a UKF step: several times a message's handling) is in no output's latency, as
the runtime predictions are computed after the output they belong to. Where every sample is a
step (no filter rate, or input no faster than it), the due sample itself is published.
ROS-free: the node passes the tracker's sample time (``Estimate.t_s``) and
``StepResult.filtered``.
"""

from __future__ import annotations

import math

from ..tracking.decimation import period_elapsed


class OutputRate:
    """Which accepted samples are published, at most ``rate_hz`` a second of sample time."""

    def __init__(self, rate_hz: float) -> None:
        if not (rate_hz > 0.0 and math.isfinite(rate_hz)):
            raise ValueError(f"publish rate {rate_hz!r}: expected a positive number of Hz")
        self.period_s = 1.0 / rate_hz
        self._last_s: float | None = None
        self._after_between = False  # the last sample was between filter steps

    def due(self, t_s: float, filter_step: bool) -> bool:
        """True when the sample at ``t_s`` (s, the tracker's time base, increasing; every
        accepted sample, in order) is to be published: the first sample, then the first one a
        period or more after the last output, but for a filter step (``filter_step``) that
        follows a sample between steps, whose output is the next sample's."""
        after_between, self._after_between = self._after_between, not filter_step
        if self._last_s is not None and not period_elapsed(t_s, self._last_s, self.period_s):
            return False
        if filter_step and after_between:
            return False
        self._last_s = t_s
        return True
