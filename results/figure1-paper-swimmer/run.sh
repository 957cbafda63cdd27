#!/usr/bin/env bash
# The paper-scale Swimmer experiment (PROTOCOL.md). Resumable: re-running skips finished runs and
# resumes unfinished ones from their last checkpoint. Seed-major: every preset's seed k before
# any preset's seed k+1.
#   bash results/figure1-paper-swimmer/run.sh [ROOT] [SEEDS]     # default runs/, 5 seeds
set -euo pipefail
ROOT=${1:-runs}
SEEDS=${2:-5}
for seeds in $(seq 1 "$SEEDS"); do  # --seeds 0-(N-1) runs seeds 0..N-1: each pass adds seed N-1
  nice -n 10 svrpo sweep figure1 --scale paper --tasks Swimmer-v5 --seeds "0-$((seeds - 1))" --root "$ROOT" \
    --jobs 1 --num_workers 1 --envs_per_worker 16 --torch_threads 1
done
