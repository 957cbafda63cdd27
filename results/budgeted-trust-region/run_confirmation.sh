#!/usr/bin/env bash
# Confirmation runs (PROTOCOL.md section 3): benchmarks/run_confirmation.sh on this experiment.
#   bash results/EXPERIMENT/run_confirmation.sh [ROOT]     # default runs/
set -euo pipefail
HERE=$(dirname "$0")
exec bash "$HERE/../../benchmarks/run_confirmation.sh" "$HERE" "$@"
