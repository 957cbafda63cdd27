#!/usr/bin/env bash
# Step 2 of the Ant anchor-gap diagnosis (PROTOCOL.md): one environment and SB3's initialisation,
# seeds 0-2, 1M steps. Resumable: re-running skips finished runs and resumes unfinished ones.
#   bash results/ant-anchor-gap/run.sh [ROOT] [JOBS]     # default runs-gap/, 1 run at a time
set -euo pipefail
ROOT=${1:-runs-gap}
svrpo sweep "$(dirname "$0")/specs/one-env-orthogonal.yaml" --root "$ROOT" --jobs "${2:-1}" \
  --num_workers 1 --torch_threads 1
