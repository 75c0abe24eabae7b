#!/usr/bin/env bash
# Fig. 9's vision checkpoints, the shipped stage-1 schedule (12 x 100 updates of 96 episodes).
set -u
cd "$(dirname "$0")/../.."
for pv in commattn:3 commnet:3 commattn:7 commnet:7 commattn:9 commnet:9; do
  p=${pv%%:*}; v=${pv##*:}; out=results/fig9_vision/${p}_v${v}
  flags=(--policy "$p" --vision "$v" --epochs 12 --updates 100 --batch 96 --threads 1 --gamma 0.9 --val-episodes 96 --seed 0 --out "$out")
  if [ -f "$out/checkpoint.pt" ]; then .venv/bin/swarm train "${flags[@]}" --resume; else .venv/bin/swarm train "${flags[@]}"; fi
done
