#!/usr/bin/env bash
# Copy the finished calls of a measurement root into the repository (PROTOCOL.md section 9):
#   bash results/gradient-error/collect.sh /work/ge-root
# steps.csv, summary.json, time.txt and stdout.txt of every finished call (one with its
# summary.json; calls in progress are OUT.tmp folders and are left), the figure of the 100%
# point's calls only, and the 25% policies' row check. Re-running copies what is new.
set -euo pipefail
ROOT=${1:?usage: collect.sh ROOT [DEST]}
DEST=${2:-$(cd "$(dirname "$0")" && pwd)}
cd "$ROOT/raw"
count=0
for call in */seed*/*/*; do
  case $call in *.tmp) continue ;; esac
  [ -s "$call/summary.json" ] || continue
  mkdir -p "$DEST/raw/$call"
  cp "$call/steps.csv" "$call/summary.json" "$call/time.txt" "$call/stdout.txt" "$DEST/raw/$call/"
  case $call in */100/*) cp "$call/gradient_error.png" "$DEST/raw/$call/" ;; esac
  count=$((count + 1))
done
if [ -s "$ROOT/policies/check.txt" ]; then
  mkdir -p "$DEST/policies" && cp "$ROOT/policies/check.txt" "$DEST/policies/"
fi
echo "$count finished calls under $DEST/raw"
