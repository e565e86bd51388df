"""Segment a pulse test into excitation windows between long rests (seed 000 Fig. 2).

One definition covers the protocols met so far:

* seed 000's pulse test (the bundled bags): rest, a 30-min discharge pulse, a 1-h rest;
* HPPC (Panasonic NCR18650PF): 10-s pulses at 0.5-6 C with 20-min rests, pulse sets at
  several SoC with C/3 discharges (logged once a minute) between them;
* pulse blocks (Nissan Leaf cell): a 30-s discharge pulse, a 40-s rest, a 10-s regen pulse and
  a 10 % discharge, then a 1-h rest.

A *window* runs from the last sample of a long rest to the last sample of the next long rest;
what lies between (one or more load steps, short rests, regen) is its excitation. A window is
fitted when its excitation is a net discharge, lasts ``min_pulse_s``, is logged without gaps
and is followed by ``min_rest_after_s`` of rest; every other window is reported with why it was
skipped. A net *charge* window marks a recharge: the test proper starts after the last one
(:func:`start_after_last_charge`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import SocEstimatorError
from ..series import BatterySeries


class IdentificationError(SocEstimatorError, ValueError):
    """A test the identification cannot use, with what is wrong and the numbers."""


@dataclass(frozen=True)
class Pulse:
    """Sample indices of one excitation window.

    ``rest_before`` is the last sample of the rest before the excitation (the OCV point);
    ``start``/``end`` are its first and last samples; ``rest_end`` is the last sample of the
    rest that follows. ``current_a`` is the mean current of the loaded samples (discharge
    positive), ``rest_before_s`` how long the pack rested before it.
    """

    rest_before: int
    start: int
    end: int
    rest_end: int
    current_a: float
    rest_before_s: float = 0.0


@dataclass(frozen=True)
class Window:
    """An excitation between two long rests, and what it is (see :func:`find_windows`)."""

    pulse: Pulse
    net_ah: float  # charge removed over the excitation (negative: a recharge)
    loaded_s: float  # time from the first to the last loaded sample
    max_step_s: float  # longest sample step holding a load (a logging gap under load)
    rest_after_s: float


def load_threshold_a(current_a: np.ndarray) -> float:
    """The current above which a sample is under load.

    Above the sensor noise (six standard deviations of the current where it is well below the
    test's pulse level) and at least 50 mA; at most 30 % of the test's 95th-percentile current.
    A Hall sensor with 40 mA noise (the bags) gives 0.25 A; a cell tester's exact zero gives
    50 mA, so 0.5 C pulses of an 18650 (1.45 A) are found among 6 C ones.
    """
    level = float(np.percentile(np.abs(current_a), 95))
    quiet = np.abs(current_a) < 0.3 * level
    noise = float(np.std(current_a[quiet])) if np.any(quiet) else 0.0
    return min(max(0.05, 6.0 * noise), max(0.3 * level, 0.05))


def long_rests(t: np.ndarray, quiet: np.ndarray, min_rest_s: float) -> list[tuple[int, int, float]]:
    """(first, last, duration_s) of the quiet runs lasting ``min_rest_s`` or more."""
    edges = np.flatnonzero(np.diff(np.concatenate([[0], quiet.astype(int), [0]])))
    out = []
    for a, b in zip(edges[::2], edges[1::2], strict=True):
        # A rest lasts from the sample after the load to its last quiet sample.
        begin = t[a - 1] if a > 0 else t[a]
        if t[b - 1] - begin >= min_rest_s:
            out.append((int(a), int(b - 1), float(t[b - 1] - begin)))
    return out


def _longest_loaded_step(t: np.ndarray, i: np.ndarray, threshold_a: float) -> float:
    """The longest step with a load at both ends (a logging gap under load).

    A step from a loaded sample into a rest is not one: a tester logs a step's last point when
    the step ends (the Nissan files: the 10 A discharge's last point, then rest points once a
    minute), so the load ended at its last sample (see ``fit.step_current_a``).
    """
    loaded = np.abs(i) > threshold_a
    both = loaded[:-1] & loaded[1:]
    return float(np.max(np.diff(t) * both, initial=0.0))


def find_windows(
    test: BatterySeries, min_rest_s: float = 300.0, threshold_a: float | None = None
) -> list[Window]:
    """Every excitation between two rests of at least ``min_rest_s``, in time order."""
    t, i = test.t_s, test.current_a
    thr = load_threshold_a(i) if threshold_a is None else threshold_a
    rests = long_rests(t, np.abs(i) <= thr, min_rest_s)
    windows = []
    for (_, last0, dur0), (first1, last1, dur1) in zip(rests[:-1], rests[1:], strict=True):
        start, end = last0 + 1, first1 - 1
        if end < start:
            continue
        loaded = np.flatnonzero(np.abs(i[start : end + 1]) > thr) + start
        dt = np.diff(t[last0 : first1 + 1])
        net_ah = float(np.sum(i[last0:first1] * dt)) / 3600.0
        on = i[loaded] > 0
        pulse = Pulse(
            rest_before=last0,
            start=start,
            end=end,
            rest_end=last1,
            current_a=float(np.mean(i[loaded][on])) if np.any(on) else 0.0,
            rest_before_s=dur0,
        )
        windows.append(
            Window(
                pulse=pulse,
                net_ah=net_ah,
                loaded_s=float(t[loaded[-1]] - t[loaded[0]]) if loaded.size else 0.0,
                max_step_s=_longest_loaded_step(t[last0 : first1 + 1], i[last0 : first1 + 1], thr),
                rest_after_s=dur1,
            )
        )
    return windows


def start_after_last_charge(test: BatterySeries, min_rest_s: float = 300.0) -> int | None:
    """Index of the first rest sample after the last recharge, or None if there is none.

    A recording that begins with a discharge to the cut-off and a CC-CV charge (the Nissan
    files) starts its pulse test at the rest after that charge; the SoC is 1 there.
    """
    thr = load_threshold_a(test.current_a)
    t, i = test.t_s, test.current_a
    rests = long_rests(t, np.abs(i) <= thr, min_rest_s)
    steps = []  # (first sample of the rest after a stretch, net charge removed over it)
    prev_end = 0
    for first, _, _ in rests:
        dt = np.diff(t[prev_end : first + 1])
        steps.append((first, float(np.sum(i[prev_end:first] * dt)) / 3600.0))
        prev_end = first
    # A recharge is a net charge (a regen pulse inside a discharging block is not), and it
    # only starts the test when discharges follow it (an all-charge file has a wrong sign).
    last = None
    for n, (first, net_ah) in enumerate(steps):
        if net_ah < 0.0 and any(later > 0.0 for _, later in steps[n + 1 :]):
            last = first
    return last


def segment_pulses(
    test: BatterySeries,
    min_pulse_s: float = 5.0,
    min_rest_before_s: float = 300.0,
    min_rest_after_s: float = 600.0,
    gap_s: float = 10.0,
    notes: list[str] | None = None,
) -> list[Pulse]:
    """The excitation windows a fit can use; the others are reported in ``notes``.

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
    windows = find_windows(test, min_rest_before_s)
    discharging = [w for w in windows if w.net_ah > 0]
    if not windows or not discharging:
        thr = load_threshold_a(i)
        if np.count_nonzero(i < -thr) > np.count_nonzero(i > thr):
            raise IdentificationError(
                "the pulses are charging (negative in the core's discharge-positive "
                "convention): wrong current sign? (CSV: see --current-sign)"
            )
        if not windows:
            raise IdentificationError(
                f"no pulse has a rest of {min_rest_before_s:.0f} s before and after it"
            )
    pulses: list[Pulse] = []
    skipped: dict[str, int] = {}
    for w in windows:
        why = None
        if w.net_ah <= 0:
            why = "a recharge"
        elif w.loaded_s < min_pulse_s:
            why = f"load shorter than {min_pulse_s:g} s (cut by the voltage limit?)"
        elif w.max_step_s > gap_s:
            why = f"a logging gap over {gap_s:g} s under load"
        elif w.rest_after_s < min_rest_after_s:
            why = f"a rest shorter than {min_rest_after_s:.0f} s after it"
        if why is None:
            pulses.append(w.pulse)
        else:
            skipped[why] = skipped.get(why, 0) + 1
    if notes is not None:
        notes.append(
            f"segmentation: {len(windows)} window(s) between rests of >= "
            f"{min_rest_before_s:.0f} s, {len(pulses)} fitted"
            + "".join(f"; {n} skipped: {why}" for why, n in skipped.items())
        )
    if not pulses:
        raise IdentificationError(
            f"{len(windows)} pulse window(s) found, but none has a discharge of "
            f">= {min_pulse_s:.0f} s logged without gaps and a rest of {min_rest_after_s:.0f} s "
            f"after it"
        )
    return pulses
