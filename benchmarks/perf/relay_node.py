"""The floor under ``soc_estimator_node``: an rclpy node that only relays BatteryState.

Subscribes ``battery/state`` and republishes each message unchanged on ``battery/soc``, with
the same QoS and executor as the real node, nothing else. ``node_latency.py --baseline`` runs
it in place of the node: its CPU and latency are what rclpy and Fast DDS cost per message on
this machine, before any estimation (docs/benchmarks.md).
"""

from __future__ import annotations

import sys

import rclpy
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from sensor_msgs.msg import BatteryState


def main() -> int:
    rclpy.init(args=sys.argv)
    from soc_estimator_ros.replay.live import RELIABLE

    node = rclpy.create_node("soc_relay")
    pub = node.create_publisher(BatteryState, "battery/soc", RELIABLE)
    node.create_subscription(BatteryState, "battery/state", pub.publish, RELIABLE)
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    try:
        executor.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
