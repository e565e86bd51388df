"""Per-cell SoC of a series pack (ROS-free): Plett's bar-delta filters beside the pack's
estimator (``filter.py``), the cells' gate, usable SoC and imbalance (``bank.py``)."""

from .bank import (
    CELL_SUMMARY_FIELDS,
    CellBank,
    CellEstimate,
    cell_field_names,
    cell_filter_config,
    cell_limits_v,
)
from .filter import CellDeltaFilter, CellFilterConfig

__all__ = [
    "CELL_SUMMARY_FIELDS",
    "CellBank",
    "CellDeltaFilter",
    "CellEstimate",
    "CellFilterConfig",
    "cell_field_names",
    "cell_filter_config",
    "cell_limits_v",
]
