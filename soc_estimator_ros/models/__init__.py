"""Battery models of the estimation core (numpy and scipy only, no ROS)."""

from .coulomb import coulomb_efficiency, coulomb_step
from .ocv import UNINFORMATIVE_SOC_STD, OcvCurve
from .rc_saft import RcModelParams, SaftRcModel
from .tables import ParamTable
from .thevenin import KineticParams, RcBranch, SurfaceLag, TheveninModel, TheveninParams

__all__ = [
    "UNINFORMATIVE_SOC_STD",
    "KineticParams",
    "OcvCurve",
    "ParamTable",
    "RcBranch",
    "RcModelParams",
    "SaftRcModel",
    "SurfaceLag",
    "TheveninModel",
    "TheveninParams",
    "coulomb_efficiency",
    "coulomb_step",
]
