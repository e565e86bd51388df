"""Launch ``soc_estimator_node`` with a battery file and a parameter file.

    ros2 launch soc_estimator_ros soc_estimator.launch.py \
        battery:=/path/to/battery.yaml namespace:=robot1 params_file:=/path/to/params.yaml

Arguments:
    battery: battery parameter file (default: the package's ``config/sla_12v5ah.yaml``).
    namespace: namespace of the node and its relative topics (default: none).
    params_file: node parameters (default: the package's ``config/soc_estimator_node.yaml``).

The share directory is found with ``launch_ros``'s ``FindPackageShare`` (ament index lookup at
launch time), so the file imports only ``launch`` and ``launch_ros``.
"""

from __future__ import annotations

from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration, PathJoinSubstitution
from launch_ros.actions import Node
from launch_ros.substitutions import FindPackageShare

from launch import LaunchDescription

PACKAGE = "soc_estimator_ros"


def generate_launch_description() -> LaunchDescription:
    """The node, its namespace, parameter file and battery file as launch arguments."""
    share = FindPackageShare(PACKAGE)
    return LaunchDescription(
        [
            DeclareLaunchArgument(
                "battery",
                default_value=PathJoinSubstitution([share, "config", "sla_12v5ah.yaml"]),
                description="battery parameter file (YAML)",
            ),
            DeclareLaunchArgument(
                "namespace", default_value="", description="namespace of the node"
            ),
            DeclareLaunchArgument(
                "params_file",
                default_value=PathJoinSubstitution([share, "config", "soc_estimator_node.yaml"]),
                description="node parameter file (ROS 2 params-file form)",
            ),
            Node(
                package=PACKAGE,
                executable="soc_estimator_node",
                name="soc_estimator_node",
                namespace=LaunchConfiguration("namespace"),
                parameters=[
                    LaunchConfiguration("params_file"),
                    {"battery_file": LaunchConfiguration("battery")},
                ],
                output="screen",
                emulate_tty=True,
            ),
        ]
    )
