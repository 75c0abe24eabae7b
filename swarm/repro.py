"""`swarm repro ITEM`: the paper's Table 1, Fig. 4 and Fig. 5 on the batched evaluator.

Each item writes `ITEM.csv` (long format), `ITEM.md` (a Markdown table headed by the command and
seed that made it), `ITEM.png` (matplotlib, Agg) and `ITEM.json` into the output directory,
every file atomically. Policies are registry names, so a learned policy joins by name (with
`checkpoints[name]` when it needs one).
"""

from __future__ import annotations

import csv
import datetime as dt
import io
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from policies import BASELINES
from swarm import atomic
from swarm.bench import (
    NullProgress,
    ProgressSink,
    int_list,
    name_list,
    time_decisions,
    timing_stats,
)
from swarm.evaluate import evaluate
from swarm.policy_spec import build_policy
from world.config import ConfigError, WorldConfig, replace, to_dict

ITEMS = ("table1", "fig4", "fig5")
# Paper's Table 1 (ms per decision, 10 robots): mean, std.
PAPER_TABLE1: dict[str, tuple[float, float]] = {
    "commattn": (37.0, 5.0), "coordinated-frontier": (230.0, 20.0),
    "nearest-frontier": (35.0, 5.0), "cost-utility": (395.0, 15.0),
}
SWEEP_KEYS = ("elratio_mean", "elratio_std", "reward_mean", "collisions_mean",
              "block_collisions_mean", "success_rate", "planning_ms_per_decision")


@dataclass(frozen=True)
class ReproConfig:
    """Options of `swarm repro` (TOML table `[repro]`)."""

    out: str | None = None
    """Directory the item files are written to (required)."""
    episodes: int = 200
    """Episodes per point of Fig. 4 and Fig. 5."""
    seed: int = 0
    """Seed of every map; every policy and point sees the same episodes."""
    policies: tuple[str, ...] = BASELINES
    """Policies compared (registry names; learned ones take `checkpoints`)."""
    checkpoints: dict[str, str] = field(default_factory=dict)
    """Checkpoint file per learned policy name."""
    robots: tuple[int, ...] = (2, 4, 6, 8, 10, 12)
    """Fig. 4: team sizes on the static map."""
    add_every: tuple[int, ...] = (1, 2, 3, 4, 5, 6, 9)
    """Fig. 5: block-adding periods m on the dynamic map."""
    decisions: int = 150
    """Table 1: timed team decisions per policy."""
    batch: int = 250
    """Episodes stepped at once by the evaluator."""
    json: str | None = None
    """Also write every item's results into this one JSON file."""

    def __post_init__(self) -> None:
        object.__setattr__(self, "policies", name_list(self.policies))
        object.__setattr__(self, "robots", int_list(self.robots, "robots"))
        object.__setattr__(self, "add_every", int_list(self.add_every, "add_every"))
        for key in ("episodes", "decisions", "batch"):
            if getattr(self, key) < 1:
                raise ConfigError(f"{key} must be >= 1, got {getattr(self, key)}")
        if not isinstance(self.checkpoints, dict) or not all(
                isinstance(k, str) and isinstance(v, str) for k, v in self.checkpoints.items()):
            raise ConfigError("checkpoints must map policy names to file names")


def header(title: str, command: str, seed: int, note: str) -> str:
    """The Markdown heading plus the provenance line every item file starts with."""
    today = dt.date.today().isoformat()
    return f"# {title}\n\nMade by `{command}` (seed {seed}, {today}). {note}\n\n"


def md_table(columns: Sequence[str], rows: Sequence[Sequence[str]]) -> str:
    """A GitHub Markdown table, first column left-aligned and the rest right-aligned."""
    lines = ["| " + " | ".join(columns) + " |",
             "|" + "|".join([":---"] + ["---:"] * (len(columns) - 1)) + "|"]
    lines += ["| " + " | ".join(r) + " |" for r in rows]
    return "\n".join(lines) + "\n"


def csv_text(rows: Sequence[dict[str, Any]]) -> str:
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=list(rows[0]), lineterminator="\n")
    writer.writeheader()
    writer.writerows(rows)
    return buf.getvalue()


def save_png(path: Path, draw: Callable[[Any], None]) -> None:
    """Draw on a fresh Agg figure and write it atomically as PNG."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.4, 4.2))
    try:
        draw(ax)
        fig.tight_layout()
        buf = io.BytesIO()
        fig.savefig(buf, format="png", dpi=120)
    finally:
        plt.close(fig)
    atomic.write_bytes(path, buf.getvalue())


def write_item(out: Path, item: str, rows: list[dict[str, Any]], md: str,
               draw: Callable[[Any], None], meta: dict[str, Any]) -> list[str]:
    """Write ITEM.csv/.md/.png/.json; returns the paths written."""
    paths = [out / f"{item}.{ext}" for ext in ("csv", "md", "png", "json")]
    atomic.write_text(paths[0], csv_text(rows))
    atomic.write_text(paths[1], md)
    save_png(paths[2], draw)
    atomic.write_json(paths[3], {**meta, "rows": rows})
    return [str(p) for p in paths]


def table1(world: WorldConfig, cfg: ReproConfig, command: str,
           progress: ProgressSink) -> dict[str, Any]:
    """Planning ms per decision of N robots (G = 1) next to the paper's Table 1."""
    rows: list[dict[str, Any]] = []
    for name in cfg.policies:
        progress.start(f"table1 {name}", cfg.decisions)
        ms = time_decisions(world, name, cfg.decisions, cfg.seed, 1, cfg.checkpoints.get(name),
                            progress)
        paper = PAPER_TABLE1.get(name, (None, None))
        rows.append({"policy": name, "robots": world.n_robots, **timing_stats(ms),
                     "paper_mean_ms": paper[0], "paper_std_ms": paper[1]})
    md = header("Table 1: planning time per decision, ms", command, cfg.seed,
                f"{world.n_robots} robots, one episode at a time, every robot deciding; "
                f"{cfg.decisions} decisions per policy. The paper's figures are from its own "
                "hardware and implementation.")
    md += md_table(
        ["policy", "ours mean ± std", "ours median", "ours p90", "paper mean ± std"],
        [[r["policy"], f"{r['mean_ms']:.3f} ± {r['std_ms']:.3f}", f"{r['median_ms']:.3f}",
          f"{r['p90_ms']:.3f}",
          "-" if r["paper_mean_ms"] is None else f"{r['paper_mean_ms']:g} ± {r['paper_std_ms']:g}"]
         for r in rows])

    def draw(ax: Any) -> None:
        xs = range(len(rows))
        ax.bar([x - 0.2 for x in xs], [r["mean_ms"] for r in rows], 0.4,
               yerr=[r["std_ms"] for r in rows], label="ours", capsize=3)
        paper = [(x, r) for x, r in zip(xs, rows, strict=True) if r["paper_mean_ms"] is not None]
        ax.bar([x + 0.2 for x, _ in paper], [r["paper_mean_ms"] for _, r in paper], 0.4,
               yerr=[r["paper_std_ms"] for _, r in paper], label="paper", capsize=3)
        ax.set_xticks(list(xs), [r["policy"] for r in rows], rotation=15)
        ax.set_yscale("log")
        ax.set_ylabel("planning time per decision (ms, log scale)")
        ax.set_title(f"Table 1: planning time, {world.n_robots} robots")
        ax.legend()

    meta = {"item": "table1", "command": command, "seed": cfg.seed, "world": to_dict(world)}
    return {"item": "table1", "rows": rows,
            "files": write_item(Path(cfg.out or "."), "table1", rows, md, draw, meta)}


def sweep_worlds(world: WorldConfig, item: str, cfg: ReproConfig) -> list[tuple[int, WorldConfig]]:
    """The (x, world config) points of Fig. 4 (robots, static) or Fig. 5 (add_every, dynamic)."""
    if item == "fig4":
        return [(n, replace(world, n_robots=n, dynamic=False)) for n in cfg.robots]
    return [(m, replace(world, add_every=m, dynamic=True)) for m in cfg.add_every]


def sweep(world: WorldConfig, item: str, cfg: ReproConfig, command: str,
          progress: ProgressSink) -> dict[str, Any]:
    """Fig. 4 or Fig. 5: elratio at the last step per policy along the swept parameter."""
    x_name = "robots" if item == "fig4" else "add_every"
    points = sweep_worlds(world, item, cfg)
    progress.start(item, len(cfg.policies) * len(points) * cfg.episodes)
    rows: list[dict[str, Any]] = []
    for name in cfg.policies:
        for x, wc in points:
            policy = build_policy(name, wc, cfg.checkpoints.get(name))
            res = evaluate(wc, policy, cfg.seed, cfg.episodes, batch=cfg.batch,
                           on_progress=progress.advance)
            s = res.summary(wc)
            rows.append({"policy": name, x_name: x, "episodes": cfg.episodes,
                         **{k: s[k] for k in SWEEP_KEYS}})
    t = world.horizon
    if item == "fig4":
        title = f"Fig. 4: exploration rate in {t} steps vs number of robots (static map)"
        note = "Paper: learned > nearest > coordinated > cost-utility."
        xlabel = "number of robots"
        short = f"Fig. 4: static map, T = {t}"
    else:
        title = (f"Fig. 5: exploration rate in {t} steps vs block-adding period m "
                 f"(dynamic map, {world.n_robots} robots, {world.n_dynamic} blocks)")
        note = "Paper: CommAttn most stable."
        xlabel = "block-adding period m (steps between batches)"
        short = f"Fig. 5: dynamic map, {world.n_robots} robots, T = {t}"
    md = header(title, command, cfg.seed,
                f"elratio mean ± std over {cfg.episodes} episodes per point. {note}")
    policies = list(cfg.policies)
    cell = {(r["policy"], r[x_name]): r for r in rows}
    md += md_table([x_name, *policies],
                   [[str(x), *(f"{cell[p, x]['elratio_mean']:.3f} ± {cell[p, x]['elratio_std']:.3f}"
                               for p in policies)] for x, _ in points])

    def draw(ax: Any) -> None:
        xs = [x for x, _ in points]
        for p in policies:
            ax.errorbar(xs, [cell[p, x]["elratio_mean"] for x in xs],
                        yerr=[cell[p, x]["elratio_std"] for x in xs], marker="o", capsize=3,
                        label=p)
        ax.set_xlabel(xlabel)
        ax.set_ylabel(f"exploration rate in {t} steps (elratio)")
        ax.set_title(short)
        ax.grid(alpha=0.3)
        ax.legend()

    meta = {"item": item, "command": command, "seed": cfg.seed, "x": x_name,
            "episodes": cfg.episodes, "world": to_dict(world)}
    return {"item": item, "rows": rows,
            "files": write_item(Path(cfg.out or "."), item, rows, md, draw, meta)}


def expand(item: str) -> list[str]:
    """`all` -> every item; otherwise the one item (ConfigError if unknown)."""
    if item == "all":
        return list(ITEMS)
    if item not in ITEMS:
        raise ConfigError(f"unknown repro item {item!r}; choose from {', '.join(ITEMS)}, all")
    return [item]


def run(items: Sequence[str], world: WorldConfig, cfg: ReproConfig, command: str,
        progress: ProgressSink | None = None) -> dict[str, Any]:
    """Reproduce `items` into `cfg.out`; every configuration is validated before any runs."""
    if not cfg.out:
        raise ConfigError("repro needs an output directory (--out DIR)")
    progress = progress or NullProgress()
    for item in items:
        if item != "table1":
            sweep_worlds(world, item, cfg)  # raises ConfigError on an impossible point
    for name in cfg.policies:  # fail on an unloadable policy before hours of work
        build_policy(name, world, cfg.checkpoints.get(name))
    results: dict[str, Any] = {}
    for item in items:
        if item == "table1":
            results[item] = table1(world, cfg, command, progress)
        else:
            results[item] = sweep(world, item, cfg, command, progress)
    if cfg.json:
        atomic.write_json(cfg.json, {"command": command, "seed": cfg.seed,
                                     "items": {k: v["rows"] for k, v in results.items()}})
    return results
