#!/usr/bin/env bash
# The paper's full schedule on the default CommAttn (results/paper_full/README.md), resumable at
# any point: each stage resumes its run directory if it has a checkpoint, else starts from the
# previous stage's. Kill it at any time (a checkpoint is written every epoch) and run it again.
# From the repository root:  bash results/paper_full/schedule.sh   (runs/ holds the stages)
set -euo pipefail
S=.venv/bin/swarm
COMMON=(--updates 100 --batch 288 --workers 2 --threads 1 --gamma 0.9 --val-episodes 288)

mkdir -p runs
for k in "" 2 3; do  # the committed run directories, where a stage stopped
    src=results/paper_full/run$k
    if [ -f "$src/checkpoint.pt" ] && [ ! -f "runs/paper_full$k/checkpoint.pt" ]; then
        cp -r "$src" "runs/paper_full$k"
    fi
done
$S train --resume --out runs/paper_full                                       # stage 1 (25 epochs)

stage() {  # out, from, epochs, lr, seed
    if [ -f "$1/checkpoint.pt" ]; then
        $S train --resume --out "$1"
    else
        $S train --policy commattn --init "$2/checkpoint.pt" --out "$1" --epochs "$3" \
            --lr "$4" --curriculum-step 0 --seed "$5" "${COMMON[@]}"
    fi
}
stage runs/paper_full2 runs/paper_full 15 0.001 42                          # stage 2
stage runs/paper_full3 runs/paper_full2 10 0.0003 43                        # stage 3
