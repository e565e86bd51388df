"""The estimation core imports no ROS module: every core module loads with ROS unimportable.

The modules are discovered with pkgutil, so a new module is covered without touching this test.
Only the thin ROS adapters (``node/ros_node.py``, ``node/ros_messages.py``, ``replay/live.py``
which drives the node, launch files) may import rclpy and message packages at import time.
"""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap
from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parents[2]
PACKAGE_DIR = REPO_ROOT / "soc_estimator_ros"

# Top-level names made unimportable (with all their submodules), plus every ``rosidl_*``.
BLOCKED = [
    "rclpy",
    "rcl_interfaces",
    "builtin_interfaces",
    "sensor_msgs",
    "std_msgs",
    "diagnostic_msgs",
    "std_srvs",
    "rosgraph_msgs",
    "launch",
    "launch_ros",
]
BLOCKED_PREFIXES = ["rosidl_"]
# The ROS adapters: allowed to import ROS, so not imported here.
ADAPTERS = [
    "soc_estimator_ros.node.ros_node",
    "soc_estimator_ros.node.ros_messages",
    "soc_estimator_ros.replay.live",
]
ADAPTER_SUBSTRINGS = ["launch"]
# Core parts that must be among the imported modules whenever they exist in the tree.
CORE_PARTS = [
    "units",
    "models",
    "params",
    "estimators",
    "identification",
    "tracking",
    "runtime",
    "recordings",
    "resources",
    "batch",
]

SCRIPT = textwrap.dedent(
    """
    import importlib, importlib.abc, json, pkgutil, sys

    BLOCKED = set({blocked!r})
    PREFIXES = tuple({prefixes!r})
    ADAPTERS = set({adapters!r})
    ADAPTER_SUBSTRINGS = {adapter_substrings!r}

    def blocked(name):
        top = name.split(".")[0]
        return top in BLOCKED or top.startswith(PREFIXES)

    class BlockRos(importlib.abc.MetaPathFinder):
        def find_spec(self, name, path=None, target=None):
            if blocked(name):
                raise ImportError(f"{{name}} is blocked: the core must not import ROS")
            return None

    sys.path.insert(0, {repo!r})
    sys.meta_path.insert(0, BlockRos())
    try:
        import rclpy  # noqa: F401
    except ImportError:
        pass
    else:
        raise SystemExit("the import blocker does not work")

    import soc_estimator_ros

    def fail(name):
        raise  # a subpackage that cannot be imported fails the test, not silently skipped

    def is_adapter(name):
        return name in ADAPTERS or any(s in name.rsplit(".", 1)[-1] for s in ADAPTER_SUBSTRINGS)

    names = sorted(
        m.name
        for m in pkgutil.walk_packages(
            soc_estimator_ros.__path__, "soc_estimator_ros.", onerror=fail
        )
        if not is_adapter(m.name)
    )
    for name in names:
        importlib.import_module(name)
    leaked = sorted(m for m in sys.modules if blocked(m))
    print(json.dumps({{"imported": names, "leaked": leaked,
                      "package": soc_estimator_ros.__file__}}))
    """
)


def _run_core_imports() -> dict:
    code = SCRIPT.format(
        blocked=BLOCKED,
        prefixes=BLOCKED_PREFIXES,
        adapters=ADAPTERS,
        adapter_substrings=ADAPTER_SUBSTRINGS,
        repo=str(REPO_ROOT),
    )
    out = subprocess.run(
        [sys.executable, "-c", code],
        cwd=REPO_ROOT,
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
    )
    assert out.returncode == 0, f"core import with ROS blocked failed:\n{out.stderr[-4000:]}"
    return json.loads(out.stdout.strip().splitlines()[-1])


def _exists(part: str) -> bool:
    return (PACKAGE_DIR / f"{part}.py").is_file() or (PACKAGE_DIR / part / "__init__.py").is_file()


def test_core_imports_without_ros() -> None:
    result = _run_core_imports()
    imported = set(result["imported"])
    assert Path(result["package"]).resolve().is_relative_to(PACKAGE_DIR)
    assert "soc_estimator_ros.units" in imported
    for part in CORE_PARTS:
        if _exists(part):
            assert f"soc_estimator_ros.{part}" in imported, part
    # Every module file of the tree except the adapters was discovered and imported.
    on_disk = {
        ".".join(p.relative_to(REPO_ROOT).with_suffix("").parts).removesuffix(".__init__")
        for p in PACKAGE_DIR.rglob("*.py")
    }
    expected = {
        m
        for m in on_disk - {"soc_estimator_ros"} - set(ADAPTERS)
        if not any(s in m.rsplit(".", 1)[-1] for s in ADAPTER_SUBSTRINGS)
    }
    assert expected <= imported, sorted(expected - imported)
    assert result["leaked"] == [], f"ROS modules in sys.modules after the core: {result['leaked']}"
