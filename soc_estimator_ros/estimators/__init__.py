"""SoC estimators sharing one interface (see ``base.py``), and a registry to build them by name.

``make_estimator(name, battery, initial_soc, ...)`` builds one with the tuning block
``battery.filters[tuning]`` (default: the block named like the estimator, if the file has one)
over the estimator's defaults.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from ..params import BatteryParams
from .base import Estimate, Estimator, StepStatus, TimePolicy, condition_covariance
from .coulomb import CoulombCounter
from .dcc_ekf import DccEkf
from .ekf import Ekf
from .hybrid import Hybrid
from .rc_kf import RcKf
from .t2rc_ukf import T2rcUkf

ESTIMATORS: dict[str, type[Estimator]] = {
    cls.name: cls for cls in (Hybrid, T2rcUkf, RcKf, Ekf, DccEkf, CoulombCounter)
}

#: The estimator the node and the replay use unless told otherwise.
DEFAULT_ESTIMATOR = Hybrid.name

#: Named tuning presets (the papers' own tunings): preset name -> estimator name. The tuning
#: block of the same name in the battery file's ``filters`` holds the values.
PRESETS: dict[str, str] = {"rc_kf_paper": RcKf.name, "ekf_paper": Ekf.name}


def make_estimator(
    name: str,
    battery: BatteryParams,
    initial_soc: float,
    initial_soc_std: float = 0.05,
    tuning: str | Mapping[str, Any] | None = None,
    time_policy: TimePolicy | None = None,
) -> Estimator:
    """Build estimator ``name`` (or a preset name) for ``battery``.

    ``tuning`` is a mapping of tuning entries, or the name of a ``filters`` block of the battery
    file; by default the block named like the estimator (or preset) is used when present.
    """
    est_name = PRESETS.get(name, name)
    if est_name not in ESTIMATORS:
        known = sorted([*ESTIMATORS, *PRESETS])
        raise ValueError(f"unknown estimator {name!r}; known: {', '.join(known)}")
    if tuning is None:
        if name in PRESETS and name not in battery.filters:
            raise ValueError(f"{battery.name}: preset {name!r} needs a filters.{name} block")
        tuning = name if name in battery.filters else None
    if isinstance(tuning, str):
        if tuning not in battery.filters:
            raise ValueError(f"{battery.name}: no tuning block filters.{tuning} in the file")
        tuning = battery.filters[tuning]
    cls = ESTIMATORS[est_name]
    return cls(battery, initial_soc, initial_soc_std, tuning=tuning, time_policy=time_policy)


__all__ = [
    "DEFAULT_ESTIMATOR",
    "ESTIMATORS",
    "PRESETS",
    "Estimate",
    "Estimator",
    "StepStatus",
    "TimePolicy",
    "condition_covariance",
    "make_estimator",
]
