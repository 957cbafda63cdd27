#!/usr/bin/env bash
# The gradient-error measurement of PROTOCOL.md (issue 41), run from the frozen worktree:
#   bash results/gradient-error/run.sh ROOT
# Re-running skips every finished step: a re-trained policy whose run is finished, a call whose
# summary.json exists (each call writes into OUT.tmp and is renamed when done). Order: the nine
# 25% policies, then calls A and B at all 36 policies (the primary measurement), then the
# paper's N = 50,000 on Hopper, then A-all and B-all.
set -euo pipefail
HERE=$(cd "$(dirname "$0")" && pwd)
REPO=$(cd "$HERE/../.." && pwd)
ROOT=$(mkdir -p "${1:-ge-root}" && cd "${1:-ge-root}" && pwd)
JOBS=${JOBS:-2}
R=$(python "$REPO/benchmarks/evidence.py" materialise "$REPO/results/runs" "$ROOT/runs")  # packed sweeps unpacked
export R ROOT
TASKS=(Hopper-v5 Walker2d-v5 HalfCheetah-v5)

retrain() {  # TASK SEED: the 25% policy, 122 iterations of the archived run's config
  local task=$1 k=$2 out="$ROOT/policies/$1/seed$2-25"
  if [ -d "$out" ] && python -c "import sys; from pathlib import Path; from svrpo.rundir.completion import is_finished; sys.exit(0 if is_finished(Path(sys.argv[1])) else 1)" "$out"; then
    return 0
  elif [ -d "$out" ]; then
    svrpo train --resume "$out" --steps 249856 --no-progress || return 1
  else
    svrpo train --preset trpo --scale modern --env "$task" --seed "$k" --steps 249856 \
      --num_workers 1 --envs_per_worker 16 --out "$out" --no-progress || return 1
  fi
}
export -f retrain

call() {  # TASK SEED POINT CALL
  local task=$1 k=$2 point=$3 name=$4 policy flags=()
  local out="$ROOT/raw/$task/seed$k/$point/$name"
  [ -s "$out/summary.json" ] && return 0
  case $point in
    0) policy="$R/figure1-modern/$task/trpo/seed$k/checkpoints/iter_000489.pt"; flags+=(--initial) ;;
    25) policy="$ROOT/policies/$task/seed$k-25" ;;
    50) policy="$R/bt-screen-trpo-d0.01-modern/$task/trpo/seed$k/checkpoints/iter_000245.pt" ;;
    100) policy="$R/figure1-modern/$task/trpo/seed$k/checkpoints/iter_000489.pt" ;;
  esac
  local A=(--estimator full,sgd,svrg,sarah,storm,page --inner_steps 8 --minibatch_size 512)
  local B=(--update-from "$R/bt-confirm-budgeted-sarah-b0.02-modern/$task/svrpo-budgeted/seed104"
           --update-from "$R/bt-confirm-budgeted-sgd-b0.02-modern/$task/svrpo-budgeted/seed104"
           --update-from "$R/bt-screen-budgeted-svrg-b0.02-modern/$task/svrpo-budgeted/seed0"
           --update-from "$R/fs-confirm-stormpg-b256-modern/$task/stormpg/seed100"
           --update-from "$R/fs-confirm-svrpg-sgd-b256-modern/$task/svrpg-sgd/seed100"
           --update-from "$R/fs-screen-svrpg-b256-modern/$task/svrpg/seed0"
           --update-from "$R/fs-screen-srvrpg-b256-modern/$task/srvrpg/seed0")
  local M=(--reference-steps 524288 --parts 64 --seed 0)
  case $name in
    A) flags+=("${A[@]}" "${M[@]}") ;;
    B) flags+=("${B[@]}" "${M[@]}") ;;
    A-all) flags+=("${A[@]}" "${M[@]}" --inner_stop all) ;;
    B-all) flags+=("${B[@]}" "${M[@]}" --inner_stop all) ;;
    N50000) flags+=(--estimator full,sgd,svrg --batch_size 50000 --minibatch_size 5000
                    --inner_steps 50 --fisher_subsample 0.1 --cg_iters 10 --cg_damping 1e-5
                    --backtrack_ratio 0.5 --reference-steps 2097152 --parts 64 --seed 0) ;;
  esac
  rm -rf "$out.tmp" && mkdir -p "$out.tmp"
  /usr/bin/time -f "%U %S %e" -o "$out.tmp/time.txt" \
    svrpo gradient-error "$policy" "${flags[@]}" --out "$out.tmp" > "$out.tmp/stdout.txt" 2>&1 \
    || { echo "failed $task seed$k $point $name: $out.tmp/stdout.txt" >&2; return 1; }
  mv "$out.tmp" "$out"
  echo "done $task seed$k $point $name"
}
export -f call

jobs() {  # the call lines of one phase: POINTS CALLS TASKS
  local task k point name
  for task in $3; do for k in 0 1 2; do for point in $1; do for name in $2; do
    echo "$task $k $point $name"
  done; done; done; done
}

mkdir -p "$ROOT/policies"
for task in "${TASKS[@]}"; do for k in 0 1 2; do echo "$task $k"; done; done \
  | xargs -P "$JOBS" -L 1 bash -c 'retrain "$@"' _
python "$HERE/check_retrained.py" "$ROOT/policies" "$R/figure1-modern" | tee "$ROOT/policies/check.txt"
{ jobs "0 25 50 100" "A B" "${TASKS[*]}"
  jobs "0 25 50 100" "N50000" "Hopper-v5"
  jobs "0 25 50 100" "A-all B-all" "${TASKS[*]}"; } \
  | xargs -P "$JOBS" -L 1 bash -c 'call "$@"' _
echo "all calls done under $ROOT/raw"
