"""CPU of the node's input callback per message, back to back and with the caches gone cold.

The node runs in this process (no executor): each ``BatteryState`` goes straight into its
subscription callback, and beside it the same message into a bare ``Publisher.publish`` (all
the relay's callback does, ``relay_node.py``). Both are timed by this thread's CPU clock, in
two regimes:

* **hot**: message after message, as an offline loop runs them: the code and data stay in the
  CPU's caches;
* **cold**: ``--sleep-ms`` between calls (the 10 ms of a 100 Hz stream less the rest of a
  message's work), as the live node waits on its executor between messages: the process
  sleeps, the core runs others, and every call starts from cold caches.

The difference between the node's and the bare publish's cold CPU is what the node adds per
message over the relay, live (docs/benchmarks.md, "Where the time goes in the node"). The two
calls alternate, so a slow spell of the machine weighs on both. Prints numbers and asserts
nothing. DDS stays on loopback with a domain id of its own.

    python benchmarks/perf/callback_cost.py [--messages 2000] [--sleep-ms 5] [--domain-id 78]
        [--publish-rate-hz 10]
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]  # the checkout (its config/)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--estimator", default="hybrid")
    ap.add_argument("--battery", type=Path, default=ROOT / "config" / "sla_12v5ah.yaml")
    ap.add_argument("--filter-rate-hz", type=float, default=10.0)
    ap.add_argument("--publish-rate-hz", type=float, default=0.0, help="0: an output per message")
    ap.add_argument("--messages", type=int, default=2000, help="per regime")
    ap.add_argument("--sleep-ms", type=float, default=5.0, help="between calls, cold regime")
    ap.add_argument("--domain-id", type=int, default=78)
    args = ap.parse_args()
    os.environ.update(ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST", ROS_DOMAIN_ID=str(args.domain_id))

    import rclpy
    from node_latency import (  # this script's directory
        load_step_current_a,
        node_rates,
        pack_voltage_v,
    )
    from rclpy.parameter import Parameter
    from sensor_msgs.msg import BatteryState

    from soc_estimator_ros.node.ros_node import SocEstimatorNode
    from soc_estimator_ros.replay.live import RELIABLE, state_message

    rclpy.init()
    state_file = Path(f"/tmp/soc_callback_cost_{os.getpid()}.yaml")
    node = SocEstimatorNode(
        parameter_overrides=[
            Parameter("battery_file", value=str(args.battery)),
            Parameter("estimator", value=args.estimator),
            Parameter("initial_soc", value=0.9),
            Parameter("state_file", value=str(state_file)),
            Parameter("filter_rate_hz", value=args.filter_rate_hz),
            Parameter("publish_rate_hz", value=args.publish_rate_hz),
        ]
    )
    bare = node.create_publisher(BatteryState, "relay/soc", RELIABLE)
    t0_ns = time.time_ns()
    k = 0
    try:
        for regime, sleep_s in (("hot", 0.0), ("cold", args.sleep_ms / 1000.0)):
            node_us: list[float] = []
            bare_us: list[float] = []
            for _ in range(args.messages):
                current = load_step_current_a(k)  # node_latency.py's input
                msg = state_message(t0_ns + k * 10_000_000, pack_voltage_v(current), current, 25.0)
                k += 1
                for call, into in ((node._on_state, node_us), (bare.publish, bare_us)):
                    start = time.thread_time_ns()
                    call(msg)
                    into.append((time.thread_time_ns() - start) / 1000.0)
                    if sleep_s:
                        time.sleep(sleep_s)
            skip = args.messages // 5  # the first fifth: start-up and the filter's first steps
            n, b = np.array(node_us[skip:]), np.array(bare_us[skip:])
            print(
                f"{regime:4s}: node callback mean {n.mean():6.1f} us (median {np.median(n):6.1f}); "
                f"bare publish mean {b.mean():6.1f} us (median {np.median(b):6.1f}); "
                f"node - publish {n.mean() - b.mean():6.1f} us"
            )
        print(
            f"({args.estimator}{node_rates(args)}, {args.battery.name}, "
            f"{args.messages} messages a regime)"
        )
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
        state_file.unlink(missing_ok=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
