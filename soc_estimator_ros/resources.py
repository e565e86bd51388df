"""Bundled battery files: where they are installed, and the one chemistry -> file map.

The package ships ``config/*.yaml``. They are found, in this order:

1. the source checkout (``<repo>/config``, an editable or ``--symlink-install`` install);
2. the install prefix of this very module (colcon: ``<prefix>/lib/pythonX.Y/site-packages/
   soc_estimator_ros`` -> ``<prefix>/share/soc_estimator_ros/config``; the same layout for a pip
   install into a virtual environment, whose ``data_files`` go to ``sys.prefix``);
3. every prefix of ``AMENT_PREFIX_PATH`` (a sourced ROS workspace) and ``sys.prefix``.

:func:`bundled_file` is the one place that maps a chemistry to its bundled file.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

from .errors import SocEstimatorError

PACKAGE = "soc_estimator_ros"

#: The bundled battery file of each chemistry (``params.CHEMISTRIES``).
BUNDLED_FILES: dict[str, str] = {
    "sla": "sla_12v5ah.yaml",
    "lfp": "lfp_12v6ah.yaml",
    "li_ion": "li_ion_ncr18650pf.yaml",
}

#: The chemistry the node loads when no ``battery_file`` is given.
DEFAULT_CHEMISTRY = "sla"


class ResourceError(SocEstimatorError, FileNotFoundError):
    """A bundled file that is not installed where the package looks for it."""


def _candidates() -> list[Path]:
    here = Path(__file__).resolve()
    dirs = [here.parents[1] / "config"]
    # <prefix>/lib/pythonX.Y/site-packages/soc_estimator_ros/resources.py -> <prefix>
    if len(here.parents) > 4:
        dirs.append(here.parents[4] / "share" / PACKAGE / "config")
    prefixes = [p for p in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep) if p]
    dirs += [Path(p) / "share" / PACKAGE / "config" for p in [*prefixes, sys.prefix]]
    return dirs


def config_dir() -> Path:
    """The directory holding the bundled battery files (see the module docstring)."""
    for d in _candidates():
        if (d / BUNDLED_FILES[DEFAULT_CHEMISTRY]).is_file():
            return d
    looked = ", ".join(str(d) for d in _candidates())
    raise ResourceError(f"the bundled battery files are not installed (looked in {looked})")


def bundled_file(chemistry: str) -> Path:
    """The bundled battery file of ``chemistry`` (``sla``, ``lfp`` or ``li_ion``)."""
    if chemistry not in BUNDLED_FILES:
        known = ", ".join(sorted(BUNDLED_FILES))
        raise ResourceError(f"no bundled battery file for chemistry {chemistry!r} (known: {known})")
    return config_dir() / BUNDLED_FILES[chemistry]


def default_battery_file() -> Path:
    """The file the node loads when its ``battery_file`` parameter is empty."""
    return bundled_file(DEFAULT_CHEMISTRY)
