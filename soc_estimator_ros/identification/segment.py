"""Segment a pulse-discharge test into pulses and the rests around them (seed 000 Fig. 2)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..bag_io import BatterySeries


class IdentificationError(ValueError):
    """A test the identification cannot use, with what is wrong and the numbers."""


@dataclass(frozen=True)
class Pulse:
    """Sample indices of one discharge pulse and its rests.

    ``rest_before`` is the index of the last rest sample before the pulse (the OCV point);
    ``start``/``end`` are the first and last samples under load; ``rest_end`` is the last
    sample of the rest that follows.
    """

    rest_before: int
    start: int
    end: int
    rest_end: int
    current_a: float  # mean pulse current (discharge positive)


def segment_pulses(
    test: BatterySeries,
    min_pulse_s: float = 60.0,
    min_rest_before_s: float = 300.0,
    min_rest_after_s: float = 600.0,
) -> list[Pulse]:
    """Find the discharge pulses of a pulse test.

    A sample is "under load" when its current exceeds 30 % of the test's 95th-percentile
    current magnitude (and 0.05 A); pulses are runs of such samples lasting ``min_pulse_s``.
    Raises :class:`IdentificationError` for a test without usable pulses or rests.
    """
    t, i = test.t_s, test.current_a
    if t.size < 100 or t[-1] - t[0] < min_pulse_s + min_rest_after_s:
        raise IdentificationError(
            f"the test is too short ({t.size} samples over {t[-1] - t[0]:.0f} s); a pulse test "
            f"needs pulses of >= {min_pulse_s:.0f} s with rests before and after"
        )
    level = float(np.percentile(np.abs(i), 95))
    if level < 0.05:
        raise IdentificationError(f"no pulses: the current never exceeds {level:.3f} A")
    on = i > max(0.3 * level, 0.05)
    charging = i < -max(0.3 * level, 0.05)
    edges = np.flatnonzero(np.diff(on.astype(int)))
    starts = [k + 1 for k in edges if on[k + 1]]
    ends = [k for k in edges if not on[k + 1]]
    if on[0]:
        starts = [0, *starts]
    if on[-1]:
        ends = [*ends, t.size - 1]
    runs = [(s, e) for s, e in zip(starts, ends, strict=False) if t[e] - t[s] >= min_pulse_s]
    if not runs:
        if np.count_nonzero(charging) > np.count_nonzero(on):
            raise IdentificationError(
                "the pulses are charging (negative in the core's discharge-positive "
                "convention): wrong current sign? (CSV: see --current-sign)"
            )
        raise IdentificationError(f"no discharge pulse lasts {min_pulse_s:.0f} s or more")
    pulses = []
    for n, (s, e) in enumerate(runs):
        prev_end = runs[n - 1][1] if n else -1
        nxt_start = runs[n + 1][0] if n + 1 < len(runs) else t.size
        rest_before = s - 1
        if rest_before <= prev_end or t[rest_before] - t[prev_end + 1] < min_rest_before_s:
            continue
        rest_end = nxt_start - 1
        if t[rest_end] - t[e] < min_rest_after_s:
            continue
        pulses.append(Pulse(rest_before, s, e, rest_end, float(np.mean(i[s : e + 1]))))
    if not pulses:
        raise IdentificationError(
            f"{len(runs)} pulse(s) found, but none has a rest of {min_rest_before_s:.0f} s "
            f"before and {min_rest_after_s:.0f} s after it"
        )
    return pulses
