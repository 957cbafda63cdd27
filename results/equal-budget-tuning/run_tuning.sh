#!/usr/bin/env bash
# Equal-budget tuning (PROTOCOL.md): the three studies advance one trial at a time in turn
# (trpo, svrpo, stormpg, then the next trial of each), each trial's six runs two at a time, so
# the studies share the machine's load. Resumable: re-running finishes an interrupted trial
# from its runs' checkpoints and never redoes a finished one.
#   bash results/equal-budget-tuning/run_tuning.sh [ROOT]     # default tune/; JOBS (default 2)
set -euo pipefail
HERE=$(cd "$(dirname "$0")" && pwd)
ROOT=${1:-tune}
JOBS=${JOBS:-2}
TRIALS=20
for trial in $(seq 1 "$TRIALS"); do
  for study in trpo svrpo stormpg; do
    svrpo tune "$HERE/$study.yaml" --root "$ROOT" --trials "$trial" --jobs "$JOBS" --no-progress
  done
done
