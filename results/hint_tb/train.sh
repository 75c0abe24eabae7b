#!/bin/bash
# Issue 17: the hint network (results/hint/hint_checkpoint.pt) fine-tuned with team-beam's move
# (light search, policies.infer.tokens.HINT_BEAM) as its hint instead of coordinated frontier's
# moves; the recipe of results/hint (seed 53). Resumes where it stopped.
cd "$(dirname "$0")/../.."
if [ -f runs/hint_tb/checkpoint.pt ]; then
  exec .venv/bin/swarm train --resume --out runs/hint_tb --epochs 7 --workers 2
fi
exec .venv/bin/swarm train --policy commattn --init results/hint/hint_checkpoint.pt \
  --hint-planner team-beam --out runs/hint_tb --epochs 7 --updates 50 --batch 192 --lr 0.0005 \
  --workers 2 --threads 1 --gamma 0.9 --curriculum-step 0 --val-episodes 192 --seed 53
