"""The batch engine: estimators vectorized across K independent filters in lock-step (plain
numpy, no ROS). ``ukf.py``: t2rc_ukf; ``lanes.py``: recordings of different lengths as lanes;
``linalg.py``: small matrices over lanes."""

from .lanes import LaneInputs, LaneRun, run_lanes
from .ukf import BatchError, BatchT2rcUkf, LaneStatus, LaneStep, UkfTuning

__all__ = [
    "BatchError",
    "BatchT2rcUkf",
    "LaneInputs",
    "LaneRun",
    "LaneStatus",
    "LaneStep",
    "UkfTuning",
    "run_lanes",
]
