"""The package builds with colcon as on a robot, and `ros2 run` would find every executable.

ros2cli is not installed by the two-command set-up, so this checks what `ros2 run` relies on:
the ament index entry, the share/ files, and each console script declared in setup.py sitting in
lib/soc_estimator_ros/ and starting (``--help``) in the environment ``local_setup.bash`` makes.
Then ``soc_replay`` and ``soc_identify`` run on bundled bags from the install, in a directory
outside the checkout: they must find the bundled battery files under the install's share/.
"""

from __future__ import annotations

import ast
import configparser
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import bag_path

from soc_estimator_ros.params import load_battery_params
from soc_estimator_ros.resources import BUNDLED_FILES

REPO_ROOT = Path(__file__).resolve().parents[2]
PACKAGE = "soc_estimator_ros"
COLCON = Path(sys.executable).with_name("colcon")
# What an ament_python package needs to build; everything else (bags, tests, .venv) stays out.
SOURCES = ["package.xml", "setup.py", "setup.cfg", "resource", "config", "launch", PACKAGE]

pytestmark = pytest.mark.slow


def declared_console_scripts() -> list[str]:
    """Names of the console scripts setup.py declares (its CONSOLE_SCRIPTS list)."""
    tree = ast.parse((REPO_ROOT / "setup.py").read_text(encoding="utf-8"))
    for node in ast.walk(tree):
        if isinstance(node, ast.Assign) and any(
            isinstance(t, ast.Name) and t.id == "CONSOLE_SCRIPTS" for t in node.targets
        ):
            entries = ast.literal_eval(node.value)
            return [entry.split("=")[0].strip() for entry in entries]
    raise AssertionError("setup.py must keep its console scripts in one CONSOLE_SCRIPTS list")


@pytest.fixture(scope="module")
def workspace(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A colcon workspace with a copy of the package, built; returns the workspace root."""
    if not COLCON.exists():
        pytest.fail(f"colcon is not installed next to {sys.executable} (requirements-test.txt)")
    ws = tmp_path_factory.mktemp("colcon_ws")
    src = ws / "src" / PACKAGE
    src.mkdir(parents=True)
    ignore = shutil.ignore_patterns("__pycache__", "*.pyc", "*.egg-info")
    for name in SOURCES:
        path = REPO_ROOT / name
        if path.is_dir():
            shutil.copytree(path, src / name, ignore=ignore)
        elif path.exists():
            shutil.copy2(path, src / name)
    env = dict(os.environ, COLCON_HOME=str(ws / "colcon_home"), PYTHONDONTWRITEBYTECODE="1")
    cmd = [
        str(COLCON),
        "--log-base",
        str(ws / "log"),
        "build",
        "--base-paths",
        str(ws / "src"),
        "--build-base",
        str(ws / "build"),
        "--install-base",
        str(ws / "install"),
        "--packages-select",
        PACKAGE,
        "--event-handlers",
        "console_cohesion+",
    ]
    out = subprocess.run(
        cmd, cwd=ws, env=env, capture_output=True, text=True, timeout=240, check=False
    )
    assert out.returncode == 0, f"colcon build failed:\n{out.stdout[-4000:]}\n{out.stderr[-4000:]}"
    return ws


def _run_in_install(
    ws: Path, command: str, cwd: Path | None = None
) -> subprocess.CompletedProcess[str]:
    """Run a shell command after sourcing install/local_setup.bash, as a robot's shell would.

    The checkout is not on PYTHONPATH and ``cwd`` (default: the workspace) is outside it.
    """
    script = f'source "{ws}/install/local_setup.bash" && {command}'
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "AMENT_PREFIX_PATH")}
    return subprocess.run(
        ["bash", "-c", script],
        cwd=cwd or ws,
        env=env,
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )


def _installed_config(ws: Path) -> Path:
    return ws / "install" / PACKAGE / "share" / PACKAGE / "config"


def _assert_no_checkout_config(text: str) -> None:
    checkout_config = str(REPO_ROOT / "config")
    assert checkout_config not in text, f"the checkout's {checkout_config} was used:\n{text}"


def test_setup_declares_console_scripts() -> None:
    assert "soc_replay" in declared_console_scripts()


def test_setup_cfg_puts_scripts_where_ros2_run_looks() -> None:
    cfg = configparser.ConfigParser(interpolation=None)
    cfg.read(REPO_ROOT / "setup.cfg")
    assert cfg["develop"]["script_dir"] == f"$base/lib/{PACKAGE}"
    assert cfg["install"]["install_scripts"] == f"$base/lib/{PACKAGE}"


def test_ament_index_and_share_files(workspace: Path) -> None:
    install = workspace / "install" / PACKAGE
    marker = install / "share/ament_index/resource_index/packages" / PACKAGE
    assert marker.is_file(), marker
    share = install / "share" / PACKAGE
    assert (share / "package.xml").read_bytes() == (REPO_ROOT / "package.xml").read_bytes()
    configs = sorted(p.name for p in (REPO_ROOT / "config").glob("*.yaml"))
    assert configs, "config/ holds the battery parameter files"
    for name in configs:
        assert (share / "config" / name).is_file(), name
    for launch_file in (REPO_ROOT / "launch").glob("*.launch.py"):
        assert (share / "launch" / launch_file.name).is_file(), launch_file.name


def test_installed_package_is_the_built_copy(workspace: Path) -> None:
    code = f"import {PACKAGE}; print({PACKAGE}.__file__)"
    out = _run_in_install(workspace, f'"{sys.executable}" -c "{code}"')
    assert out.returncode == 0, out.stderr
    assert str(workspace / "install") in out.stdout, out.stdout


def test_entry_points_match_setup_py(workspace: Path) -> None:
    site = workspace / "install" / PACKAGE / "lib"
    (entry_points,) = site.glob(f"python3*/site-packages/{PACKAGE}-*.egg-info/entry_points.txt")
    cfg = configparser.ConfigParser()
    cfg.read(entry_points)
    assert sorted(cfg["console_scripts"]) == sorted(declared_console_scripts())


@pytest.mark.parametrize("script", declared_console_scripts())
def test_console_script_runs_from_lib(workspace: Path, script: str) -> None:
    exe = workspace / "install" / PACKAGE / "lib" / PACKAGE / script
    assert exe.is_file(), f"{exe} missing: `ros2 run {PACKAGE} {script}` would not find it"
    assert os.access(exe, os.X_OK), f"{exe} is not executable"
    out = _run_in_install(workspace, f'"{exe}" --help')
    assert out.returncode == 0, f"{script} --help exited {out.returncode}:\n{out.stderr[-3000:]}"
    assert "usage" in out.stdout.lower(), out.stdout[-2000:]


def test_installed_config_dir_is_the_share_copy(workspace: Path, tmp_path: Path) -> None:
    code = "from soc_estimator_ros.resources import config_dir; print(config_dir())"
    out = _run_in_install(workspace, f'"{sys.executable}" -c "{code}"', cwd=tmp_path)
    assert out.returncode == 0, out.stderr[-3000:]
    found = Path(out.stdout.strip().splitlines()[-1])
    assert found.resolve() == _installed_config(workspace).resolve(), found


def test_installed_soc_replay_runs_a_bag(workspace: Path, tmp_path: Path) -> None:
    bag = bag_path("sla_field_run_2_partial")
    exe = workspace / "install" / PACKAGE / "lib" / PACKAGE / "soc_replay"
    out = _run_in_install(workspace, f'"{exe}" "{bag}" --estimator coulomb', cwd=tmp_path)
    assert out.returncode == 0, f"soc_replay exited {out.returncode}:\n{out.stderr[-3000:]}"
    header = out.stdout.splitlines()[0].split()
    assert header[:3] == ["input", "estimator", "MAE%"], out.stdout[-2000:]
    assert any(line.split()[:2] == [bag.name, "coulomb"] for line in out.stdout.splitlines())
    _assert_no_checkout_config(out.stdout + out.stderr)


def test_installed_soc_identify_uses_the_bundled_template(workspace: Path, tmp_path: Path) -> None:
    bag = bag_path("sla_pulse_test")
    exe = workspace / "install" / PACKAGE / "lib" / PACKAGE / "soc_identify"
    output = tmp_path / "id.yaml"
    command = f'"{exe}" "{bag}" --chemistry sla --output "{output}"'
    out = _run_in_install(workspace, command, cwd=tmp_path)
    assert out.returncode == 0, f"soc_identify exited {out.returncode}:\n{out.stderr[-3000:]}"
    _assert_no_checkout_config(out.stdout + out.stderr + output.read_text(encoding="utf-8"))
    params = load_battery_params(output)
    # Not identified, so taken from the default template (the bundled SLA file).
    template = load_battery_params(_installed_config(workspace) / BUNDLED_FILES["sla"])
    assert params.name == template.name
