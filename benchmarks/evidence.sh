#!/usr/bin/env bash
# The issue-11 evidence sweeps, in the order they were run. Every step resumes: re-running this
# script skips finished runs and continues unfinished ones from their last checkpoint.
#
#   bash benchmarks/evidence.sh            # from the repository root, svrpo installed
#   SB3_PYTHON=/work/sb3venv/bin/python bash benchmarks/evidence.sh   # with the sb3-contrib anchor
#
# Layout of work, the same for every method so wall-clock compares like with like: two training
# processes at a time on the two cores, each with one sampling worker of 16 environments and one
# torch thread.
set -euo pipefail
ROOT=${ROOT:-runs}
SVRPO=${SVRPO:-svrpo}  # e.g. "python -m svrpo" to run a frozen checkout on PYTHONPATH
COMMON="--root $ROOT --num_workers 1 --envs_per_worker 16 --torch_threads 1"

# 1. The modern scale's decisive pair, next to the outside anchor (sb3-contrib's own TRPO,
#    separate virtual environment, see benchmarks/vs_sb3.py) on the other core.
if [[ -n "${SB3_PYTHON:-}" ]]; then
  "$SB3_PYTHON" benchmarks/vs_sb3.py --libraries sb3-contrib --steps 1000000 --torch-threads 1 \
    --envs Hopper-v5 Walker2d-v5 --seeds 0 1 2 --out benchmarks/results/sb3_anchor_1M.json &
  $SVRPO sweep figure1 --scale modern --tasks Hopper-v5,Walker2d-v5 --jobs 1 $COMMON
  wait
else
  $SVRPO sweep figure1 --scale modern --tasks Hopper-v5,Walker2d-v5 --jobs 2 $COMMON
fi

# 2. SARAH and STORM next to SVRG and TRPO (issue 13), then the paper's ablations, at laptop
#    scale (the svrpo and trpo runs are shared with figure1's).
$SVRPO sweep estimators --scale laptop --jobs 2 $COMMON
$SVRPO sweep figure2 --scale laptop --jobs 2 $COMMON
$SVRPO sweep figure3 --scale laptop --jobs 2 $COMMON

# 3. Figure 1 at laptop scale on all six tasks, then at the modern scale on the other four.
$SVRPO sweep figure1 --scale laptop --jobs 2 $COMMON
$SVRPO sweep figure1 --scale modern --jobs 2 $COMMON
