#!/bin/sh
# Shipped policies (trained on 20 x 20, 10 robots) on 40 x 40 maps (blocks scaled by area:
# 324 static, 280 dynamic) with 20, 30 and 50 robots; horizon chosen so that robots x steps
# per cell is the paper's (10 x 30 / 400 = 0.75): 20 x 60, 30 x 40, 50 x 24. Seed 0, 100
# held-out episodes each. Coordinated frontier was first run at 20 robots only (314 ms a
# decision there); since its incremental assignment (2026-12-02) also at 30 and 50 robots, in
# files of its own (*_coordinated). One core: nice -n 10 sh results/scale/run.sh
cd "$(dirname "$0")/../.."
for spec in 20:60 30:40 50:24; do
  n=${spec%%:*}; t=${spec##*:}
  out="results/scale/eval_40x40_n${n}_t${t}"
  if [ -f "$out.json" ]; then echo "$out.json exists: skipped (delete it to re-run)"; continue; fi
  policies=random,nearest-frontier,commattn,commnet,vain,bicnet
  [ "$n" = 20 ] && policies=random,nearest-frontier,coordinated-frontier,commattn,commnet,vain,bicnet
  .venv/bin/swarm eval --policy "$policies" --size 40x40 --robots "$n" --horizon "$t" \
    --episodes 100 --batch 100 --seed 0 --json "$out.json" > "$out.txt" 2>/dev/null
done
for spec in 30:40 50:24; do
  n=${spec%%:*}; t=${spec##*:}
  out="results/scale/eval_40x40_n${n}_t${t}_coordinated"
  if [ -f "$out.json" ]; then echo "$out.json exists: skipped (delete it to re-run)"; continue; fi
  .venv/bin/swarm eval --policy coordinated-frontier --size 40x40 --robots "$n" --horizon "$t" \
    --episodes 100 --batch 100 --seed 0 --json "$out.json" > "$out.txt" 2>/dev/null
done
