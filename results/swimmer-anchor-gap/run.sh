#!/usr/bin/env bash
# The Swimmer anchor-gap diagnosis (PROTOCOL.md). Resumable.
#   bash results/swimmer-anchor-gap/run.sh [ROOT]     # default runs-gap/
set -euo pipefail
ROOT=${1:-runs-gap}
for spec in "$(dirname "$0")"/specs/*.yaml; do
  svrpo sweep "$spec" --root "$ROOT" --jobs 2 --num_workers 1 --torch_threads 1
done
