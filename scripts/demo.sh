#!/usr/bin/env bash
# The README's main command: set up .venv if needed, then replay the bundled bags through the
# estimators and print the comparison; plots go to demo_out/ (DEMO_OUT overrides).
# Extra arguments go to soc_replay.
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$ROOT"
./scripts/bootstrap.sh

# DDS stays on this machine, in a domain of its own.
export ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST
export ROS_DOMAIN_ID="${ROS_DOMAIN_ID:-57}"
export MPLBACKEND=Agg
OUT="${DEMO_OUT:-$ROOT/demo_out}"
mkdir -p "$OUT"

# The demo: every estimator on one SLA and one LFP field run, one table, one plot per bag.
.venv/bin/soc_replay bags/sla_field_run_1_full_rest bags/lfp_field_run_1_full_rest --all --plot-dir "$OUT" "$@"
