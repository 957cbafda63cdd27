#!/usr/bin/env bash
# Step 6 of the anchor-gap diagnosis (PROTOCOL.md section 11): every known difference set to
# sb3-contrib's, Ant-v5 then Swimmer-v5, seeds 0-2 each, 1,001,472 steps. Resumable.
#   bash results/ant-anchor-gap/run_closest.sh [ROOT] [JOBS]   # default runs-closest/, 1 at a time
set -euo pipefail
ROOT=${1:-runs-closest}
for task in ant swimmer; do
  svrpo sweep "$(dirname "$0")/specs/closest-$task.yaml" --root "$ROOT" --jobs "${2:-1}" \
    --num_workers 1 --torch_threads 1
done
