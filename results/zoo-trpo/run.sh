#!/usr/bin/env bash
# rl-zoo's TRPO reproduced (PROTOCOL.md): both arms as one `svrpo sweep` queue, then rl-zoo's
# evaluation protocol (150 deterministic episodes) on every run's final policy. Resumable: re-running
# skips finished runs, resumes unfinished ones from their checkpoints, skips finished evaluations.
#   bash results/zoo-trpo/run.sh [ROOT]     # default runs/; JOBS=N runs at a time (default 2)
# Outputs: ROOT/zoo-trpo-zoo/, ROOT/zoo-trpo-raw-rewards-zoo/ (runs) and
# ROOT/zoo-trpo-eval150/EXPERIMENT/TASK/seedK.txt (`svrpo evaluate` output).
set -euo pipefail
HERE=$(cd "$(dirname "$0")" && pwd)
ROOT=${1:-runs}
JOBS=${JOBS:-2}
svrpo sweep "$HERE/zoo-trpo.yaml" "$HERE/zoo-trpo-raw-rewards.yaml" --root "$ROOT" --jobs "$JOBS"

evaluate() {  # RUN_DIR: 150 episodes from seeds 5000000..5000149, written atomically
  local run=$1 experiment task seed out
  seed=$(basename "$run"); task=$(basename "$(dirname "$(dirname "$run")")")
  experiment=$(basename "$(dirname "$(dirname "$(dirname "$run")")")")
  out="$EVAL_ROOT/$experiment/$task/$seed.txt"
  [ -s "$out" ] && return 0
  mkdir -p "$(dirname "$out")"
  svrpo evaluate "$run" --episodes 150 --seed 5000000 > "$out.tmp"
  mv "$out.tmp" "$out"
}
export -f evaluate
export EVAL_ROOT="$ROOT/zoo-trpo-eval150"
shopt -s nullglob
RUNS=("$ROOT"/zoo-trpo-zoo/*/trpo/seed* "$ROOT"/zoo-trpo-raw-rewards-zoo/*/trpo/seed*)
if [ ${#RUNS[@]} -ne 60 ]; then
  echo "expected 60 run directories under $ROOT, found ${#RUNS[@]}" >&2
  exit 1
fi
printf '%s\n' "${RUNS[@]}" | xargs -P "$JOBS" -I{} bash -c 'evaluate "$1"' _ {}
