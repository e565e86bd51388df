"""Test-wide set-up: DDS stays on loopback, with a ROS_DOMAIN_ID of this test run's own.

The environment is set at import time, before any test module can import rclpy. Parallel runs
on one machine (and the pytest-xdist workers of one run) get different domain ids, so their
nodes never hear each other; ``SOC_TEST_ROS_DOMAIN_ID`` pins the id when needed.

Bags are read once per test run: ``read_battery_bag`` (rosbags deserializes each message in
Python, 4 s for a 100 000-sample bag) keeps what it read of a bag in a directory the run's
workers share, and a later read of the same unchanged bag, with the same topics, in any worker,
loads that (a fresh copy each time). The first read of every bag is the reader's own; a read
that fails is never kept. ``SOC_TEST_BAG_CACHE=off`` reads every time.
"""

from __future__ import annotations

import functools
import hashlib
import importlib.util
import os
import pickle
import shutil
import sys
import tempfile
import zlib
from pathlib import Path
from types import ModuleType
from typing import Any

import numpy as np
import pytest

import soc_estimator_ros.recordings as _recordings
import soc_estimator_ros.recordings.bags as _bags
from soc_estimator_ros.series import BatterySeries

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


#: The xdist group of the tests that read :func:`hybrid_on_field_run` (``--dist loadgroup`` in
#: scripts/test.sh runs a group on one worker, so each run is computed once per suite).
HYBRID_FIELD_RUNS = pytest.mark.xdist_group("hybrid_field_runs")


@functools.cache
def hybrid_on_field_run(name: str) -> tuple[BatterySeries, np.ndarray, np.ndarray, Any]:
    """The default estimator on a whole bundled field run from its reference start, through
    the tracker (the node's path; no runtime predictions): the recording, the SoC and the
    low-battery level at every sample, and the level thresholds. Shared by test_accuracy and
    test_levels_field_runs."""
    from soc_estimator_ros.params import load_battery_params  # noqa: PLC0415
    from soc_estimator_ros.replay.run import battery_file_for, tracker_config  # noqa: PLC0415
    from soc_estimator_ros.tracking import GateConfig, Sample, Tracker  # noqa: PLC0415

    series = _recordings.read_recording(bag_path(name))
    battery = load_battery_params(battery_file_for(series))
    tracker = Tracker(
        battery,
        GateConfig.from_limits(battery.limits),
        tracker_config(series, "hybrid", "ref", runtime=False),
    )
    n = len(series)
    soc = np.full(n, np.nan)
    level = np.zeros(n, dtype=int)
    for k in range(n):
        r = tracker.process(
            Sample(
                int(series.stamp_ns[k]),
                float(series.current_a[k]),
                float(series.voltage_v[k]),
                float(series.temperature_c[k]),
            )
        )
        assert r.estimate is not None, (name, k, r.verdict)
        soc[k] = r.estimate.soc
        level[k] = int(tracker.runtime.level)
    return series, soc, level, tracker.runtime.thresholds


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


# -- bags read once per run (module docstring) -------------------------------------------------
_BAG_CACHE_ENV = "SOC_TEST_BAG_CACHE"
_read_battery_bag = _bags.read_battery_bag


def pytest_configure(config: pytest.Config) -> None:
    """The controller (or a run without xdist) makes the shared directory; the workers it
    starts afterwards inherit its path in the environment."""
    if os.environ.get(_BAG_CACHE_ENV) or hasattr(config, "workerinput"):
        return
    path = tempfile.mkdtemp(prefix="soc-test-bags-")
    os.environ[_BAG_CACHE_ENV] = path
    config.stash[_cache_dir_key] = path


def pytest_unconfigure(config: pytest.Config) -> None:
    path = config.stash.get(_cache_dir_key, None)
    if path is not None:
        shutil.rmtree(path, ignore_errors=True)
        os.environ.pop(_BAG_CACHE_ENV, None)


_cache_dir_key = pytest.StashKey[str]()


def _read_battery_bag_once(
    path: Path | str,
    state_topic: str = _bags.STATE_TOPIC,
    reference_topic: str | None = _bags.REFERENCE_TOPIC,
    max_samples: int | None = None,
) -> _recordings.BatterySeries:
    """``read_battery_bag``, its result kept per (bag files' names, sizes, mtimes; topics).
    A head (``max_samples``) is cut from a kept whole bag if there is one, else read alone
    (and not kept)."""
    cache = os.environ.get(_BAG_CACHE_ENV, "off")
    bag = Path(path)
    if cache == "off" or not bag.is_dir():
        return _read_battery_bag(path, state_topic, reference_topic, max_samples)
    files = sorted((f.name, f.stat().st_size, f.stat().st_mtime_ns) for f in bag.iterdir())
    key = repr((str(bag.resolve()), state_topic, reference_topic, files))
    kept = Path(cache) / (hashlib.sha256(key.encode()).hexdigest() + ".pickle")
    try:
        whole = pickle.loads(kept.read_bytes())
        return whole if max_samples is None else whole.window(0, max_samples)
    except (FileNotFoundError, EOFError, pickle.UnpicklingError):
        pass
    if max_samples is not None:
        return _read_battery_bag(path, state_topic, reference_topic, max_samples)
    series = _read_battery_bag(path, state_topic, reference_topic)
    fd, tmp = tempfile.mkstemp(dir=cache, suffix=".tmp")
    with os.fdopen(fd, "wb") as fh:
        pickle.dump(series, fh, protocol=pickle.HIGHEST_PROTOCOL)
    os.replace(tmp, kept)  # atomic: a worker reading it meanwhile sees all or nothing
    return series


# Both names: read_recording looks the package's up at each call; test modules import either.
_bags.read_battery_bag = _read_battery_bag_once
_recordings.read_battery_bag = _read_battery_bag_once
