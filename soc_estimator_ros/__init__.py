"""soc_estimator_ros: onboard State-of-Charge estimation for small robot battery packs.

The estimation core (``models``, ``params``, ``conventions`` and, later, ``estimators`` and
``identification``) imports no ROS module; ``node.py`` is the thin rclpy adapter around it.
"""

__version__ = "0.1.0"
