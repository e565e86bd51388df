"""Replay a recording through a live ``soc_estimator_node`` and record what it publishes.

``soc_replay --live`` runs this: the node (:class:`SocEstimatorNode` of ``node/ros_node.py``,
the class ``ros2 run`` starts) and a link node that publishes the recording's ``BatteryState``
samples and ``/clock`` (the node runs on sim time) and subscribes to the node's outputs, both
in one rclpy context spun from this thread. The result is an ``EstimateSeries`` like the
offline replay's (one row per input sample; a rejected sample repeats the last estimate), so
the two can be compared sample for sample.

Pace: lossless lock-step by default (publish a batch, wait until the node has answered every
sample of it, then the next: as fast as the node keeps up, nothing queued out); with
``rate`` the batches are also held back to ``rate`` times the recorded pace.

DDS stays on this machine: before rclpy starts, ``ROS_AUTOMATIC_DISCOVERY_RANGE`` defaults to
``LOCALHOST``, and ``ROS_DOMAIN_ID`` (when unset) to one derived from the process id, so a
replay never talks to a robot's graph. Each run uses its own namespace.

This module imports rclpy; the offline replay never imports it.
"""

from __future__ import annotations

import os
import tempfile
import time
import uuid
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, cast

import numpy as np

#: Domain ids 1..101 are safe for Fast DDS's port arithmetic on every Linux host.
_DOMAIN_MIN, _DOMAIN_SPAN = 1, 101


def isolate_dds() -> None:
    """Keep DDS on loopback with a domain of this process's own, unless already set."""
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    os.environ.setdefault("ROS_DOMAIN_ID", str(_DOMAIN_MIN + os.getpid() % _DOMAIN_SPAN))


isolate_dds()

import rclpy  # noqa: E402
from rclpy.context import Context  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.node import Node  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy  # noqa: E402
from rosgraph_msgs.msg import Clock  # noqa: E402
from sensor_msgs.msg import BatteryState  # noqa: E402
from std_msgs.msg import Float64MultiArray  # noqa: E402

from ..messages import STATUS_FULL, bridge_state, decode_estimate, decode_runtime  # noqa: E402
from ..node.ros_messages import battery_state_msg  # noqa: E402
from ..node.ros_node import SocEstimatorNode  # noqa: E402
from ..series import (  # noqa: E402
    HEALTH_COLUMNS,
    RUNTIME_COLUMNS,
    BatterySeries,
    EstimateSeries,
    RuntimeSeries,
)
from ..tracking import TrackerConfig  # noqa: E402
from ..units import NS_PER_S, ns_to_stamp  # noqa: E402

RELIABLE = QoSProfile(
    history=HistoryPolicy.KEEP_LAST, depth=1000, reliability=ReliabilityPolicy.RELIABLE
)


def state_message(
    stamp_ns: int,
    voltage_v: float,
    current_a: float,
    temperature_c: float = float("nan"),
    design_capacity_ah: float = float("nan"),
    present: bool = True,
    serial_number: str = "",
) -> BatteryState:
    """A bridge's rclpy ``BatteryState`` (``messages.bridge_state``; current in the core's sign)."""
    fields = bridge_state(
        stamp_ns,
        voltage_v,
        current_a,
        temperature_c=temperature_c,
        design_capacity_ah=design_capacity_ah,
        present=present,
        serial_number=serial_number,
    )
    return battery_state_msg(fields)


def series_messages(
    series: BatterySeries, n: int | None = None, serial_number: str = ""
) -> list[BatteryState]:
    """The first ``n`` samples of a recording as bridge messages (with the cells' voltages
    when the recording has them)."""
    count = len(series) if n is None else n
    msgs = [
        state_message(
            int(series.stamp_ns[k]),
            float(series.voltage_v[k]),
            float(series.current_a[k]),
            float(series.temperature_c[k]),
            series.design_capacity_ah,
            serial_number=serial_number,
        )
        for k in range(count)
    ]
    if series.cell_voltage_v is not None:
        for msg, row in zip(msgs, series.cell_voltage_v, strict=False):
            msg.cell_voltage = [float(v) for v in row]
    return msgs


@dataclass
class NodeLink:
    """A helper node beside a ``soc_estimator_node``: publishes its input (and ``/clock``),
    records its outputs, and spins both from the calling thread.

    ``soc`` and ``est`` collect ``battery/soc`` and ``battery/soc_estimate`` in arrival order,
    ``runtime`` the ``battery/runtime`` predictions; ``soc_stale`` collects the node's
    keep-alive ``battery/soc`` messages while its input is stale (status UNKNOWN: no new
    estimate, kept apart so ``soc`` holds one message per estimate); ``diag`` collects
    ``(monotonic time, DiagnosticArray)``.
    """

    context: Context
    node: SocEstimatorNode
    namespace: str
    batch: int = 100
    soc: list[BatteryState] = field(default_factory=list)
    est: list[Float64MultiArray] = field(default_factory=list)
    runtime: list[Float64MultiArray] = field(default_factory=list)
    soc_stale: list[BatteryState] = field(default_factory=list)
    diag: list[tuple[float, Any]] = field(default_factory=list)

    def __post_init__(self) -> None:
        from diagnostic_msgs.msg import DiagnosticArray

        self.io: Node = rclpy.create_node(
            f"link_{uuid.uuid4().hex[:8]}", namespace=self.namespace, context=self.context
        )
        self.pub = self.io.create_publisher(BatteryState, "battery/state", RELIABLE)
        self.clock_pub = self.io.create_publisher(Clock, "/clock", 10)
        self.io.create_subscription(BatteryState, "battery/soc", self._on_soc, RELIABLE)
        self.io.create_subscription(
            Float64MultiArray, "battery/soc_estimate", self.est.append, RELIABLE
        )
        self.io.create_subscription(
            Float64MultiArray, "battery/runtime", self.runtime.append, RELIABLE
        )
        self.io.create_subscription(
            DiagnosticArray, "/diagnostics", lambda m: self.diag.append((time.monotonic(), m)), 10
        )
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.executor.add_node(self.io)
        self.closed = False

    def _on_soc(self, msg: BatteryState) -> None:
        if msg.power_supply_status == BatteryState.POWER_SUPPLY_STATUS_UNKNOWN:
            self.soc_stale.append(msg)
        else:
            self.soc.append(msg)

    def wait_matched(self, needs_input: bool = True, timeout_s: float = 10.0) -> bool:
        """Until the node's outputs (and, with ``needs_input``, its input) are matched."""
        return self.spin_until(
            lambda: (
                (not needs_input or self.pub.get_subscription_count() >= 1)
                and self.node._soc_pub.get_subscription_count() >= 1
                and self.node._est_pub.get_subscription_count() >= 1
            ),
            timeout_s,
        )

    def spin_until(self, done: Callable[[], bool], timeout_s: float = 10.0) -> bool:
        end = time.monotonic() + timeout_s
        while not done():
            if time.monotonic() > end:
                return False
            self.executor.spin_once(timeout_sec=0.01)
        return True

    def spin_for(self, seconds: float) -> None:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            self.executor.spin_once(timeout_sec=0.01)

    def judged(self) -> int:
        """Samples the node's input gate has accepted or rejected so far."""
        return sum(self.node.tracker.gate.counts.values())

    def publish_clock(self, stamp_ns: int) -> None:
        msg = Clock()
        msg.clock.sec, msg.clock.nanosec = ns_to_stamp(stamp_ns)
        self.clock_pub.publish(msg)

    def send(
        self,
        msgs: Sequence[BatteryState],
        expect_outputs: bool = True,
        rate: float | None = None,
        clock: bool = False,
        progress: Callable[[int, int], None] | None = None,
    ) -> None:
        """Publish in batches; after each, wait until the node answered (or judged) it all.

        ``rate``: hold the batches back to that multiple of the recorded pace. ``clock``:
        publish each batch's first stamp on ``/clock`` first (the node on sim time: no sample
        of the batch is older than the node's clock, so none is stale).
        """
        t_wall0 = time.monotonic()
        t_rec0 = None
        for start in range(0, len(msgs), self.batch):
            batch = msgs[start : start + self.batch]
            first = batch[0].header.stamp
            first_ns = first.sec * NS_PER_S + first.nanosec
            if rate is not None:
                t_rec0 = first_ns if t_rec0 is None else t_rec0
                lag = (first_ns - t_rec0) / NS_PER_S / rate - (time.monotonic() - t_wall0)
                if lag > 0:
                    self.spin_for(lag)
            if clock:
                self.publish_clock(first_ns)
            want_out = len(self.soc) + len(batch)
            want_judged = self.judged() + len(batch)
            for m in batch:
                self.pub.publish(m)
            if expect_outputs:
                ok = self.spin_until(
                    cast(
                        "Callable[[], bool]",
                        lambda w=want_out: len(self.soc) >= w and len(self.est) >= w,
                    ),
                    30.0,
                )
            else:
                ok = self.spin_until(
                    cast("Callable[[], bool]", lambda w=want_judged: self.judged() >= w), 30.0
                )
            if not ok:
                raise RuntimeError(f"the node answered {len(self.soc)} of {want_out} samples")
            if progress is not None:
                progress(start + len(batch), len(msgs))

    def close(self) -> None:
        if not self.closed:
            self.closed = True
            self.executor.shutdown(timeout_sec=1.0)
            self.node.destroy_node()
            self.io.destroy_node()


def start_node(context: Context, namespace: str, **params: Any) -> SocEstimatorNode:
    """A ``soc_estimator_node`` in ``namespace`` with parameter overrides."""
    overrides = [Parameter(k, value=v) for k, v in params.items()]
    return SocEstimatorNode(namespace=namespace, context=context, parameter_overrides=overrides)


def replay_live(
    series: BatterySeries,
    battery_file: Path,
    config: TrackerConfig,
    rate: float | None = None,
    progress: Callable[[int, int], None] | None = None,
    node_params: Mapping[str, Any] | None = None,
) -> tuple[EstimateSeries, str, RuntimeSeries]:
    """Every sample of ``series`` through a live node; its estimates, the start it used, and
    its runtime predictions (``battery/runtime``) and FULL status (``battery/soc``).

    The node starts as ``config`` says (``initial_soc``, its std, the estimator), with
    ``node_params`` besides (``cells_in_series``, ``capacity_ah``). Raises
    ``RuntimeError`` when the node does not judge every sample within 30 s of its batch.
    """
    context = Context()
    rclpy.init(context=context)
    try:
        with tempfile.TemporaryDirectory(prefix="soc_live_") as tmp:
            ns = f"/soc_replay_{uuid.uuid4().hex[:8]}"
            init = config.initial_soc
            node = start_node(
                context,
                ns,
                battery_file=str(battery_file),
                estimator=config.estimator,
                initial_soc=init if isinstance(init, str) else repr(float(init)),
                initial_soc_std=float(config.initial_soc_std),
                input_reliability="reliable",
                qos_depth=1000,
                state_file=str(Path(tmp) / "state.yaml"),
                use_sim_time=True,
                **(node_params or {}),
            )
            link = NodeLink(context, node, ns)
            try:
                if not link.wait_matched():
                    raise RuntimeError("the node's topics did not match within 10 s")
                link.send(
                    series_messages(series),
                    expect_outputs=False,
                    rate=rate,
                    clock=True,
                    progress=progress,
                )
                used = node.tracker.samples_used
                if not link.spin_until(lambda: len(link.est) >= used and len(link.soc) >= used):
                    raise RuntimeError(f"the node published {len(link.est)} of {used} estimates")
                # The runtime report of the last sample is published with it (or not at all).
                link.spin_for(0.05)
                return (
                    estimates_from(link, series),
                    f"as the node: initial_soc={init}",
                    runtime_from(link, series, node.battery.limits.soc_min),
                )
            finally:
                link.close()
    finally:
        rclpy.try_shutdown(context=context)


def estimates_from(link: NodeLink, series: BatterySeries) -> EstimateSeries:
    """The node's outputs as an ``EstimateSeries``, one row per input sample (matched by
    stamp; a sample without an output repeats the previous row, NaN before the first)."""
    rows = [decode_estimate(m) for m in link.est]
    names = tuple(k.removeprefix("x.") for k in rows[0] if k.startswith("x.")) if rows else ()
    n, d = len(series), len(names)
    by_stamp = {round(r["stamp_s"] * NS_PER_S): r for r in rows}
    soc, std, v_pred, nis, innov = (np.full(n, np.nan) for _ in range(5))
    x = np.full((n, d), np.nan)
    p = np.full((n, d, d), np.nan)
    status: list[str] = []
    last = None
    for k, stamp in enumerate(series.stamp_ns):
        r = by_stamp.get(int(stamp))
        status.append("live" if r is not None else "rejected")
        if r is not None:
            v_pred[k], innov[k], nis[k] = r["voltage_pred_v"], r["innovation_v"], r["nis"]
            last = r
        if last is not None:
            soc[k], std[k] = last["soc"], last["soc_std"]
            x[k] = [last[f"x.{a}"] for a in names]
            p[k] = [[last[f"P.{a}.{b}"] for b in names] for a in names]
    return EstimateSeries.over(
        series,
        estimator=link.node.tracker.estimator.name,
        soc=soc,
        soc_std=std,
        voltage_pred_v=v_pred,
        nis=nis,
        status=tuple(status),
        innovation_v=innov,
        x=x,
        p=p,
        state_names=names,
    )


def runtime_from(link: NodeLink, series: BatterySeries, soc_empty: float) -> RuntimeSeries:
    """The node's ``battery/runtime`` and FULL status as a ``RuntimeSeries``, one row per input
    sample (a report holds from its sample's stamp on, as the offline replay keeps it)."""
    n = len(series)
    # Matched to the microsecond: a float64 stamp in seconds holds 1e18 ns to about 0.2 us.
    by_stamp = {round(r["stamp_s"] * 1e6): r for r in map(decode_runtime, link.runtime)}
    full_by_stamp = {
        m.header.stamp.sec * NS_PER_S + m.header.stamp.nanosec: m.power_supply_status == STATUS_FULL
        for m in link.soc
    }
    # The health columns stay NaN: a live replay does not learn health (soc_replay refuses
    # --learn-health and --state with --live).
    values = {k: np.full(n, np.nan) for k in (*RUNTIME_COLUMNS, *HEALTH_COLUMNS)}
    full = np.zeros(n, dtype=bool)
    last: dict[str, float] | None = None
    is_full = False
    for k, stamp in enumerate(series.stamp_ns):
        last = by_stamp.get(round(int(stamp) / 1000), last)
        is_full = full_by_stamp.get(int(stamp), is_full)
        full[k] = is_full
        if last is not None:
            for name in RUNTIME_COLUMNS:
                values[name][k] = last[name]
    return RuntimeSeries(values, full, soc_empty)
