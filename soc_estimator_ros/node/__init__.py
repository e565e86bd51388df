"""The ROS 2 node: ``ros_node`` (the rclpy adapter), ``parameters`` (the parameter table),
``diagnostics`` and ``ros_messages`` (rclpy message fillers). Importing this package does not
import rclpy; its modules do."""
