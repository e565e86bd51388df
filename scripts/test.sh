#!/usr/bin/env bash
# The README's test command: set up .venv if needed, lint (ruff), type-check (mypy), then run the
# whole test suite.
# Extra arguments go to pytest (e.g. ./scripts/test.sh -k colcon -n 0).
# SOC_TEST_JOBS sets the number of pytest-xdist workers (default 2; 0 = no workers).
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$ROOT"
./scripts/bootstrap.sh

# DDS stays on this machine; test/conftest.py gives each run its own ROS_DOMAIN_ID.
export ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST
export MPLBACKEND=Agg

failed=()
echo "test.sh: ruff check ."
.venv/bin/ruff check --no-cache . || failed+=("ruff check")
echo "test.sh: ruff format --check ."
.venv/bin/ruff format --no-cache --check . || failed+=("ruff format --check")
echo "test.sh: mypy"
.venv/bin/mypy || failed+=("mypy")

echo "test.sh: pytest"
status=0
.venv/bin/python -m pytest -p no:cacheprovider -q --durations=10 -n "${SOC_TEST_JOBS:-2}" \
  --dist loadgroup "$@" ||
  status=$?
if [ "$status" -eq 5 ]; then
  failed+=("pytest (no tests ran)")
elif [ "$status" -ne 0 ]; then
  failed+=("pytest (exit $status)")
fi

if [ "${#failed[@]}" -ne 0 ]; then
  printf 'test.sh: FAILED: %s\n' "${failed[@]}" >&2
  exit 1
fi
echo "test.sh: lint and tests passed"
