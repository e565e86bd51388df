"""package.xml stays honest: format 3, ament_python, and a declared rosdep key for every import.

Every module the package imports (scanned with ast, including imports inside functions) that is
neither standard library nor the package itself must map to a rosdep key in ROSDEP_KEY below,
and that key must be an exec_depend (or depend) of package.xml.
"""

from __future__ import annotations

import ast
import re
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import yaml

REPO_ROOT = Path(__file__).resolve().parents[2]
PACKAGE = "soc_estimator_ros"

# Python top-level module -> rosdep key that provides it. Extend when the code imports something
# new (ROS keys: the package name; others: ros/rosdistro rosdep/python.yaml or base.yaml).
ROSDEP_KEY = {
    "numpy": "python3-numpy",
    "scipy": "python3-scipy",
    "yaml": "python3-yaml",
    "matplotlib": "python3-matplotlib",
    "filterpy": "python3-filterpy-pip",
    "rosbags": "python3-rosbags-pip",
    "rclpy": "rclpy",
    "sensor_msgs": "sensor_msgs",
    "std_msgs": "std_msgs",
    "diagnostic_msgs": "diagnostic_msgs",
    "std_srvs": "std_srvs",
    "rosgraph_msgs": "rosgraph_msgs",
    "builtin_interfaces": "builtin_interfaces",
    "rcl_interfaces": "rcl_interfaces",
    "launch": "launch",
    "launch_ros": "launch_ros",
    "ament_index_python": "ament_index_python",
}
# Desktop-only modules: imported lazily (inside functions) by this one file, for fleet-size
# replays the robot never runs; setup.py's "fleet" extra and requirements.txt install them, and
# package.xml does not make a robot's `rosdep install` pull a cluster engine.
DESKTOP_ONLY = {"dask": "replay/fleet.py", "fsspec": "replay/fleet.py"}
# rosdep keys this package uses that the rosdistro database does not define (as far as we could
# check); rosdep/soc_estimator_ros.yaml defines them for `rosdep install`.
LOCAL_ROSDEP_KEYS = {"python3-rosbags-pip"}
REQUIRED_EXEC_DEPENDS = {
    "rclpy",
    "sensor_msgs",
    "std_msgs",
    "diagnostic_msgs",
    "std_srvs",
    "builtin_interfaces",
    "rcl_interfaces",
    "launch",
    "launch_ros",
    "python3-numpy",
    "python3-scipy",
    "python3-yaml",
    "python3-matplotlib",
    "python3-filterpy-pip",
    "python3-rosbags-pip",
}


def _manifest() -> ET.Element:
    return ET.parse(REPO_ROOT / "package.xml").getroot()


def _keys(root: ET.Element, *tags: str) -> set[str]:
    return {(e.text or "").strip() for tag in tags for e in root.iter(tag)}


def _runtime_keys(root: ET.Element) -> set[str]:
    return _keys(root, "depend", "exec_depend")


def test_format_name_version_and_build_type() -> None:
    root = _manifest()
    assert root.tag == "package" and root.get("format") == "3"
    assert root.findtext("name") == PACKAGE
    assert root.findtext("license") == "Apache-2.0"
    assert root.find("export/build_type").text == "ament_python"
    assert "ament_python" in _keys(root, "buildtool_depend")
    version = root.findtext("version")
    setup_py = (REPO_ROOT / "setup.py").read_text(encoding="utf-8")
    assert re.search(rf'version="{re.escape(version)}"', setup_py), (
        "setup.py version != package.xml"
    )
    init = (REPO_ROOT / PACKAGE / "__init__.py").read_text(encoding="utf-8")
    assert f'__version__ = "{version}"' in init, "__init__.__version__ != package.xml"


def test_declares_the_runtime_and_test_dependencies() -> None:
    root = _manifest()
    missing = REQUIRED_EXEC_DEPENDS - _runtime_keys(root)
    assert not missing, f"package.xml lacks <exec_depend> for {sorted(missing)}"
    assert "python3-pytest" in _keys(root, "test_depend", "depend")


def _imports(path: Path) -> set[str]:
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    names: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names |= {alias.name.split(".")[0] for alias in node.names}
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names.add(node.module.split(".")[0])
    return names


def _top_level_imports(path: Path) -> set[str]:
    """Modules imported at a module's top level (not inside a function)."""
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    names: set[str] = set()
    for node in tree.body:
        if isinstance(node, ast.Import):
            names |= {alias.name.split(".")[0] for alias in node.names}
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names.add(node.module.split(".")[0])
    return names


def test_desktop_only_modules_are_the_fleet_extra() -> None:
    setup_py = (REPO_ROOT / "setup.py").read_text(encoding="utf-8")
    requirements = (REPO_ROOT / "requirements.txt").read_text(encoding="utf-8")
    fleet = re.search(r'"fleet": \[(.*)\],', setup_py)
    assert fleet is not None, 'setup.py has no "fleet" extra'
    for module in DESKTOP_ONLY:
        assert f'"{module}' in fleet.group(1), module
        assert re.search(rf"^{module}==", requirements, re.M), module


def _package_sources() -> list[Path]:
    return [*(REPO_ROOT / PACKAGE).rglob("*.py"), *(REPO_ROOT / "launch").glob("*.py")]


def test_every_import_is_a_declared_dependency() -> None:
    declared = _runtime_keys(_manifest())
    stdlib = set(sys.stdlib_module_names) | {"__future__"}
    problems = []
    for path in _package_sources():
        rel = path.relative_to(REPO_ROOT)
        for module in sorted(_imports(path) - stdlib - {PACKAGE}):
            if module in DESKTOP_ONLY:
                home = REPO_ROOT / PACKAGE / DESKTOP_ONLY[module]
                if path != home or module in _top_level_imports(path):
                    problems.append(
                        f"{rel} imports {module!r}: desktop only, lazily from "
                        f"{DESKTOP_ONLY[module]} (DESKTOP_ONLY)"
                    )
                continue
            key = ROSDEP_KEY.get(module)
            if key is None:
                problems.append(
                    f"{rel} imports {module!r}: add its rosdep key to ROSDEP_KEY in "
                    f"test/packaging/test_package_manifest.py and an <exec_depend> to package.xml"
                )
            elif key not in declared:
                problems.append(f"{rel} imports {module!r}: add <exec_depend>{key}</exec_depend>")
    assert not problems, "\n".join(problems)


def test_the_scan_sees_the_third_party_imports() -> None:
    """Guard the scanner itself: the core's known third-party imports are found."""
    found = set().union(*(_imports(p) for p in _package_sources()))
    assert "numpy" in found


def test_local_rosdep_file_defines_the_missing_keys() -> None:
    rules = yaml.safe_load((REPO_ROOT / "rosdep" / "soc_estimator_ros.yaml").read_text())
    declared = _runtime_keys(_manifest())
    for key in LOCAL_ROSDEP_KEYS:
        assert key in declared, key
        for os_name in ("debian", "ubuntu"):
            assert rules[key][os_name]["pip"]["packages"], (key, os_name)
