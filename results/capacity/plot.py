"""The two stage-1 runs side by side (results/capacity/curves.png): training elratio (moving
mean of 25 updates) and validation elratio after each epoch, against training episodes.

    .venv/bin/python results/capacity/plot.py
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from swarm.common.report import save_png
from swarm.learn.curves import moving_mean, read_curve

HERE = Path(__file__).parent
BATCH = 96  # episodes per update of both runs
RUNS = {"default sizes": "base", "wide (embed 64, hidden 64, state 128, match 64)": "wide"}


def main() -> None:
    def draw(axes: Any) -> None:
        for label, run in RUNS.items():
            c = read_curve(HERE / f"{run}_curve.csv")
            axes[0].plot([e / 1000 for e in c["episodes"]], moving_mean(c["elratio"], 25),
                         label=label)
            val = [json.loads(line) for line in (HERE / f"{run}_log.jsonl").open()]
            val = [r for r in val if "val_elratio_mean" in r]
            axes[1].plot([r["update"] * BATCH / 1000 for r in val],
                         [r["val_elratio_mean"] for r in val], marker="o", label=label)
        axes[0].set_ylabel("training elratio (sampled, moving mean of 25 updates)")
        axes[1].set_ylabel("validation elratio (96 episodes, greedy)")
        for ax in axes:
            ax.set_xlabel("training episodes (thousands)")
            ax.grid(alpha=0.3)
            ax.legend(fontsize=8)
        axes[0].figure.suptitle("CommAttn stage 1 at two sizes (seed 0, batch 96, lr 3e-3, "
                                "curriculum, team memory)", fontsize=9)

    save_png(HERE / "curves.png", draw, ncols=2)


if __name__ == "__main__":
    main()
