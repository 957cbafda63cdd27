#!/usr/bin/env bash
# Screening of fresh samples in the inner loop (PROTOCOL.md). Resumable: re-running skips
# finished runs and resumes unfinished ones. Seed-major over the eight configurations, so that
# every configuration's seed k trains beside the others' (equal load), one run per core.
#   bash results/fresh-samples/run_screening.sh [ROOT]     # default runs/
set -euo pipefail
ROOT=${1:-runs}
SPECS=(svrpg-b256 srvrpg-b256 stormpg-b256 svrpg-sgd-b256 svrpg-b512 srvrpg-b512 stormpg-b512 svrpg-sgd-b512)
DIR=$(dirname "$0")/screening
for seeds in 1 2 3; do  # --seeds N runs seeds 0..N-1: each pass adds seed N-1 of every configuration
  for spec in "${SPECS[@]}"; do
    svrpo sweep "$DIR/$spec.yaml" --seeds "$seeds" --root "$ROOT" --jobs 2 \
      --num_workers 1 --envs_per_worker 16 --torch_threads 1
  done
done
