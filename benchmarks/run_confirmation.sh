#!/usr/bin/env bash
# Confirmation runs of a screen-then-confirm experiment (its PROTOCOL.md, section 3), from the specs
# benchmarks/screening_report.py --write-confirmation wrote into EXPERIMENT_DIR/confirmation/
# after the screening's decision. Resumable: re-running skips finished runs and resumes
# unfinished ones. Seed-major: one `svrpo sweep` of every spec per seed (seed 100 of every
# configuration, then 101, ...), one queue ordered by task, then configuration, so the
# configurations train side by side at equal load, one run per core, and no core idles while
# one configuration's last run finishes alone.
#   bash benchmarks/run_confirmation.sh EXPERIMENT_DIR [ROOT]     # default ROOT runs/
set -euo pipefail
if [ $# -lt 1 ]; then
  echo "usage: bash benchmarks/run_confirmation.sh EXPERIMENT_DIR [ROOT]" >&2
  exit 2
fi
DIR=$1/confirmation
ROOT=${2:-runs}
shopt -s nullglob
SPECS=("$DIR"/*.yaml)
if [ ${#SPECS[@]} -eq 0 ]; then
  echo "no confirmation specs in $DIR: run benchmarks/screening_report.py --write-confirmation first" >&2
  exit 2
fi
for seed in $(seq 100 109); do
  # "A-A" is the one seed A: a bare number N would mean N seeds, 0..N-1.
  svrpo sweep "${SPECS[@]}" --seeds "$seed-$seed" --root "$ROOT" --jobs 2 \
    --num_workers 1 --envs_per_worker 16 --torch_threads 1
done
