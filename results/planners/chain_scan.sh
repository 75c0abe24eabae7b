#!/usr/bin/env bash
# `chain-plan`'s search settings on episodes 0-19 of seed 0 (each against `team-beam` on the
# same episodes): a chain head planning from scratch every tick (--cold) at three depths, and
# warm-started from the plan it sent last tick at three. From the repository root.
set -eu
cd "$(dirname "$0")/../.."
out=results/planners/chain_scan
mkdir -p "$out"
for s in "2 16 1 16 --cold" "12 48 0 16 --cold" "24 64 0 16 --cold" \
         "2 16 0 16" "4 32 0 16" "8 48 0 16"; do
  name=$(echo "$s" | tr ' ' '_' | tr -d '-')
  # shellcheck disable=SC2086
  .venv/bin/python results/planners/chain_plan.py 20 "$out/$name.json" $s --only
done
