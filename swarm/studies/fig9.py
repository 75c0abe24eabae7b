"""Fig. 9 of the paper: success rate (and elratio) over vision range x communication range.

The vision range changes a network's input, so each vision v needs a checkpoint trained with
it: `checkpoints/vision/NAME_vV.pt` (the shipped `checkpoints/NAME.pt`, or the one given, for
the default v = 5, whatever the world's vision: this figure sweeps it, and the comm range);
a vision without one is left out, named in the Markdown and in one warning line on stderr.
The communication range changes no weight shape: every range is evaluated with the same
checkpoint, which was trained at the default range of 10 cells. Every point plays the same
held-out episodes (evaluation seed).
"""

from __future__ import annotations

import math
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from swarm.common.policy_spec import SHIPPED, build_policy, shown
from swarm.common.report import checkpoints_of, header, md_table, write_item
from swarm.learn.evaluate import evaluate
from world.config import ConfigError, WorldConfig, replace, to_dict

VISIONS = (3, 5, 7, 9)
RANGES = (1.0, 2.0, 3.0, 5.0, 7.0, 9.0, 11.0, 13.0, 15.0, math.inf)
POLICIES = ("commnet", "commattn")


def vision_checkpoint(name: str, vision: int, default: WorldConfig,
                      shipped: str | None, where: Path = SHIPPED / "vision") -> Path | None:
    """The checkpoint of `name` trained with vision `vision` (`where`/NAME_vV.pt, or `shipped`
    at the default vision), or None if there is none."""
    if vision == default.vision and shipped:
        return Path(shipped)
    path = where / f"{name}_v{vision}.pt"
    return path if path.is_file() else None


def fig9(world: WorldConfig, out: Path, command: str, seed: int, episodes: int,
         policies: Sequence[str] = POLICIES, visions: Sequence[int] = VISIONS,
         ranges: Sequence[float] = RANGES, batch: int = 250,
         checkpoints: dict[str, str | None] | None = None, progress: Any = None,
         vision_dir: Path = SHIPPED / "vision") -> dict[str, Any]:
    """Rows per (policy, vision, comm range): success rate and elratio on `episodes` held-out
    dynamic-map episodes of `seed`, the vision checkpoints from `vision_dir`; writes
    fig9.csv/.md/.png/.json into `out`."""
    checkpoints = checkpoints or {}
    base = replace(world, dynamic=True)
    rows: list[dict[str, Any]] = []
    missing: list[str] = []
    for name in policies:
        for v in visions:
            ckpt = vision_checkpoint(name, v, WorldConfig(), checkpoints.get(name), vision_dir)
            if ckpt is None:
                missing.append(f"{name} v={v}")
                continue
            for r in ranges:
                wc = replace(base, vision=v, comm_range=r)
                policy = build_policy(name, wc, str(ckpt))
                res = evaluate(wc, policy, seed, episodes, batch=batch)
                s = res.summary(wc)
                rows.append({"policy": name, "vision": v,
                             "comm_range": "inf" if math.isinf(r) else r,
                             "episodes": episodes, "success_rate": s["success_rate"],
                             "elratio_mean": s["elratio_mean"], "elratio_std": s["elratio_std"],
                             "checkpoint": shown(str(ckpt))})
                if progress is not None:
                    progress.advance(episodes)
    note = (f"Success rate (elratio >= 0.9 and no block collision) and mean elratio over "
            f"{episodes} held-out dynamic-map episodes per point. Every checkpoint was trained "
            "at comm range 10; a vision range needs its own checkpoint.")
    if missing:
        note += f" Left out (no checkpoint): {', '.join(missing)}."
        print(f"swarm: warning: fig9 leaves out {', '.join(missing)}: no checkpoint "
              f"NAME_vV.pt in {vision_dir}", file=sys.stderr)
    if (world.vision, world.comm_range) != (WorldConfig.vision, WorldConfig.comm_range):
        note += (f" The world's vision {world.vision} and comm range {world.comm_range:g} "
                 "(for the other items of the command) are not used here: this figure sweeps "
                 "both.")
    md = header("Fig. 9: success rate over vision range x communication range", command, seed,
                note, checkpoints_of(rows))
    cols = [str(c) for c in ("inf" if math.isinf(r) else f"{r:g}" for r in ranges)]
    for name in policies:
        for v in visions:
            mine = [r for r in rows if r["policy"] == name and r["vision"] == v]
            if mine:
                md += f"\n**{name}, vision {v}** (success % / elratio)\n\n"
                md += md_table(["comm range", *cols],
                               [["success / elratio", *(f"{100 * r['success_rate']:.1f} / "
                                                        f"{r['elratio_mean']:.3f}"
                                                        for r in mine)]])

    def draw(axes: Any) -> None:
        axes = list(axes) if hasattr(axes, "__len__") else [axes]
        xs = list(range(len(ranges)))
        for ax, name in zip(axes, policies, strict=False):
            for v in visions:
                mine = [r for r in rows if r["policy"] == name and r["vision"] == v]
                if mine:
                    ax.plot(xs, [100 * r["success_rate"] for r in mine], marker="o",
                            label=f"vision {v}")
            ax.set_xticks(xs, cols)
            ax.set_xlabel("communication range (cells)")
            ax.set_ylabel("success rate (%)")
            ax.set_title(f"Fig. 9: {name}")
            ax.grid(alpha=0.3)
            ax.legend(fontsize=8)

    meta = {"item": "fig9", "command": command, "seed": seed, "world": to_dict(base),
            "missing": missing}
    files = write_item(out, "fig9", rows or [{"policy": "", "vision": 0}], md, draw, meta,
                       ncols=max(len(policies), 1))
    return {"item": "fig9", "rows": rows, "files": files}


def fig9_items(items: Sequence[str], policies: Sequence[str], default: bool) -> list[str]:
    """`items` as repro makes them: with other items, fig9 is left out when `policies` name
    neither CommNet nor CommAttn (a `[repro]` table may serve several items); fig9 alone refuses
    `policies` it cannot draw (`repro fig9 --policies random` drew CommNet and CommAttn), unless
    they are repro's default list (`default`)."""
    if "fig9" not in items:
        return list(items)
    if len(items) > 1:
        return [i for i in items if i != "fig9" or set(policies) & set(POLICIES)]
    other = [n for n in policies if n not in POLICIES]
    if other and not default:
        raise ConfigError(f"fig9 draws {' and '.join(POLICIES)} only, not --policies "
                          f"{','.join(other)}: name either of them, or leave --policies out for "
                          "both")
    return list(items)


def drawn(policies: Sequence[str]) -> list[str]:
    """The policies fig9 draws: CommNet and CommAttn, those of them in `policies`, else both."""
    return [n for n in POLICIES if n in policies] or list(POLICIES)


def check_fig9_checkpoints(world: WorldConfig, cfg: Any) -> None:
    """Every checkpoint `cfg` gives fig9 (one per policy, at the default vision) loads for its
    policy: a wrong one is refused before any point is run (it was found after the first
    policy's whole sweep)."""
    default = WorldConfig().vision
    for name in drawn(cfg.policies):
        ckpt = vision_checkpoint(name, default, WorldConfig(), cfg.checkpoint(name))
        if ckpt is not None:
            build_policy(name, replace(world, dynamic=True, vision=default), str(ckpt))


def fig9_item(world: WorldConfig, cfg: Any, command: str) -> dict[str, Any]:
    """`swarm repro fig9`: CommNet and CommAttn (those of them in `cfg.policies`, else both)
    with `cfg` (a `ReproConfig`)'s seed, episodes, batch and checkpoints."""
    names = drawn(cfg.policies)
    return fig9(world, Path(cfg.out), command, cfg.seed, cfg.fig9_episodes, policies=names,
                batch=cfg.batch, checkpoints={n: cfg.checkpoint(n) for n in names})
