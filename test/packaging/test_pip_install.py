"""A plain (non-editable) pip install finds its bundled battery files under <prefix>/share.

The package is installed with ``pip install --prefix`` into a temporary prefix (``data_files``
land in ``<prefix>/share/soc_estimator_ros``), then run with only that prefix's site-packages on
PYTHONPATH and a working directory outside the checkout: ``resources.config_dir()`` must resolve
to the prefix's share/ and ``soc_replay`` must replay a bundled bag.

``--ignore-installed`` matters: without it pip *uninstalls* the copy of soc_estimator_ros the
running environment already has (the editable install of the development venv) before installing
into the prefix. The test checks that the environment's own install is left as it was.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import sysconfig
from pathlib import Path

from conftest import bag_path

REPO_ROOT = Path(__file__).resolve().parents[2]
PACKAGE = "soc_estimator_ros"
# What setup.py needs to build; the copy keeps build/ and *.egg-info out of the checkout.
SOURCES = ["package.xml", "setup.py", "setup.cfg", "resource", "config", "launch", PACKAGE]


def _copy_sources(dest: Path) -> Path:
    dest.mkdir(parents=True)
    ignore = shutil.ignore_patterns("__pycache__", "*.pyc", "*.egg-info")
    for name in SOURCES:
        path = REPO_ROOT / name
        if path.is_dir():
            shutil.copytree(path, dest / name, ignore=ignore)
        elif path.exists():
            shutil.copy2(path, dest / name)
    return dest


def _own_install() -> list[str]:
    """The running environment's install records of the package (must survive the test)."""
    site = Path(sysconfig.get_path("purelib"))
    return sorted(p.name for p in site.glob("*soc_estimator_ros*"))


def _run(args: list[str], cwd: Path, env: dict[str, str]) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        args, cwd=cwd, env=env, capture_output=True, text=True, timeout=240, check=False
    )


def test_pip_prefix_install_finds_its_share_files(tmp_path: Path) -> None:
    bag = bag_path("sla_field_run_2_partial")
    src = _copy_sources(tmp_path / "src")
    prefix = tmp_path / "prefix"
    run_dir = tmp_path / "run"
    run_dir.mkdir()
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "AMENT_PREFIX_PATH")}
    env["PYTHONDONTWRITEBYTECODE"] = "1"

    before = _own_install()
    pip = [sys.executable, "-m", "pip", "install", "--no-deps", "--no-build-isolation"]
    pip += ["--no-index", "--no-cache-dir", "--disable-pip-version-check", "--no-compile"]
    pip += ["--ignore-installed", "--prefix", str(prefix), str(src)]
    out = _run(pip, cwd=tmp_path, env=env)
    assert out.returncode == 0, f"pip install failed:\n{out.stdout[-3000:]}\n{out.stderr[-3000:]}"
    assert _own_install() == before, "pip touched the running environment's install"

    (site,) = {p.parent for p in prefix.glob(f"lib*/python3*/site-packages/{PACKAGE}")}
    share_config = prefix / "share" / PACKAGE / "config"
    assert (share_config / "sla_12v5ah.yaml").is_file(), sorted(prefix.rglob("*.yaml"))
    env["PYTHONPATH"] = str(site)

    code = (
        f"import {PACKAGE}; from {PACKAGE}.resources import config_dir; "
        f"print({PACKAGE}.__file__); print(config_dir())"
    )
    out = _run([sys.executable, "-c", code], cwd=run_dir, env=env)
    assert out.returncode == 0, out.stderr[-3000:]
    module_file, found = out.stdout.strip().splitlines()[-2:]
    assert Path(module_file).resolve().is_relative_to(site.resolve()), (
        f"imported {module_file}, not the prefix copy"
    )
    assert Path(found).resolve() == share_config.resolve(), found

    replay = [sys.executable, "-m", f"{PACKAGE}.replay.cli", str(bag), "--estimator", "coulomb"]
    out = _run(replay, cwd=run_dir, env=env)
    assert out.returncode == 0, f"replay exited {out.returncode}:\n{out.stderr[-3000:]}"
    assert any(line.split()[:2] == [bag.name, "coulomb"] for line in out.stdout.splitlines())
    assert str(REPO_ROOT / "config") not in out.stdout + out.stderr
