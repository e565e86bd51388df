"""The tracker without DDS: initialization, resume, re-basing on jumped stamps, switch, reset,
recovery, temperature rule and lost-input counting (tracking/tracker.py)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from conftest import REPO_ROOT

from soc_estimator_ros.estimators import make_estimator
from soc_estimator_ros.params import load_battery_params
from soc_estimator_ros.tracking import (
    GateConfig,
    Level,
    Sample,
    SavedState,
    Tracker,
    TrackerConfig,
    Verdict,
)
from soc_estimator_ros.tracking.persistence import load_state, resume_decision, save_state
from soc_estimator_ros.units import NS_PER_S

SLA = load_battery_params(REPO_ROOT / "config" / "sla_12v5ah.yaml")
T0_NS = 1_778_000_000 * NS_PER_S
DAY_NS = 86_400 * NS_PER_S
PERIOD_NS = NS_PER_S // 10  # a 10 Hz bridge


class FakeClock:
    """A steady clock the test advances by hand."""

    def __init__(self) -> None:
        self.t = 100.0

    def __call__(self) -> float:
        return self.t


def make(config: TrackerConfig | None = None, **kw) -> tuple[Tracker, FakeClock]:
    clock = FakeClock()
    gate = GateConfig.from_limits(SLA.limits, stale_timeout_s=2.0, time_jump_s=10.0)
    tracker = Tracker(
        SLA,
        gate,
        config or TrackerConfig(estimator="coulomb", initial_soc=0.7),
        steady_clock=clock,
        **kw,
    )
    return tracker, clock


def feed(
    tracker: Tracker,
    clock: FakeClock,
    stamps_ns,
    current_a: float = 1.0,
    voltage_v: float = 12.6,
    live: bool = True,
) -> list:
    """Samples at ``stamps_ns``; with ``live`` the receiver's clock advances by the real 0.1 s
    per sample (the bridge's rate), whatever the stamps say."""
    out = []
    for stamp in stamps_ns:
        clock.t += 0.1
        clock_ns = round(clock.t * NS_PER_S) if live else None
        out.append(
            tracker.process(Sample(int(stamp), current_a, voltage_v, 25.0), clock_ns=clock_ns)
        )
    return out


def stream(start_ns: int, n: int) -> list[int]:
    return [start_ns + k * PERIOD_NS for k in range(n)]


def test_a_normal_stream_counts_charge_like_coulomb_counting() -> None:
    tracker, clock = make()
    results = feed(tracker, clock, stream(T0_NS, 101))
    assert all(r.accepted for r in results)
    # 10 s at 1 A from 0.7 on the file's capacity: the same arithmetic as the estimator alone.
    ref = make_estimator("coulomb", SLA, 0.7, 0.1)
    for k in range(101):
        ref.step(k * 0.1, 1.0, 12.6, 25.0)
    assert tracker.soc == pytest.approx(ref.soc, abs=1e-12)


def test_one_stamp_a_day_ahead_is_rejected_and_not_integrated() -> None:
    """Today's defect: one future stamp sent the SoC 0.70 -> 0.00 (a day integrated)."""
    tracker, clock = make()
    feed(tracker, clock, stream(T0_NS, 50))
    soc_before = tracker.soc
    bad = feed(tracker, clock, [T0_NS + 50 * PERIOD_NS + DAY_NS])
    assert bad[0].verdict is Verdict.TIME_JUMP and not bad[0].accepted
    after = feed(tracker, clock, stream(T0_NS + 51 * PERIOD_NS, 2800))
    assert all(r.accepted for r in after)  # the good stream goes on
    # 2851 samples at 1 A: only the charge the current explains (0.1 s each), nothing else.
    expected = soc_before - 1.0 * 2801 * 0.1 / 3600 / SLA.capacity_ah
    assert tracker.soc == pytest.approx(expected, abs=2e-4)  # 2e-4: the skipped sample's 0.1 s
    assert tracker.gate.counts[Verdict.TIME_JUMP] == 1


def test_a_source_on_zero_based_stamps_for_three_seconds_is_followed_both_ways() -> None:
    """Today's defect: a bridge on zero-based stamps for 3 s, then back: SoC 0.73 -> 0.00."""
    tracker, clock = make()
    feed(tracker, clock, stream(T0_NS, 100))
    soc_before = tracker.soc
    zero = feed(tracker, clock, stream(0, 30))  # 3 s before its clock syncs
    back = feed(tracker, clock, stream(T0_NS + 13 * NS_PER_S, 100))
    assert sum(r.accepted for r in zero) >= 5  # re-based after the 2 s stale timeout
    assert sum(r.accepted for r in back) >= 95  # re-based after 3 agreeing samples
    elapsed_s = 0.1 * 130  # the receiver's clock since soc_before: 130 samples at 10 Hz
    # Moved by the charge counted over the real elapsed time: 1 A over 13 s (the jumped
    # samples' time is bridged as steps, so nothing is lost; 1e-9: float arithmetic).
    assert soc_before - tracker.soc == pytest.approx(elapsed_s / 3600 / SLA.capacity_ah, rel=1e-9)
    assert tracker.soc_var <= 1.0


def test_a_lone_jumped_sample_between_good_ones_is_an_outlier() -> None:
    tracker, clock = make()
    feed(tracker, clock, stream(T0_NS, 10))
    stamps = [
        T0_NS + 10 * PERIOD_NS + DAY_NS,
        T0_NS + 10 * PERIOD_NS,
        T0_NS + DAY_NS + 11 * PERIOD_NS,
    ]
    results = feed(tracker, clock, stamps)
    assert [r.verdict for r in results] == [Verdict.TIME_JUMP, Verdict.ACCEPTED, Verdict.TIME_JUMP]


def test_a_real_silence_is_a_gap_not_a_jump() -> None:
    """The bridge silent for 60 s (the receiver's clock saw them pass): integrated as a gap."""
    tracker, clock = make()
    feed(tracker, clock, stream(T0_NS, 10))
    clock.t += 60.0
    results = feed(tracker, clock, stream(T0_NS + 61 * NS_PER_S, 3))
    assert all(r.accepted for r in results)
    assert results[0].estimate is not None and results[0].estimate.status.value == "gap"


def test_offline_stamps_are_the_only_time() -> None:
    """Without a receiver's clock (a recording), a forward gap is a gap (no jump check)."""
    tracker, clock = make()
    results = feed(tracker, clock, [T0_NS, T0_NS + DAY_NS], live=False)
    assert all(r.accepted for r in results)


def test_backward_jump_waits_for_the_stale_timeout() -> None:
    tracker, clock = make()
    feed(tracker, clock, stream(T0_NS, 10))
    early = feed(tracker, clock, stream(T0_NS - 100 * NS_PER_S, 5))  # 0.5 s of stale samples
    assert all(r.verdict is Verdict.STALE for r in early)
    late = feed(tracker, clock, stream(T0_NS - 99 * NS_PER_S, 20))
    assert late[-1].accepted
    assert any(
        e.level is Level.ERROR and "jumped back" in e.message for r in late for e in r.events
    )


def test_ocv_initialization_and_the_event_saying_so() -> None:
    tracker, clock = make(TrackerConfig(estimator="hybrid", initial_soc="ocv"))
    v = 12.7
    r = feed(tracker, clock, [T0_NS], current_a=0.0, voltage_v=v)[0]
    soc, _ = tracker.soc_from_ocv(v)
    assert r.estimate is not None
    assert "from the OCV" in r.events[0].message
    assert r.estimate.soc == pytest.approx(soc, abs=0.02)  # one update step after the reset


def test_a_start_under_load_reads_the_voltage_through_the_model() -> None:
    """The first sample at 10 A: its voltage is the file's model at 70 % with the branches
    half-way to their steady state (a load held for a while). Read through the model the start
    is 70 % (0.005: the reading's SoC grid, 0.0025); read as an OCV it would be 40 points low
    (the drop at 10 A is about 0.6 V on a 1.5 V-per-unit curve)."""
    tracker, clock = make(TrackerConfig(estimator="coulomb", initial_soc="ocv"))
    model = SLA.thevenin_model()
    soc, current_a = 0.7, 10.0
    x = [soc]
    for i, b in enumerate(model.params.branches):
        r_ohm, _ = model.branch_at(i, soc, 25.0)
        x.append(0.5 * r_ohm * b.drive_a(soc, current_a, 25.0))
    v = model.terminal_voltage(np.array(x), current_a, 25.0)
    r = feed(tracker, clock, [T0_NS], current_a=current_a, voltage_v=v)[0]
    assert "from the OCV" in r.events[0].message
    assert tracker.soc == pytest.approx(soc, abs=0.005)
    assert tracker.soc_from_ocv(v)[0] < soc - 0.3  # the same voltage at rest


def test_resume_uses_a_recent_state_and_falls_back_to_the_ocv(tmp_path: Path) -> None:
    path = tmp_path / "state.yaml"
    save_state(path, SavedState(0.42, 1e-4, T0_NS / NS_PER_S - 10, "coulomb", SLA.name))

    def resume(now_s: float):
        return resume_decision(path, now_s, 3600.0, SLA.name)

    tracker, clock = make(TrackerConfig(estimator="coulomb", initial_soc="resume"), resume=resume)
    r = feed(tracker, clock, [T0_NS])[0]
    assert "resuming" in r.events[0].message
    assert tracker.soc == pytest.approx(0.42, abs=1e-3)
    # A binary state file: one line, set aside, OCV start (today: a crash on every restart).
    path.write_bytes(b"\x89PNG\r\n\x1a\n\xff\xfe\x00")
    tracker, clock = make(TrackerConfig(estimator="coulomb", initial_soc="resume"), resume=resume)
    r = feed(tracker, clock, [T0_NS])[0]
    assert r.events[0].level is Level.WARNING and "not a text file" in r.events[0].message
    assert "\n" not in r.events[0].message
    assert not path.exists() and (tmp_path / "state.yaml.unusable").exists()
    assert r.accepted


def test_reset_switch_and_recover() -> None:
    tracker, clock = make(TrackerConfig(estimator="coulomb", initial_soc=0.6))
    tracker.reset_soc(0.5, 0.05)  # before the first sample: replaces initial_soc
    feed(tracker, clock, stream(T0_NS, 20))
    assert tracker.soc == pytest.approx(0.5 - 1.9 / 3600 / SLA.capacity_ah, abs=1e-12)
    rev = tracker.revision
    soc, std, last = tracker.reset_from_ocv()
    assert tracker.soc == pytest.approx(soc) and tracker.revision == rev + 1
    event = tracker.switch_estimator("coulomb")
    assert tracker.estimator.name == "coulomb" and "switched" in event.message
    assert tracker.soc == pytest.approx(soc)

    def boom(*args, **kwargs):
        raise FloatingPointError("synthetic")

    tracker.estimator.step = boom  # type: ignore[method-assign]
    r = feed(tracker, clock, [T0_NS + 30 * PERIOD_NS])[0]
    assert (
        r.verdict is Verdict.ESTIMATOR_ERROR and tracker.gate.counts[Verdict.ESTIMATOR_ERROR] == 1
    )
    assert feed(tracker, clock, [T0_NS + 31 * PERIOD_NS])[0].accepted  # a new estimator runs
    with pytest.raises(ValueError):
        tracker.prepare_estimator("no_such_filter")


def test_implausible_temperatures_are_ignored_and_counted() -> None:
    tracker, clock = make()
    for k, temp in enumerate([25.0, math.nan, math.inf, 1000.0, -300.0, 30.0]):
        clock.t += 0.1
        r = tracker.process(Sample(T0_NS + k * PERIOD_NS, 1.0, 12.6, temp))
        assert r.accepted  # a temperature never rejects a sample
    assert tracker.gate.temperature_ignored == 3  # inf, 1000, -300; NaN means "not measured"
    assert tracker.last_sample is not None and tracker.last_sample.temperature_c == 30.0


def test_missing_samples_are_counted_from_the_stamps() -> None:
    tracker, clock = make()
    stamps = stream(T0_NS, 60)
    kept = [s for k, s in enumerate(stamps) if k < 55 or k % 2 == 0]  # lose 2 of the last 5
    feed(tracker, clock, kept)
    assert tracker.sample_period_s == pytest.approx(0.1)
    assert tracker.missing_samples == 2


def test_what_is_saved_is_always_loadable(tmp_path: Path) -> None:
    """A huge gap grows the variance past 1; the state saved is clipped to what loads."""
    tracker, clock = make()
    feed(tracker, clock, [T0_NS, T0_NS + 30 * DAY_NS], live=False)
    assert tracker.estimator.soc_var > 1.0
    path = tmp_path / "s.yaml"
    save_state(path, SavedState(tracker.soc, tracker.soc_var, 0.0, "coulomb", SLA.name))
    assert load_state(path).soc_var == 1.0


def test_another_serial_number_is_another_pack_only_once_it_persists() -> None:
    """A garbled or flapping serial field (two BMS on one topic, a noisy UART) reset the learned
    health on every glitch; once running, another serial number is another pack only after
    SERIAL_CONFIRM_SAMPLES samples in a row, and each glitch is counted."""
    from soc_estimator_ros.tracking.tracker import SERIAL_CONFIRM_SAMPLES

    tracker, clock = make(TrackerConfig(estimator="coulomb", initial_soc=0.7, health=True))
    assert tracker.health is not None
    events = []

    def sample(k: int, serial: str) -> None:
        clock.t += 0.1
        event = tracker.pack_serial(serial)
        if event is not None:
            events.append(event)
        tracker.process(Sample(T0_NS + k * PERIOD_NS, 1.0, 12.6, 25.0))

    sample(0, "A")
    assert tracker.health.serial_number == "A"
    health = tracker.health.capacity
    for k, serial in enumerate(["B", "A", "B", "", "B", "A"], start=1):
        sample(k, serial)
    assert tracker.health.serial_number == "A" and tracker.health.capacity is health
    assert tracker.serial_unconfirmed == 3 and not events  # the three lone "B"s
    for k in range(7, 7 + SERIAL_CONFIRM_SAMPLES):
        sample(k, "B")
    assert tracker.health.serial_number == "B" and tracker.health.capacity is not health
    assert len(events) == 1 and "'A' -> 'B'" in events[0].message
