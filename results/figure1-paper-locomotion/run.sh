#!/usr/bin/env bash
# The paper-scale locomotion experiment (PROTOCOL.md, issue 53), run from the frozen worktree the
# protocol names. Resumable: re-running skips finished runs and resumes unfinished ones from their
# last checkpoint. Seed-major: every arm's seed k before any arm's seed k+1; two runs at a time.
#   bash results/figure1-paper-locomotion/run.sh ROOT [FIRST_SEED]
# While it runs, the 50% checkpoints of Walker2d svrpo/trpo seeds 0-2 (iteration 250, read by the
# mechanism step, PROTOCOL.md section 9) are copied to ROOT/milestones/ before pruning removes them.
set -euo pipefail
ROOT=${1:?usage: run.sh ROOT [FIRST_SEED]}
FIRST=${2:-0}
HERE="$(cd "$(dirname "$0")" && pwd)"
mkdir -p "$ROOT"

keep_milestones() {
  while true; do
    for preset in svrpo trpo; do
      for seed in 0 1 2; do
        source="$ROOT/paper-locomotion-paper/Walker2d-v5/$preset/seed$seed/checkpoints/iter_000250.pt"
        target="$ROOT/milestones/Walker2d-v5/$preset/seed$seed/iter_000250.pt"
        if [ -f "$source" ] && [ ! -f "$target" ]; then
          mkdir -p "$(dirname "$target")" && cp "$source" "$target.tmp" && mv "$target.tmp" "$target"
        fi
      done
    done
    sleep 15
  done
}
keep_milestones &
keeper=$!
trap 'kill $keeper 2>/dev/null || true' EXIT

for seed in $(seq "$FIRST" 4); do
  specs=("$HERE/primary-25m.yaml" "$HERE/primary-50m.yaml" "$HERE/ablations-swimmer.yaml")
  if [ "$seed" -le 2 ]; then specs+=("$HERE/ablations-walker.yaml"); fi
  nice -n 10 svrpo sweep "${specs[@]}" --seeds "$seed-$seed" --root "$ROOT" --jobs 2
done
