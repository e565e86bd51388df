"""Test-wide set-up: DDS stays on loopback, with a ROS_DOMAIN_ID of this test run's own.

The environment is set at import time, before any test module can import rclpy. Parallel runs
on one machine (and the pytest-xdist workers of one run) get different domain ids, so their
nodes never hear each other; ``SOC_TEST_ROS_DOMAIN_ID`` pins the id when needed.
"""

from __future__ import annotations

import importlib.util
import os
import sys
import zlib
from pathlib import Path
from types import ModuleType

import pytest

REPO_ROOT = Path(__file__).resolve().parents[1]
BAGS_DIR = REPO_ROOT / "bags"

# Fast DDS derives its UDP ports from the domain id; 1..101 is safe on every Linux host.
_DOMAIN_MIN, _DOMAIN_MAX = 1, 101


def _test_domain_id() -> int:
    pinned = os.environ.get("SOC_TEST_ROS_DOMAIN_ID")
    if pinned:
        return int(pinned)
    span = _DOMAIN_MAX - _DOMAIN_MIN + 1
    worker = os.environ.get("PYTEST_XDIST_WORKER")  # "gw0", "gw1", ... under pytest-xdist
    if worker is None:
        return _DOMAIN_MIN + os.getpid() % span
    # One base per run (shared by its workers), then consecutive ids, one per worker.
    workers = int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1"))
    run = os.environ.get("PYTEST_XDIST_TESTRUNUID", str(os.getppid()))
    base = zlib.crc32(run.encode()) % max(1, span - workers)
    return _DOMAIN_MIN + (base + int(worker.removeprefix("gw"))) % span


os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
os.environ["ROS_DOMAIN_ID"] = str(_test_domain_id())


@pytest.fixture(scope="session")
def repo_root() -> Path:
    """The repository root (a checkout, not an installed copy)."""
    return REPO_ROOT


@pytest.fixture(scope="session")
def bags_dir() -> Path:
    """The directory of bundled rosbag2 recordings (``bags/<name>/``)."""
    return BAGS_DIR


def bag_path(name: str) -> Path:
    """A bundled bag by name; skips the calling test when that bag is not in the checkout."""
    path = BAGS_DIR / name
    if not (path / "metadata.yaml").is_file():
        pytest.skip(f"bundled bag {name!r} not present in {BAGS_DIR}")
    return path


def load_benchmark(name: str) -> ModuleType:
    """A script of ``benchmarks/`` as a module (they are scripts, not a package); ``name`` is
    its path below ``benchmarks/`` without ``.py`` (``"perf/ukf_floor"``)."""
    path = REPO_ROOT / "benchmarks" / f"{name}.py"
    name = Path(name).name
    spec = importlib.util.spec_from_file_location(name, path)
    assert spec is not None and spec.loader is not None, path
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module  # as an import does: a dataclass there looks its module up
    spec.loader.exec_module(module)
    return module
