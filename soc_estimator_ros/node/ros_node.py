"""``soc_estimator_node``: the live SoC estimator, a thin rclpy adapter over a ``Tracker``.

Topics, parameters, services and persistence are documented in docs/node.md. In short:

* input ``battery/state`` (``sensor_msgs/BatteryState``, header stamp drives the filter), or
  ``current_topic`` + ``voltage_topic`` (``std_msgs/Float32``/``Float64``, paired by receive
  time, ``tracking/pairing.py``);
* every sample goes through the ROS-free :class:`~soc_estimator_ros.tracking.Tracker` (input
  gate, estimator, initialization, re-basing), the path ``soc_replay`` uses too;
* outputs ``battery/soc`` (``BatteryState``, the one rule of ``messages.estimate_state``),
  ``battery/soc_estimate`` (labelled ``Float64MultiArray``), ``battery/runtime`` (the tracker's
  runtime monitor: time to empty and full, state of power, level; once a second of sample
  time), ``/diagnostics`` (1 Hz, ``node/diagnostics.py``); the two vectors only while some
  node subscribes to them;
* stale input: no sample accepted for ``stale_timeout_s`` -> ``battery/soc`` keeps coming at
  ``publish_rate_hz`` (1 Hz when 0) with status UNKNOWN and the last SoC, diagnostics ERROR;
* run-time control: parameter ``estimator`` (switch), ``reset_soc_to``, service
  ``~/reset_soc_from_ocv``, ``mission_power_w``, the ``low_soc_*`` levels; the state is saved
  every ``save_period_s`` (written on the saver's thread, ``node/state_saver.py``) and on
  shutdown.

The callbacks only convert and delegate; parameters are validated in one callback and applied
in another (as ros2/demos do). All tracker access is serialized by one lock, so the node is safe
under a multi-threaded executor.
"""

from __future__ import annotations

import sys
import threading
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import rclpy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rcl_interfaces.msg import SetParametersResult
from rclpy.clock import Clock, ClockType
from rclpy.context import Context
from rclpy.event_handler import PublisherEventCallbacks
from rclpy.exceptions import ParameterException
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import BatteryState
from std_msgs.msg import Float32, Float64, Float64MultiArray, Header
from std_srvs.srv import Trigger

from ..errors import SocEstimatorError
from ..estimators.base import Estimator
from ..messages import estimate_state, pack_temperature_c
from ..params import BatteryParams, load_battery_params
from ..resources import default_battery_file
from ..runtime import LevelThresholds, RuntimeConfig
from ..scaling import scale_to_pack
from ..tracking import (
    Event,
    GateConfig,
    Level,
    Sample,
    SavedState,
    ScalarPairer,
    Tracker,
    TrackerConfig,
    Verdict,
)
from ..tracking.decimation import filter_period_s
from ..tracking.persistence import (
    remove_stale_temp_files,
    resume_decision,
    resume_health,
)
from ..units import NS_PER_S, CurrentSign, core_current_from, core_current_from_ros, stamp_to_ns
from .diagnostics import Diagnostics
from .housekeeping import Housekeeping
from .output_rate import OutputRate
from .parameters import (
    KNOWN_ESTIMATORS,
    LEVEL_PARAMETERS,
    NODE_NAME,
    PARAMETERS,
    NodeConfigError,
    default_state_file,
    level_overrides,
    parse_initial_soc,
    usage,
)
from .ros_messages import battery_state_msg, estimate_msg, runtime_msg
from .state_saver import StateSaver

#: How often (s) each throttled event (a rejection reason, ...) may be logged.
REJECTION_LOG_PERIOD_S = 5.0
#: Period (s) of the ``/diagnostics`` status.
DIAGNOSTICS_PERIOD_S = 1.0
#: Seconds a RuntimeError out of spin waits for a signal's shutdown before it is a fault.
SHUTDOWN_GRACE_S = 2.0
#: Seconds a save that must be on disk (shutdown, ``save_now``) may take before it is a fault.
SAVE_TIMEOUT_S = 10.0
_CURRENT_SIGNS = {
    "ros": CurrentSign.CHARGE_POSITIVE,
    "charge_positive": CurrentSign.CHARGE_POSITIVE,
    "discharge_positive": CurrentSign.DISCHARGE_POSITIVE,
}


class SocEstimatorNode(Node):
    """Estimates a battery's SoC from BatteryState (or current + voltage) samples."""

    def __init__(self, node_name: str = NODE_NAME, **kwargs: Any) -> None:
        """Declare the parameters, load the battery file, build everything.

        ``kwargs`` go to :class:`rclpy.node.Node` (``namespace``, ``context``,
        ``parameter_overrides``, ...). Raises a :class:`SocEstimatorError` (a bad parameter or
        battery file) after destroying the half-built node.
        """
        super().__init__(node_name, **kwargs)
        self._destroyed = False
        try:
            self._setup()
        except BaseException:
            self._destroyed = True
            saver: StateSaver | None = getattr(self, "_saver", None)
            if saver is not None:  # built before the failure: stop its thread
                saver.close(SAVE_TIMEOUT_S)
            Node.destroy_node(self)
            raise

    # -- set-up -------------------------------------------------------------------------------
    def _setup(self) -> None:
        for spec in PARAMETERS:
            self.declare_parameter(spec.name, spec.default, spec.descriptor())
        self._lock = threading.RLock()
        p = self._param
        self.battery_file = p("battery_file") or str(default_battery_file())
        battery = load_battery_params(self.battery_file)
        try:
            self.battery: BatteryParams = scale_to_pack(
                battery, p("cells_in_series"), p("capacity_ah")
            )
        except ValueError as exc:
            raise NodeConfigError(f"cells_in_series / capacity_ah: {exc}") from exc
        self.state_file = self._state_file_path(p("state_file"))
        self.tracker = self._make_tracker()
        self._stale_vs_clock: bool = p("stale_vs_clock")
        self._diagnostics = Diagnostics(self.tracker, self.battery_file, time.monotonic())
        self._log_times: dict[str, float] = {}
        self._published_seq = 0
        #: A filter step ran since the estimate vector was last published.
        self._pending_estimate = False
        self._saved_revision = 0
        self._pending_switch: Estimator | None = None
        self._last_header: Header | None = None
        self._soc_msg = BatteryState()  # filled anew for every output (battery_state_msg)
        self._read_sample_parameters()
        self._last_location = ""
        self._last_serial = ""
        inputs = self._create_topics()
        self.create_service(Trigger, "~/reset_soc_from_ocv", self._on_reset_from_ocv)
        self.create_service(Trigger, "~/reset_health", self._on_reset_health)
        self._publish_rate_hz: float = p("publish_rate_hz")
        self._output_rate = OutputRate(self._publish_rate_hz) if self._publish_rate_hz else None
        save_period_s: float = 0.0
        self._saver: StateSaver | None = None
        if self.state_file is not None:
            for tmp in remove_stale_temp_files(self.state_file):
                self.get_logger().warning(f"removed a temporary file left by a kill: {tmp}")
            save_period_s = p("save_period_s")
            self._saver = StateSaver(self.state_file, self._on_save_error)
        # One steady-clock timer for the stale output, the diagnostics and the saves (the
        # silence is wall time). Every timer is rebuilt into the executor's wait set on every
        # spin, so one timer instead of three is less rclpy work per input message
        # (docs/benchmarks.md, "Where the time goes in the node").
        stale_period_s = 1.0 / self._publish_rate_hz if self._publish_rate_hz > 0.0 else 1.0
        self._housekeeping = Housekeeping(time.monotonic())
        self._housekeeping.every(stale_period_s, self._publish_stale)
        self._housekeeping.every(DIAGNOSTICS_PERIOD_S, self._publish_diagnostics)
        if save_period_s > 0.0:
            self._housekeeping.every(save_period_s, self._save_in_background)
        steady = Clock(clock_type=ClockType.STEADY_TIME)
        self.create_timer(
            self._housekeeping.tick_s,
            lambda: self._housekeeping.run(time.monotonic()),
            clock=steady,
        )
        self.add_on_set_parameters_callback(self._validate_parameters)
        self.add_post_set_parameters_callback(self._apply_parameters)
        self.get_logger().info(
            f"estimating SoC of {self.battery.name!r} ({self.battery_file}) with "
            f"{self.tracker.estimator_name!r} from {inputs}; initial_soc={p('initial_soc')}; "
            f"state file: {self.state_file if self.state_file else 'none'}"
        )

    def _param(self, name: str) -> Any:
        return self.get_parameter(name).value

    def _read_sample_parameters(self) -> None:
        """The run-time parameters every sample reads, kept as attributes (a parameter lookup
        per field and sample was a twentieth of the node's time); re-read on every set."""
        p = self._param
        self._idle_current_a: float = p("idle_current_a")
        self._charging_current_a: float = p("charging_current_a")
        self._location: str = p("location")
        self._serial_number: str = p("serial_number")
        self._sim_time: bool = bool(p("use_sim_time"))

    def _state_file_path(self, value: str) -> Path | None:
        if value.lower() == "none":
            return None
        if value:
            return Path(value).expanduser()
        return default_state_file(self.get_name(), self.get_namespace())

    def _make_tracker(self) -> Tracker:
        p = self._param
        vmin, vmax = p("voltage_absurd_min_v"), p("voltage_absurd_max_v")
        try:
            gate = GateConfig.from_limits(
                self.battery.limits,
                current_factor=p("current_absurd_factor"),
                stale_timeout_s=p("stale_timeout_s"),
                time_jump_s=p("time_jump_s"),
                voltage_min_v=vmin if vmin >= 0.0 else None,
                voltage_max_v=vmax if vmax >= 0.0 else None,
            )
        except ValueError as exc:
            raise NodeConfigError(f"input gate: {exc}") from exc
        name = p("estimator")
        levels = level_overrides({k: p(k) for k in LEVEL_PARAMETERS})
        try:
            LevelThresholds.resolve(self.battery.limits, self.battery.levels, levels)
        except ValueError as exc:
            raise NodeConfigError(f"low_soc_*: {exc}") from exc
        runtime = RuntimeConfig(
            window_s=p("runtime_window_s"),
            mission_power_w=p("mission_power_w"),
            idle_current_a=p("idle_current_a"),
            charging_current_a=p("charging_current_a"),
            levels=levels,
            deferred=True,  # computed off the outputs (_publish_runtime_locked)
        )
        config = TrackerConfig(
            estimator=name,
            initial_soc=parse_initial_soc(p("initial_soc")),
            initial_soc_std=p("initial_soc_std"),
            ocv_voltage_std_v=p("ocv_voltage_std_v"),
            rebase_after_s=p("stale_timeout_s"),
            runtime=runtime,
            health=p("learn_health"),
            filter_period_s=filter_period_s(p("filter_rate_hz")),
        )
        health = None
        if config.health and self.state_file is not None:
            health, reason = resume_health(
                self.state_file, self.battery.name, self.battery.capacity_ah
            )
            self.get_logger().info(reason)
        resume = None
        if self.state_file is not None:
            path, max_age_s, battery = self.state_file, p("resume_max_age_s"), self.battery.name

            def resume(now_s: float) -> Any:
                return resume_decision(path, now_s, max_age_s, battery)

        try:
            return Tracker(self.battery, gate, config, resume=resume, health=health)
        except ValueError as exc:
            raise NodeConfigError(f"estimator = {name!r}: {exc}") from exc

    def _qos(self, reliable: bool) -> QoSProfile:
        return QoSProfile(
            history=HistoryPolicy.KEEP_LAST,
            depth=self._param("qos_depth"),
            reliability=ReliabilityPolicy.RELIABLE if reliable else ReliabilityPolicy.BEST_EFFORT,
            durability=DurabilityPolicy.VOLATILE,
        )

    def _create_topics(self) -> str:
        """Publishers and subscriptions; returns a description of the inputs for the log."""
        p = self._param
        out_qos = self._qos(reliable=True)
        # No QoS event handlers on the outputs: each is a waitable rebuilt into the executor's
        # wait set on every spin, and a subscriber whose QoS cannot match is reported by its
        # own node (rclpy's default subscription handler) anyway.
        quiet = PublisherEventCallbacks(use_default_callbacks=False)

        def publisher(msg_type: Any, topic: str, qos: QoSProfile | int) -> Any:
            return self.create_publisher(msg_type, topic, qos, event_callbacks=quiet)

        self._soc_pub = publisher(BatteryState, p("output_topic"), out_qos)
        self._est_pub = publisher(Float64MultiArray, p("estimate_topic"), out_qos)
        self._runtime_pub = publisher(Float64MultiArray, p("runtime_topic"), out_qos)
        self._diag_pub = publisher(DiagnosticArray, "/diagnostics", 10)
        reliability = p("input_reliability")
        if reliability not in ("best_effort", "reliable"):
            raise NodeConfigError(
                f"input_reliability = {reliability!r}: expected best_effort or reliable"
            )
        in_qos = self._qos(reliable=reliability == "reliable")
        current_topic, voltage_topic = p("current_topic"), p("voltage_topic")
        self.pairer: ScalarPairer | None = None
        if not (current_topic or voltage_topic):
            self.create_subscription(BatteryState, p("state_topic"), self._on_state, in_qos)
            return str(p("state_topic"))
        if not (current_topic and voltage_topic):
            raise NodeConfigError("current_topic and voltage_topic must be set together")
        scalar_type = {"float32": Float32, "float64": Float64}.get(p("scalar_type"))
        if scalar_type is None:
            raise NodeConfigError(
                f"scalar_type = {p('scalar_type')!r}: expected float32 or float64"
            )
        sign_name = p("current_sign")
        if sign_name not in _CURRENT_SIGNS:
            raise NodeConfigError(
                f"current_sign = {sign_name!r}: expected ros or discharge_positive"
            )
        self._current_sign = _CURRENT_SIGNS[sign_name]
        self.pairer = ScalarPairer(p("pair_tolerance_s"))
        self.create_subscription(scalar_type, current_topic, self._on_current, in_qos)
        self.create_subscription(scalar_type, voltage_topic, self._on_voltage, in_qos)
        return f"{current_topic} + {voltage_topic} ({p('scalar_type')}, {sign_name} sign)"

    # -- input callbacks: convert and delegate -------------------------------------------------
    def _on_state(self, msg: BatteryState) -> None:
        sample = Sample(
            stamp_to_ns(msg.header.stamp.sec, msg.header.stamp.nanosec),
            core_current_from_ros(float(msg.current)),
            float(msg.voltage),
            pack_temperature_c(float(msg.temperature), msg.cell_temperature),
            bool(msg.present),
            tuple(msg.cell_voltage),  # an array of float32: its items are Python floats
        )
        self.process_sample(sample, msg.header, msg.location, msg.serial_number)

    def _on_current(self, msg: Float32 | Float64) -> None:
        assert self.pairer is not None
        now_ns = self.clock_ns()
        current_a = core_current_from(float(msg.data), self._current_sign)
        with self._lock:
            paired = self.pairer.add_current(now_ns, current_a)
        if paired is not None:
            self.process_sample(Sample(paired.stamp_ns, paired.current_a, paired.voltage_v))

    def _on_voltage(self, msg: Float32 | Float64) -> None:
        assert self.pairer is not None
        now_ns = self.clock_ns()
        with self._lock:
            paired = self.pairer.add_voltage(now_ns, float(msg.data))
        if paired is not None:
            self.process_sample(Sample(paired.stamp_ns, paired.current_a, paired.voltage_v))

    def clock_ns(self) -> int:
        """The node's ROS clock now (ns). Without ``use_sim_time`` ROS time is the system
        time, read directly: ``Clock.now()`` builds a ``Time``, and asking the clock whether a
        sim-time override is active takes its handle, together 8 % of the callback's CPU when
        the caches are cold between 100 Hz messages (docs/benchmarks.md). rclpy's
        ``TimeSource`` turns the override on exactly when ``use_sim_time`` is true."""
        if self._sim_time:
            return self.get_clock().now().nanoseconds
        return time.time_ns()

    def process_sample(
        self,
        sample: Sample,
        header: Header | None = None,
        location: str = "",
        serial_number: str = "",
    ) -> Verdict:
        """Run one sample through the tracker and publish its estimate (if accepted).

        ``header`` (the input's, copied to the output; None builds one from the stamp),
        ``location`` and ``serial_number`` (used when the parameters are empty).
        """
        clock_ns = self.clock_ns()
        now_ns = clock_ns if self._stale_vs_clock else None
        with self._lock:
            # Another pack's first sample is estimated with that pack's health.
            pack = self.tracker.pack_serial(self._serial_number or serial_number)
            if pack is not None:
                self._log((pack,))
            result = self.tracker.process(sample, now_ns=now_ns, clock_ns=clock_ns)
            self._log(result.events)
            est = result.estimate
            if est is not None:
                self._last_header = header
                self._last_location, self._last_serial = location, serial_number
                self._pending_estimate = self._pending_estimate or result.filtered
                rate = self._output_rate
                if rate is None or rate.due(est.t_s, result.filtered):
                    self._publish_locked()
                if rate is None or rate.takes_deferred_work:
                    self._publish_runtime_locked()
        return result.verdict

    def _log(self, events: Sequence[Event]) -> None:
        """Log tracker events; each event key at most every ``REJECTION_LOG_PERIOD_S``."""
        log = self.get_logger()
        for event in events:
            if event.key:
                now = time.monotonic()
                last = self._log_times.get(event.key)
                if last is not None and now - last < REJECTION_LOG_PERIOD_S:
                    continue
                self._log_times[event.key] = now
            # One call site per severity: rclpy ties a call site to one severity.
            if event.level is Level.ERROR:
                log.error(event.message)
            elif event.level is Level.WARNING:
                log.warning(event.message)
            else:
                log.info(event.message)

    # -- outputs ------------------------------------------------------------------------------
    def _publish_locked(self) -> None:
        est, last = self.tracker.last_estimate, self.tracker.last_sample
        if est is None or last is None:
            return
        self._published_seq += 1
        capacity_ah, soh = self._learned_health()
        fields = estimate_state(
            self.battery,
            self.tracker.usable_soc,
            last.stamp_ns,
            last.voltage_v,
            last.current_a,
            last.temperature_c,
            idle_current_a=self._idle_current_a,
            charging_current_a=self._charging_current_a,
            full=self.tracker.runtime.full,
            location=self._location or self._last_location,
            serial_number=self._serial_number or self._last_serial,
            capacity_ah=capacity_ah,
            soh=soh,
        )
        self._soc_pub.publish(battery_state_msg(fields, self._last_header, self._soc_msg))
        if self._pending_estimate:
            self._pending_estimate = False
            # The vectors are built and published only for a listener: a publish costs rclpy
            # and the DDS CPU with no subscriber too, about half of one with a subscriber
            # (docs/benchmarks.md).
            if self._est_pub.get_subscription_count():
                health = self.tracker.health
                self._est_pub.publish(
                    estimate_msg(
                        last.stamp_ns / NS_PER_S,
                        est,
                        None if health is None else health.fields(),
                        self.tracker.last_cells,
                    )
                )

    def _publish_runtime_locked(self) -> None:
        """The runtime prediction due, computed only now (RuntimeConfig's ``deferred``): the
        same numbers as on its own sample, after that sample's SoC is out or, with a publish
        rate, on a sample without an output (node/output_rate.py)."""
        report = self.tracker.runtime.flush()
        if report is not None and self._runtime_pub.get_subscription_count():
            self._runtime_pub.publish(runtime_msg(report))

    def _learned_health(self) -> tuple[float | None, float | None]:
        """``estimate_state``'s capacity and SOH: those the estimator computes with (the
        learned ones once beyond their noise, ``HealthMonitor.learned``); None, None with
        learn_health off."""
        health = self.tracker.health
        if health is None:
            return None, None
        return health.applied_capacity_ah, health.applied_soh

    def stale_for(self, now_steady_s: float) -> float | None:
        """Seconds without an accepted sample beyond ``stale_timeout_s`` (None: not stale,
        or no sample yet)."""
        last = self.tracker.last_accept_steady_s
        if last is None or now_steady_s - last <= self._param("stale_timeout_s"):
            return None
        return now_steady_s - last

    def _publish_stale(self) -> None:
        """While the input is stale: ``battery/soc`` with the last SoC, status UNKNOWN."""
        with self._lock:
            if self.stale_for(time.monotonic()) is None:
                return
            last = self.tracker.last_sample
            if last is None:
                return
            header = Header()
            header.stamp = self.get_clock().now().to_msg()
            header.frame_id = self._last_header.frame_id if self._last_header else "battery"
            capacity_ah, soh = self._learned_health()
            cells = self.tracker.last_cells
            fields = estimate_state(
                self.battery,
                self.tracker.soc if cells is None else cells.usable_soc,
                0,
                last.voltage_v,
                last.current_a,
                stale=True,
                location=self._location or self._last_location,
                serial_number=self._serial_number or self._last_serial,
                capacity_ah=capacity_ah,
                soh=soh,
            )
            self._soc_pub.publish(battery_state_msg(fields, header, self._soc_msg))

    def _publish_diagnostics(self) -> None:
        arr = DiagnosticArray()
        arr.header.stamp = self.get_clock().now().to_msg()
        arr.status = [self.diagnostic_status()]
        self._diag_pub.publish(arr)

    def diagnostic_status(self) -> DiagnosticStatus:
        """The node's DiagnosticStatus now (node/diagnostics.py)."""
        with self._lock:
            extra: list[tuple[str, Any]] = []
            if self.pairer is not None:
                extra = [("pairs", self.pairer.paired), ("unpaired_dropped", self.pairer.dropped)]
            stale_timeout_s = self._param("stale_timeout_s")
            report = self._diagnostics.report(time.monotonic(), stale_timeout_s, extra)
        return DiagnosticStatus(
            level=bytes([int(report.level)]),
            name=f"{self.get_name()}: SoC estimator",
            message=report.message,
            hardware_id=self._param("serial_number") or self._last_serial or self.battery.name,
            values=[KeyValue(key=k, value=v) for k, v in report.values],
        )

    # -- services and parameters --------------------------------------------------------------
    def _on_reset_from_ocv(
        self, request: Trigger.Request, response: Trigger.Response
    ) -> Trigger.Response:
        del request
        with self._lock:
            try:
                soc, std, last = self.tracker.reset_from_ocv()
            except LookupError as exc:
                response.success, response.message = False, str(exc)
                return response
        response.success = True
        response.message = (
            f"SoC reset to {soc:.4f} (std {std:.4f}) from the OCV at {last.voltage_v:.3f} V"
        )
        if abs(last.current_a) > self._param("idle_current_a"):
            response.message += (
                f" (warning: under load, {last.current_a:.2f} A; read through the battery "
                "file's model, its relaxation unknown: a rest reads the OCV better)"
            )
        self.get_logger().info(response.message)
        return response

    def _on_reset_health(
        self, request: Trigger.Request, response: Trigger.Response
    ) -> Trigger.Response:
        """Another pack: the learned health starts again from the battery file's values."""
        del request
        with self._lock:
            if self.tracker.health is None:
                response.success = False
                response.message = "health is not learned (learn_health is false)"
                return response
            self.tracker.new_pack(self._param("serial_number") or self._last_serial)
        response.success = True
        response.message = (
            f"health reset to the battery file's: capacity {self.battery.capacity_ah:g} Ah, "
            "R0 factor 1"
        )
        self.get_logger().info(response.message)
        return response

    def _validate_parameters(self, params: list[Parameter]) -> SetParametersResult:
        for param in params:
            if param.name == "estimator":
                name = param.value
                if not isinstance(name, str) or name not in KNOWN_ESTIMATORS:
                    return SetParametersResult(
                        successful=False,
                        reason=f"unknown estimator {name!r}; known: {', '.join(KNOWN_ESTIMATORS)}",
                    )
                with self._lock:
                    try:
                        self._pending_switch = self.tracker.prepare_estimator(name)
                    except ValueError as exc:
                        return SetParametersResult(successful=False, reason=str(exc))
            elif param.name == "reset_soc_to":
                value = float(param.value)
                if value >= 0.0 and not 0.0 <= value <= 1.0:
                    return SetParametersResult(
                        successful=False, reason="reset_soc_to must be in [0, 1] (or -1)"
                    )
        if any(param.name in LEVEL_PARAMETERS for param in params):
            values = {k: self._param(k) for k in LEVEL_PARAMETERS}
            values.update({q.name: q.value for q in params if q.name in LEVEL_PARAMETERS})
            try:
                LevelThresholds.resolve(
                    self.battery.limits, self.battery.levels, level_overrides(values)
                )
            except ValueError as exc:
                return SetParametersResult(successful=False, reason=str(exc))
        return SetParametersResult(successful=True)

    def _apply_parameters(self, params: list[Parameter]) -> None:
        with self._lock:
            self._read_sample_parameters()
        for param in params:
            if param.name == "estimator":
                with self._lock:
                    prepared, self._pending_switch = self._pending_switch, None
                    self._log([self.tracker.switch_estimator(param.value, prepared)])
            elif param.name == "reset_soc_to" and float(param.value) >= 0.0:
                # Post-set: a reset_soc_std set in the same call is already in effect.
                soc, std = float(param.value), self._param("reset_soc_std")
                with self._lock:
                    self.tracker.reset_soc(soc, std)
                self.get_logger().info(f"SoC reset to {soc:.4f} (std {std:.4f}) by reset_soc_to")
            elif param.name == "mission_power_w":
                with self._lock:
                    self.tracker.runtime.set_mission_power(float(param.value))
            elif param.name == "idle_current_a":
                with self._lock:
                    self.tracker.runtime.set_idle_current(float(param.value))
        if any(param.name in LEVEL_PARAMETERS for param in params):
            # Post-set: every level parameter of the call is in effect; validated above.
            overrides = level_overrides({k: self._param(k) for k in LEVEL_PARAMETERS})
            with self._lock:
                th = self.tracker.runtime.set_levels(overrides)
            self.get_logger().info(
                f"battery levels: warn {th.warn_soc:.3f}, critical {th.critical_soc:.3f}, "
                f"emergency {th.emergency_soc:.3f}, hysteresis {th.hysteresis_soc:.3f}, "
                f"debounce {th.debounce_s:g} s"
            )

    # -- persistence and shutdown -------------------------------------------------------------
    def saved_state(self) -> SavedState | None:
        """What would be saved now (None before the first accepted sample)."""
        with self._lock:
            return self.tracker.saved_state()

    def _submit_save(self, force: bool) -> bool:
        """Hand a snapshot of the state to the saver if it changed since the last one, the
        last write failed, or ``force``; False if there was nothing to hand."""
        assert self._saver is not None
        with self._lock:
            revision = self.tracker.revision
            if revision == self._saved_revision and self._saver.ok and not force:
                return False
            state = self.saved_state()
        if state is None:
            return False
        self._saver.submit(state)
        self._saved_revision = revision
        return True

    def _save_in_background(self) -> None:
        """The periodic save: the executor takes a snapshot, the saver's thread writes it
        (``state_saver.py``: a disk's stall must not hold the input messages)."""
        if self._saver is not None:
            self._submit_save(force=False)

    def save_now(self, force: bool = False) -> bool:
        """Save the state if it changed since the last save (or ``force``) and wait until it
        is written; False if there was nothing to save or the write failed."""
        if self._saver is None:
            return False
        submitted = self._submit_save(force)
        if not self._saver.flush(SAVE_TIMEOUT_S):
            self.get_logger().error(
                f"saving the state to {self.state_file} did not end within {SAVE_TIMEOUT_S:g} s"
            )
            return False
        return submitted and self._saver.ok

    def _on_save_error(self, exc: Exception) -> None:
        """A failed write (on the saver's thread): logged; the next save tries again."""
        self.get_logger().warning(
            f"cannot save the state to {self.state_file}: {exc}", throttle_duration_sec=60.0
        )

    def destroy_node(self) -> None:
        """Save the state (if any), then destroy the node."""
        if not self._destroyed:
            self._destroyed = True
            try:
                if self.save_now():
                    self.get_logger().info(f"state saved to {self.state_file}")
            except Exception as exc:  # never let a failed save block the shutdown
                self.get_logger().error(f"saving the state on shutdown failed: {exc}")
            if self._saver is not None:
                self._saver.close(SAVE_TIMEOUT_S)
        super().destroy_node()


def context_goes_down(context: Context, within_s: float) -> bool:
    """True once ``context`` is shut down, False if it is still up after ``within_s``."""
    deadline = time.monotonic() + within_s
    while context.ok():
        if time.monotonic() >= deadline:
            return False
        time.sleep(0.01)
    return True


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point; ``argv`` excludes the program name (default ``sys.argv[1:]``)."""
    args = list(sys.argv[1:] if argv is None else argv)
    own = args[: args.index("--ros-args")] if "--ros-args" in args else args
    if "-h" in own or "--help" in own:
        print(usage())
        return 0
    rclpy.init(args=[NODE_NAME, *args])
    node: SocEstimatorNode | None = None
    rc = 0
    try:
        node = SocEstimatorNode()
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except (SocEstimatorError, ParameterException) as exc:
        print(f"{NODE_NAME}: {exc}", file=sys.stderr)
        rc = 1
    except RuntimeError:
        # SIGINT shuts the context down; a callback already running then fails to publish
        # ("publisher's context is invalid", rclpy's RCLError), or the executor, converting a
        # message when the signal's KeyboardInterrupt arrives, fails in pybind11 ("Unable to
        # convert call argument '0' to Python object") a moment before rclpy's signal thread
        # has shut the context down. That is the stop that was asked for, not a fault: the
        # state is still saved below. An error with the context still up after
        # SHUTDOWN_GRACE_S raises.
        if node is None or not context_goes_down(node.context, SHUTDOWN_GRACE_S):
            raise
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    return rc


if __name__ == "__main__":
    sys.exit(main())
