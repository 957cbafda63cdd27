#!/usr/bin/env bash
# Screening of the budgeted trust region (PROTOCOL.md). Resumable: re-running skips finished runs
# and resumes unfinished ones. Seed-major over the ten configurations, so that every
# configuration's seed k trains beside the others' (equal load), one run per core.
#   bash results/budgeted-trust-region/run_screening.sh [ROOT]     # default runs/
set -euo pipefail
ROOT=${1:-runs}
SPECS=(trpo-d0.01 trpo-d0.02 trpo-d0.04 svrpo-sampling-d0.04 budgeted-svrg-b0.02 budgeted-sgd-b0.02
       budgeted-sarah-b0.02 budgeted-svrg-b0.04 budgeted-sgd-b0.04 budgeted-sarah-b0.04)
DIR=$(dirname "$0")/screening
for seeds in 1 2 3; do  # --seeds 0-(N-1) runs seeds 0..N-1: each pass adds seed N-1 of every configuration
  for spec in "${SPECS[@]}"; do
    svrpo sweep "$DIR/$spec.yaml" --seeds "0-$((seeds - 1))" --root "$ROOT" --jobs 2 \
      --num_workers 1 --envs_per_worker 16 --torch_threads 1
  done
done
