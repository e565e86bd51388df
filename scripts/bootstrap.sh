#!/usr/bin/env bash
# Set up .venv: Python >= 3.10 virtual environment, pinned dependencies from PyPI (including the
# ROS 2 Jazzy wheels), and this package installed editable. Called by demo.sh and test.sh.
#
# Re-runs are fast: pip runs only when requirements*.txt, setup.py, setup.cfg, this script or the
# interpreter changed (a stamp in .venv records their sha256). PYTHON=/path/to/python3 picks
# the interpreter; SOC_BOOTSTRAP_FORCE=1 reinstalls.
#
# Run it (don't source it): it exits on the first error.
set -euo pipefail

ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
VENV="$ROOT/.venv"
PY="${PYTHON:-python3}"
PIP_VERSION="26.3"
STAMP="$VENV/.soc_estimator_ros.stamp"

die() {
  echo "bootstrap: error: $*" >&2
  exit 1
}

command -v "$PY" >/dev/null 2>&1 || die "'$PY' not found: install Python >= 3.10 (apt-get install python3 python3-venv)"
"$PY" -c 'import sys; sys.exit(sys.version_info < (3, 10))' ||
  die "Python >= 3.10 is required; '$PY' is $("$PY" --version 2>&1)"

# One bootstrap at a time per checkout (demo.sh and test.sh may start together).
if command -v flock >/dev/null 2>&1; then
  LOCK="${TMPDIR:-/tmp}/soc_estimator_ros-bootstrap-$(printf '%s' "$ROOT" | sha256sum | cut -c1-16).lock"
  exec 9>"$LOCK"
  flock 9
fi

# A .venv whose interpreter vanished, or made for another path (moved checkout: its scripts'
# shebangs point elsewhere), is rebuilt from scratch.
if [ -e "$VENV" ]; then
  if ! "$VENV/bin/python" -c 'pass' >/dev/null 2>&1 ||
    { [ -f "$VENV/bin/pip" ] && ! head -n1 "$VENV/bin/pip" | grep -qF "#!$VENV/bin/python"; }; then
    echo "bootstrap: recreating $VENV"
    rm -rf "$VENV"
  fi
fi

if [ ! -x "$VENV/bin/python" ]; then
  "$PY" -m venv "$VENV" >/dev/null ||
    die "'$PY -m venv' failed: install the venv module (Debian/Ubuntu: apt-get install python3-venv)"
fi
"$VENV/bin/python" -c 'import sys; sys.exit(sys.version_info < (3, 10))' ||
  die ".venv uses $("$VENV/bin/python" --version 2>&1); remove .venv and run again with PYTHON=python3.1x"
# colcon must never crawl into the virtual environment.
touch "$VENV/COLCON_IGNORE"

want="$(
  {
    cat "$ROOT/requirements.txt" "$ROOT/requirements-test.txt" "$ROOT/setup.py" "$ROOT/setup.cfg"
    cat "${BASH_SOURCE[0]}"
    "$VENV/bin/python" -c 'import sys; print(sys.version)'
  } | sha256sum | cut -d' ' -f1
)"
if [ "${SOC_BOOTSTRAP_FORCE:-0}" != "1" ] && [ -f "$STAMP" ] && [ "$(cat "$STAMP")" = "$want" ]; then
  exit 0
fi

rm -f "$STAMP"
echo "bootstrap: installing pinned dependencies into .venv (the first run takes a few minutes)"
start=$SECONDS
pip=("$VENV/bin/python" -m pip --quiet --quiet --disable-pip-version-check)
"${pip[@]}" install "pip==$PIP_VERSION" || die "could not install pip $PIP_VERSION"
"${pip[@]}" install -r "$ROOT/requirements.txt" -r "$ROOT/requirements-test.txt" ||
  die "pip could not install requirements.txt / requirements-test.txt"
# The package itself, editable, without touching the pinned set (--no-deps).
"${pip[@]}" install --no-deps --no-build-isolation -e "$ROOT" || die "pip install -e . failed"

"$VENV/bin/python" -c 'import soc_estimator_ros' || die "soc_estimator_ros does not import from .venv"
for exe in soc_replay soc_identify soc_estimator_node colcon ruff mypy pytest; do
  [ -x "$VENV/bin/$exe" ] || die ".venv/bin/$exe is missing after the install"
done
printf '%s\n' "$want" >"$STAMP"
echo "bootstrap: .venv ready ($((SECONDS - start)) s)"
