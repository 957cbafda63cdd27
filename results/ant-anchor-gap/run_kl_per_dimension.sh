#!/usr/bin/env bash
# Step 5 of the anchor-gap diagnosis (PROTOCOL.md section 10): our trpo with sb3-contrib's
# effective trust region (max_kl and cg_damping times the action dimension), Ant-v5 then
# Swimmer-v5, seeds 0-4 each, 1,001,472 steps. Resumable.
#   bash results/ant-anchor-gap/run_kl_per_dimension.sh [ROOT] [JOBS]   # default runs-kl/, 1 at a time
set -euo pipefail
ROOT=${1:-runs-kl}
for task in ant swimmer; do
  svrpo sweep "$(dirname "$0")/specs/kl-per-dimension-$task.yaml" --root "$ROOT" --jobs "${2:-1}" \
    --num_workers 1 --envs_per_worker 16 --torch_threads 1
done
