"""Battery health, learned online: full capacity, a factor on ``R_0``, state of health.

``HealthMonitor`` (``monitor.py``) runs beside the estimator; ``capacity.py`` holds the
weighted total-least-squares fit of the capacity (and the law by which an aged pack's rest
readings are read, ``OcvAgeing``), ``resistance.py`` the ``R_0`` factor's
filter. No ROS here.
"""

from .capacity import CapacityEstimator, CapacityPair, OcvAgeing, fit_capacity
from .monitor import HEALTH_FIELDS, HealthMonitor, HealthState
from .resistance import ResistanceFactor, step_observation

__all__ = [
    "HEALTH_FIELDS",
    "CapacityEstimator",
    "CapacityPair",
    "HealthMonitor",
    "HealthState",
    "OcvAgeing",
    "ResistanceFactor",
    "fit_capacity",
    "step_observation",
]
