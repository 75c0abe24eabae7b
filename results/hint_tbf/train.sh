#!/bin/bash
# Issue 17: the team-beam-hint network (results/hint_tb) fine-tuned with the hint it is best
# with at test time, the full team-beam search (beam 24, two passes: the model fields of
# hint_tb_full_checkpoint.pt), where it was trained on the light one (beam 8, one pass).
# Epochs of 25 updates of 192 (a checkpoint every ~25 min here). Resumes where it stopped.
cd "$(dirname "$0")/../.."
if [ -f runs/hint_tbf/checkpoint.pt ]; then
  exec .venv/bin/swarm train --resume --out runs/hint_tbf --epochs 4 --workers 2
fi
exec .venv/bin/swarm train --policy commattn --init results/hint_tb/hint_tb_full_checkpoint.pt \
  --out runs/hint_tbf --epochs 4 --updates 25 --batch 192 --lr 0.0003 \
  --workers 2 --threads 1 --gamma 0.9 --curriculum-step 0 --val-episodes 192 --seed 61
