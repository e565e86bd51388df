"""The Nav2 contract of ``battery/soc`` over loopback: what Nav2's battery conditions and
docking plugins read from it across a mission that ends on the dock.

A subscriber with Nav2's QoS (``nav2::qos::StandardTopicQoS``: reliable, keep last 10,
volatile) reads every message as Nav2 does:

* ``IsBatteryLow``: ``percentage <= min_battery`` (a NaN is never low, so the node must never
  publish one);
* ``IsBatteryCharging``: ``power_supply_status == CHARGING``;
* the docking plugins (``SimpleChargingDock``): charging while ``current > 0.5 A``.

**The mission is synthetic and only fit for this contract test, not for any accuracy claim.**
It needs a discharge past the critical level, a dock, a charge to FULL with a float and a
drive off in one recording; the corpus missions' PyBaMM dock charges start at 22-40 %
SoC, above the LFP file's 20 % critical level, where IsBatteryLow never fires, so it is built
from the end of a bundled field run
(``lfp_field_run_2_partial``, the last 25 minutes, decimated to the 1 Hz a slow bridge
publishes), followed by segments made with the package's own Thevenin model (the LFP file's):
a short drive to the dock, a rest, a CC-CV charge (6 A to 14.4 V, then the current that holds
14.4 V) to past its taper, a float, and the drive off the dock. A model-made charge agrees with
the estimator's own model by construction, so it says nothing about how well the SoC is
estimated during a charge; it checks statuses, FULL and levels, which depend on the current
and voltage alone (and on the SoC for the levels).
"""

from __future__ import annotations

import math
import uuid
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
from conftest import REPO_ROOT

rclpy = pytest.importorskip("rclpy")

from rclpy.context import Context  # noqa: E402
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy  # noqa: E402
from sensor_msgs.msg import BatteryState  # noqa: E402

from soc_estimator_ros.messages import decode_runtime  # noqa: E402
from soc_estimator_ros.params import load_battery_params  # noqa: E402
from soc_estimator_ros.recordings import read_battery_bag  # noqa: E402
from soc_estimator_ros.replay.live import NodeLink, start_node, state_message  # noqa: E402
from soc_estimator_ros.runtime import BatteryLevel  # noqa: E402

LFP_FILE = REPO_ROOT / "config" / "lfp_12v6ah.yaml"
NAV2_QOS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=10,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.VOLATILE,
)
DOCK_CHARGING_THRESHOLD_A = 0.5  # SimpleChargingDock's charging_threshold default
S = 1_000_000_000
CHARGE_A = 6.0  # the LFP file's current_max_charge_a
V_CV = 14.4  # the LFP file's charge voltage (14.6 V - 0.05 V x 4 cells)
ELECTRONICS_A = 0.35


@dataclass
class Phase:
    """A stretch of the mission: its name and the index range of its samples."""

    name: str
    start: int
    stop: int


@pytest.fixture(scope="module")
def ctx() -> Iterable[Context]:
    context = Context()
    rclpy.init(context=context)
    yield context
    rclpy.try_shutdown(context=context)


def build_mission() -> tuple[list[tuple[int, float, float]], list[Phase], float]:
    """(stamp ns, current A core sign, voltage V) samples, the phases, the start's SoC."""
    path = REPO_ROOT / "bags" / "lfp_field_run_2_partial"
    if not (path / "metadata.yaml").is_file():
        pytest.skip(f"bundled bag {path.name} not present")
    run = read_battery_bag(path)
    first = int(np.searchsorted(run.t_s, run.t_s[-1] - 1500.0))
    idx = np.arange(first, len(run), 10)  # the last 25 minutes at 1 Hz
    samples = [
        (int(run.stamp_ns[k]), float(run.current_a[k]), float(run.voltage_v[k])) for k in idx
    ]
    phases = [Phase("field", 0, len(samples))]
    assert run.soc_ref is not None
    soc0 = float(run.soc_ref[idx[0]])

    battery = load_battery_params(LFP_FILE)
    model = battery.thevenin_model()
    x = model.rested_state(float(run.soc_ref[-1]))  # the model takes over at the true SoC
    z = model.surface_rest()
    t = samples[-1][0]

    def step(current: float, dt_s: float) -> None:
        """One sample of the model: ``current`` held for ``dt_s``."""
        nonlocal x, z, t
        x, z = model.step(x, current, dt_s, 25.0), model.surface_step(z, current, dt_s, x[0])
        t += round(dt_s * S)
        samples.append((t, current, model.terminal_voltage(x, current, 25.0, sum(z))))

    def phase(name: str, start: int) -> None:
        phases.append(Phase(name, start, len(samples)))

    def cv_current(dt_s: float) -> float:
        """The charge current that ends a ``dt_s`` step at V_CV (bisection)."""
        lo, hi = -CHARGE_A, 0.0
        for _ in range(60):
            mid = 0.5 * (lo + hi)
            xm, zm = model.step(x, mid, dt_s, 25.0), model.surface_step(z, mid, dt_s, x[0])
            if model.terminal_voltage(xm, mid, 25.0, sum(zm)) > V_CV:
                lo = mid
            else:
                hi = mid
        return 0.5 * (lo + hi)

    start = len(samples)
    for _ in range(300):  # 5 min at 5 A to the dock: about 0.20 -> 0.13
        step(5.0, 1.0)
    phase("drive to dock", start)
    start = len(samples)
    for _ in range(60):
        step(ELECTRONICS_A, 1.0)
    phase("docked", start)
    start = len(samples)  # CC at 6 A until the next step would pass 14.4 V (2-s samples)
    while True:
        xn = model.step(x, -CHARGE_A, 2.0, 25.0)
        zn = model.surface_step(z, -CHARGE_A, 2.0, x[0])
        if model.terminal_voltage(xn, -CHARGE_A, 25.0, sum(zn)) >= V_CV:
            break
        step(-CHARGE_A, 2.0)
    phase("cc", start)
    start = len(samples)  # CV: the current tapers, then floats well below the taper
    for _ in range(900):
        current = cv_current(2.0)
        step(current, 2.0)
        if -current < 0.05:
            break
    phase("cv", start)
    start = len(samples)
    for current in [ELECTRONICS_A] * 20 + [6.0] * 60:
        step(current, 1.0)
    phase("off the dock", start)
    return samples, phases, soc0


def test_battery_soc_meets_nav2s_battery_conditions_and_docking(ctx, tmp_path: Path):
    samples, phases, soc0 = build_mission()
    ns = f"/nav2_{uuid.uuid4().hex[:8]}"
    node = start_node(
        ctx,
        ns,
        battery_file=str(LFP_FILE),
        estimator="hybrid",
        initial_soc=repr(soc0),
        input_reliability="reliable",
        qos_depth=1000,
        state_file=str(tmp_path / "state.yaml"),
    )
    link = NodeLink(ctx, node, ns, batch=10)
    nav2 = rclpy.create_node(f"nav2_{uuid.uuid4().hex[:8]}", namespace=ns, context=ctx)
    seen: list[BatteryState] = []
    nav2.create_subscription(BatteryState, "battery/soc", seen.append, NAV2_QOS)
    link.executor.add_node(nav2)
    try:
        assert link.wait_matched()
        assert link.spin_until(lambda: node._soc_pub.get_subscription_count() >= 2)
        link.send([state_message(t, v, i, 25.0, 6.0, serial_number="LFP-1") for t, i, v in samples])
        link.spin_for(0.2)
    finally:
        link.close()
        nav2.destroy_node()
    soc, runtime = link.soc, [decode_runtime(m) for m in link.runtime]
    assert len(soc) == len(samples)  # one estimate per sample, none stale
    assert len(seen) >= 0.9 * len(samples)  # Nav2's depth-10 reader, batches of 10

    th = node.tracker.runtime.thresholds
    min_battery = th.critical_soc  # IsBatteryLow's min_battery set to the critical level
    # -- every message Nav2 reads ------------------------------------------------------------
    for m in seen:
        assert math.isfinite(m.percentage) and 0.0 <= m.percentage <= 1.0
        docking_charging = m.current > DOCK_CHARGING_THRESHOLD_A
        is_battery_charging = m.power_supply_status == BatteryState.POWER_SUPPLY_STATUS_CHARGING
        assert docking_charging == is_battery_charging, (m.current, m.power_supply_status)
        assert m.power_supply_status != BatteryState.POWER_SUPPLY_STATUS_UNKNOWN

    by_phase = {p.name: soc[p.start : p.stop] for p in phases}
    status = {p.name: [m.power_supply_status for m in by_phase[p.name]] for p in phases}
    c = BatteryState
    # -- the mission: discharging, low, then critical before the dock ----------------------
    field = status["field"]
    assert field.count(c.POWER_SUPPLY_STATUS_DISCHARGING) > 0.8 * len(field)
    assert c.POWER_SUPPLY_STATUS_FULL not in field
    low = [m.percentage <= min_battery for m in by_phase["drive to dock"]]
    assert low[-1], "IsBatteryLow never fired before the dock"
    assert status["drive to dock"] == [c.POWER_SUPPLY_STATUS_DISCHARGING] * len(low)
    # -- the charge: CHARGING through CC, FULL at the CV's end, recalibrated to 1 -----------
    assert set(status["cc"]) == {c.POWER_SUPPLY_STATUS_CHARGING}
    cv = status["cv"]
    full_at = cv.index(c.POWER_SUPPLY_STATUS_FULL)
    assert by_phase["cv"][full_at].percentage == 1.0
    assert set(cv[full_at:]) == {c.POWER_SUPPLY_STATUS_FULL}  # FULL while it floats
    tapered = [-m.current for m in by_phase["cv"][:full_at] if -m.current <= 0.3]
    assert tapered, "FULL before the current tapered below 0.05 C"
    assert not any(m.percentage <= min_battery for m in by_phase["cv"][full_at:])
    # -- off the dock: DISCHARGING within the low-pass (a few seconds), FULL released -------
    off = status["off the dock"]
    first_dis = off.index(c.POWER_SUPPLY_STATUS_DISCHARGING)
    assert first_dis <= 5 and set(off[:first_dis]) <= {c.POWER_SUPPLY_STATUS_FULL}
    assert set(off[first_dis:]) == {c.POWER_SUPPLY_STATUS_DISCHARGING}

    # -- levels (battery/runtime, one a sample at 1 Hz) --------------------------------------
    stamp_index = {round(t / 1000): k for k, (t, _, _) in enumerate(samples)}  # us
    levels = np.full(len(samples), -1)
    for r in runtime:
        levels[stamp_index[round(r["stamp_s"] * 1e6)]] = int(r["level"])
    assert np.all(levels >= 0)  # a report per sample (1 Hz input, 1-s schedule)
    before_charge = levels[: phases[3].start]  # field, drive to dock, docked
    assert np.all(np.diff(before_charge) >= 0), "a level cleared during the discharge"
    assert before_charge[-1] >= BatteryLevel.CRITICAL
    assert before_charge[0] <= BatteryLevel.WARN
    # Each trip came at least the debounce after the SoC crossed its threshold.
    percent = np.array([m.percentage for m in soc])
    t_s = np.array([t for t, _, _ in samples]) * 1e-9
    for k in np.flatnonzero(np.diff(before_charge) > 0) + 1:
        level = BatteryLevel(int(levels[k]))
        below = percent[: k + 1] < th.threshold(level)
        crossed = k - int(np.argmin(below[::-1]))  # first sample of the run below it
        assert t_s[k] - t_s[crossed] >= th.debounce_s - 1.0
    assert levels[phases[4].stop - 1] == BatteryLevel.OK  # charged: every level cleared
    # Time to full while charging, 0 once full; time to empty while driving.
    ttf = [r["time_to_full_s"] for r in runtime]
    assert any(math.isfinite(v) and v > 600.0 for v in ttf)
    assert 0.0 in ttf
    tte = np.array([r["time_to_empty_s"] for r in runtime[: phases[1].stop]])
    assert np.all(tte >= 0.0) and np.any(np.isfinite(tte) & (tte > 0.0))
    assert tte[-1] == 0.0  # the drive to the dock ends below soc_min
