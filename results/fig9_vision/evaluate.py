"""Fig. 9 at the vision ranges whose checkpoints `train.sh` has finished: each finished run's
checkpoint (`NAME_vV/checkpoint.pt`, all 12 epochs done) is copied to `ckpts/NAME_vV.pt` and
`swarm.studies.fig9` evaluates those visions on the same 1000 held-out episodes of seed 0 per
point as `swarm repro fig9` (whose vision-5 rows, the shipped networks, they compare with).
From the repository root:

    .venv/bin/python results/fig9_vision/evaluate.py results/fig9_vision/fig9

A vision is evaluated only when both networks have finished there (the figure compares them).
"""
from __future__ import annotations

import shutil
import sys
from pathlib import Path

import torch

from policies.checkpoint import load_checkpoint
from swarm.studies.fig9 import POLICIES, fig9
from world.config import WorldConfig

HERE = Path(__file__).resolve().parent
EPOCHS = 12


def finished(name: str, vision: int) -> Path | None:
    path = HERE / f"{name}_v{vision}" / "checkpoint.pt"
    if not path.is_file():
        return None
    return path if load_checkpoint(path)["train"]["epoch"] >= EPOCHS else None


def main(out: str) -> None:
    torch.set_num_threads(1)
    ckpts = HERE / "ckpts"
    ckpts.mkdir(exist_ok=True)
    visions = []
    for v in (3, 7, 9):
        done = {name: finished(name, v) for name in POLICIES}
        if all(done.values()):
            for name, path in done.items():
                shutil.copyfile(path, ckpts / f"{name}_v{v}.pt")  # type: ignore[arg-type]
            visions.append(v)
    if not visions:
        print("no vision has both networks finished yet")
        return
    res = fig9(WorldConfig(), Path(out), "results/fig9_vision/evaluate.py " + out, 0, 1000,
               visions=visions, vision_dir=ckpts)
    print(res["files"])


if __name__ == "__main__":
    main(sys.argv[1])
