#!/bin/bash
# Issue 17: the team-beam hint network (results/hint_tb/hint_tb_checkpoint.pt) fine-tuned with
# `chain-plan`'s move as its hint (light search: model hint_beam 8, hint_passes 1 =
# ChainConfig(1, 8, 0, 8)) and a prior of 8 on the hinted move's logit (model hint_prior: it
# starts at the planner's level and learns where to leave it). Resumes where it stopped.
cd "$(dirname "$0")/../.."
if [ -f runs/hint_chain/checkpoint.pt ]; then
  exec .venv/bin/swarm train --resume --out runs/hint_chain --epochs 4 --workers 2
fi
exec .venv/bin/swarm train --policy commattn --init results/hint_tb/hint_tb_checkpoint.pt \
  --hint-planner chain-plan --hint-prior 8 --out runs/hint_chain --epochs 4 --updates 25 \
  --batch 96 --lr 0.0005 --workers 2 --threads 1 --gamma 0.9 --curriculum-step 0 \
  --val-episodes 96 --seed 71
