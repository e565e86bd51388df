"""soc_estimator_ros: onboard State-of-Charge estimation for small robot battery packs.

The estimation core (``units``, ``params``, ``models``, ``estimators``, ``evaluation``,
``identification``, ``recordings``, ``tracking``, ``replay`` offline) imports no ROS module;
``node`` is the thin rclpy adapter over a ``tracking.Tracker`` (docs/architecture.md).
"""

__version__ = "0.1.0"
