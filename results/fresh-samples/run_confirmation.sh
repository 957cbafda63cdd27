#!/usr/bin/env bash
# Confirmation runs (PROTOCOL.md section 3) from the specs benchmarks/screening_report.py
# --write-confirmation wrote into confirmation/ after the screening's decision. Resumable:
# re-running skips finished runs and resumes unfinished ones. Seed-major across the specs (seed
# 100 of every configuration, then 101, ...), so the configurations train side by side at equal
# load, one run per core.
#   bash results/EXPERIMENT/run_confirmation.sh [ROOT]     # default runs/
set -euo pipefail
ROOT=${1:-runs}
DIR=$(dirname "$0")/confirmation
shopt -s nullglob
SPECS=("$DIR"/*.yaml)
if [ ${#SPECS[@]} -eq 0 ]; then
  echo "no confirmation specs in $DIR: run benchmarks/screening_report.py --write-confirmation first" >&2
  exit 2
fi
for seed in $(seq 100 109); do
  for spec in "${SPECS[@]}"; do
    svrpo sweep "$spec" --seeds "$seed" --root "$ROOT" --jobs 2 \
      --num_workers 1 --envs_per_worker 16 --torch_threads 1
  done
done
