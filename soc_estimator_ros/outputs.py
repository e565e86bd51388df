"""The node's estimate vector as plain data (no rclpy): its fields, labels and values.

``battery/soc_estimate`` (``std_msgs/Float64MultiArray``) carries one flat float64 vector per
estimate (node.py's docstring)::

    data = [stamp_s, soc, soc_var, soc_std, voltage_pred_v, innovation_v, nis,
            x[0..n-1], P[0,0], P[0,1], ..., P[n-1,n-1]]      (P row-major)

with ``layout.dim[0].label = "fields:" + ",".join(labels)``. The node publishes it live and
``soc_replay --output-bag`` writes it to a bag; both build it here, so a bag of an offline
replay reads like a recording of the node.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from .estimators.base import Estimate

ESTIMATE_FIELDS = (
    "stamp_s",
    "soc",
    "soc_var",
    "soc_std",
    "voltage_pred_v",
    "innovation_v",
    "nis",
)


def estimate_labels(state_names: Sequence[str]) -> list[str]:
    """Labels of the estimate vector for an estimator's state names."""
    names = list(state_names)
    return [
        *ESTIMATE_FIELDS,
        *(f"x.{n}" for n in names),
        *(f"P.{a}.{b}" for a in names for b in names),
    ]


def layout_label(state_names: Sequence[str]) -> str:
    """``layout.dim[0].label`` of the estimate vector."""
    return "fields:" + ",".join(estimate_labels(state_names))


def estimate_row(
    stamp_s: float,
    soc: float,
    soc_var: float,
    voltage_pred_v: float,
    innovation_v: float,
    nis: float,
    x: np.ndarray,
    p: np.ndarray,
) -> list[float]:
    """The estimate vector from its parts."""
    head = [stamp_s, soc, soc_var, math.sqrt(max(soc_var, 0.0)), voltage_pred_v, innovation_v, nis]
    return (
        [float(v) for v in head] + [float(v) for v in np.ravel(x)] + [float(v) for v in np.ravel(p)]
    )


def estimate_vector(stamp_s: float, est: Estimate) -> list[float]:
    """The estimate vector of one :class:`Estimate`."""
    return estimate_row(
        stamp_s, est.soc, est.soc_var, est.voltage_pred_v, est.innovation_v, est.nis, est.x, est.p
    )


def decode_estimate(msg: Any) -> dict[str, float]:
    """A ``Float64MultiArray`` estimate message (rclpy's or rosbags') as {label: value}."""
    label = msg.layout.dim[0].label
    if not label.startswith("fields:"):
        raise ValueError(f"not a soc_estimate layout: {label!r}")
    names = label.removeprefix("fields:").split(",")
    return dict(zip(names, (float(v) for v in msg.data), strict=True))
