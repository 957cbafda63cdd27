#!/usr/bin/env bash
# Screening of fresh samples in the inner loop (PROTOCOL.md). Resumable: re-running skips
# finished runs and resumes unfinished ones. Seed-major over the eight configurations, so that
# every configuration's seed k trains beside the others' (equal load), one run per core.
#   bash results/fresh-samples/run_screening.sh [ROOT] [SPEC ...]     # default runs/, all eight
# With SPECs, only those configurations (same order, same seeds): two streams of four, each with
# JOBS=1 and its own ROOT, keep both cores busy where one stream's three tasks on two cores would
# leave one idle at the end of every call (PROTOCOL.md, 2026-12-04).
set -euo pipefail
ROOT=${1:-runs}
if [ $# -gt 1 ]; then
  SPECS=("${@:2}")
else
  SPECS=(svrpg-b256 srvrpg-b256 stormpg-b256 svrpg-sgd-b256 svrpg-b512 srvrpg-b512 stormpg-b512 svrpg-sgd-b512)
fi
DIR=$(dirname "$0")/screening
for seeds in 1 2 3; do  # --seeds 0-(N-1) runs seeds 0..N-1: each pass adds seed N-1 of every configuration
  for spec in "${SPECS[@]}"; do
    svrpo sweep "$DIR/$spec.yaml" --seeds "0-$((seeds - 1))" --root "$ROOT" --jobs "${JOBS:-2}" \
      --num_workers 1 --envs_per_worker 16 --torch_threads 1
  done
done
