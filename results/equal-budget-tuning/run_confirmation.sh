#!/usr/bin/env bash
# The confirmation (PROTOCOL.md section 3 and "Confirmation specs and report"): the specs that
# benchmarks/tuning_confirmation.py wrote into confirmation/ from the finished studies, seeds
# 200-209, seed-major: one `svrpo sweep` of every spec per seed (one queue ordered by task, then
# configuration, so the four configurations train side by side at equal load). Each spec holds its
# own execution settings (the tuned ones: one worker of 16 environments and one torch thread, as in
# tuning; the zoo TRPO: its scale's two in-process environments). Resumable: re-running skips
# finished runs and resumes unfinished ones from their checkpoints.
#   bash results/equal-budget-tuning/run_confirmation.sh [ROOT]     # default runs/; JOBS (default 2)
set -euo pipefail
HERE=$(cd "$(dirname "$0")" && pwd)
ROOT=${1:-runs}
JOBS=${JOBS:-2}
shopt -s nullglob
SPECS=("$HERE"/confirmation/*.yaml)
if [ ${#SPECS[@]} -ne 4 ]; then
  echo "expected the 4 confirmation specs in $HERE/confirmation, found ${#SPECS[@]}:" \
       "run python benchmarks/tuning_confirmation.py specs once the three studies have finished" >&2
  exit 2
fi
for seed in $(seq 200 209); do
  # "A-A" is the one seed A: a bare number N would mean N seeds, 0..N-1.
  svrpo sweep "${SPECS[@]}" --seeds "$seed-$seed" --root "$ROOT" --jobs "$JOBS"
done
