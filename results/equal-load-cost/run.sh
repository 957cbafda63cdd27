#!/usr/bin/env bash
# The equal-load cost measurement (PROTOCOL.md). Resumable: re-running skips finished runs.
#   bash results/equal-load-cost/run.sh [ROOT]     # default runs-cost/
set -euo pipefail
ROOT=${1:-runs-cost}
svrpo sweep "$(dirname "$0")/spec.yaml" --root "$ROOT" --jobs 2 \
  --num_workers 1 --envs_per_worker 16 --torch_threads 1
