"""The ROS 2 node: ``ros_node`` (the rclpy adapter), ``parameters`` (the parameter table),
``diagnostics``, ``housekeeping`` (the periodic chores on one timer) and ``ros_messages``
(rclpy message fillers). Importing this package does not import rclpy; its modules do."""
