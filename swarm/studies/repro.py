"""`swarm repro ITEM`: the paper's Table 1, Table 2, Fig. 4, Fig. 5 and Fig. 8 on the batched
evaluator (Fig. 8 from the training curves shipped beside the checkpoints).

Each item writes `ITEM.csv` (long format), `ITEM.md` (a Markdown table headed by the command and
seed that made it), `ITEM.png` (matplotlib, Agg) and `ITEM.json` into the output directory,
every file atomically; its old files go when it starts (one stopped part-way leaves no new files
beside old ones). Policies are registry names, so a learned policy joins by name (with
`checkpoints[name]` when it needs one; by default the one shipped in `checkpoints/NAME.pt`).
"""

from __future__ import annotations

import sys
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from policies import learned_names
from swarm.bench.micro import (
    NullProgress,
    ProgressSink,
    int_list,
    name_list,
    time_decisions,
    timing_stats,
)
from swarm.common import atomic
from swarm.common.policy_spec import SHIPPED, build_policy, shown
from swarm.common.report import (
    checkpoints_of,
    counted,
    header,
    item_files,
    md_table,
    paired,
    paired_cell,
    provenance,
    write_item,
)
from swarm.learn.curves import fig8 as curves_figure
from swarm.learn.curves import read_curve
from swarm.learn.evaluate import evaluate
from swarm.studies import comm as cs
from world.config import ConfigError, WorldConfig, check_count, check_seed, replace, to_dict

ITEMS = ("table1", "table2", "fig4", "fig5", "fig8", "fig9", "fig10", "fig11", "comm")
ANALYSES = ("fig10", "fig11", "comm")  # CommAttn's communication (swarm.studies.commviz, comm)
LEARNED = learned_names()
ALL_POLICIES = (*LEARNED, "nearest-frontier", "coordinated-frontier", "cost-utility", "random")
SAYS = {  # the planners that bound the others, as Table 2 describes those it holds
    "team-beam": "`team-beam` is a hand-written decentralized planner (every robot plans the "
                 "robots it hears with `central`'s search, on its own belief)",
    "chain-plan": "`chain-plan` is a hand-written decentralized planner (a whole-horizon team "
                  "plan that each robot refines and passes to its successor in the hidden-state "
                  "message)",
    "central": "`central` pools every robot's observations (a perfect radio)",
    "oracle": "`oracle` knows the whole episode in advance (first {} episodes only)"}
REFERENCE = tuple(SAYS)
# Paper's Table 2 (10 robots, 30 s, 1000 episodes): mean reward, collisions, elratio %, std %.
PAPER_TABLE2: dict[str, tuple[float, float, float, float | None]] = {
    "commattn": (37, 9, 95.2, 3.1), "vain": (21, 15, 90.2, None),
    "bicnet": (25, 22, 89.8, None), "commnet": (24, 13, 89.2, None),
}
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
    policies: tuple[str, ...] = ALL_POLICIES
    """Policies compared (registry names; learned ones take `checkpoints`)."""
    checkpoints: dict[str, str] = field(default_factory=dict)
    """Checkpoint file per learned policy name (default: the shipped checkpoints/NAME.pt)."""
    table2_episodes: int = 1000
    """Table 2: held-out episodes per policy (the paper: 1000)."""
    comm_episodes: int = 200
    """`comm`: held-out episodes per (policy, condition)."""
    comm_policies: tuple[str, ...] = cs.POLICIES
    """`comm`: policies compared, the first one paired against each other (learned ones take
    `checkpoints`; e.g. add `chain-plan`, or a network of your own as `commattn`)."""
    fig9_episodes: int = 1000
    """Fig. 9: held-out episodes per (policy, vision, comm range) point."""
    fig10_episodes: int = 200
    """Fig. 10: static-map episodes whose decoder states are recorded."""
    fig11_episodes: int = 1000
    """Fig. 11: episodes on the one fixed static map."""
    oracle_episodes: int = 60
    """Table 2: the oracle plans each episode in ~2 s, so it plays only the first this many of
    the held-out episodes (its paired difference is over those)."""
    reference: bool = True
    """Table 2 with the default policies: add the planners (team-beam, chain-plan, central, oracle)
    and each policy's share of the oracle-to-random gap (name them in `policies` to choose)."""
    curves: dict[str, str] = field(default_factory=dict)
    """Fig. 8: training-curve CSV per learned policy (default: checkpoints/NAME_curve.csv); a
    key NAME:TAG draws one more curve of NAME, labelled so (yours beside the shipped one)."""
    smooth: int = 25
    """Fig. 8: moving-average window, in updates."""
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
    resume: bool = False
    """`comm`: go on from the cells an interrupted one in `out` made with the same settings."""

    def __post_init__(self) -> None:
        object.__setattr__(self, "policies", name_list(self.policies))
        given = self.comm_policies.split(",") if isinstance(self.comm_policies, str) else \
            self.comm_policies if isinstance(self.comm_policies, (list, tuple)) else ()
        names = [n.strip() for n in given if isinstance(n, str)]
        if twice := next((n for n in names if n and names.count(n) > 1), None):
            raise ConfigError(f"--comm-policies names {twice} twice: comm compares each policy "
                              "once")
        object.__setattr__(self, "comm_policies", name_list(self.comm_policies))
        check_seed(self.seed)
        object.__setattr__(self, "robots", int_list(self.robots, "robots"))
        object.__setattr__(self, "add_every", int_list(self.add_every, "add_every"))
        for key in ("episodes", "decisions", "batch", "table2_episodes", "smooth",
                    "fig9_episodes", "fig10_episodes", "fig11_episodes", "oracle_episodes",
                    "comm_episodes"):
            check_count(getattr(self, key), key)
        if not isinstance(self.checkpoints, dict) or not all(
                isinstance(k, str) and isinstance(v, str) for k, v in self.checkpoints.items()):
            raise ConfigError("checkpoints must map policy names to file names")
        from policies import LEARNED

        if stray := sorted(set(self.checkpoints) - LEARNED):  # (a typo ran the shipped one)
            raise ConfigError(f"--checkpoint {', '.join(stray)}: not a learned policy; "
                              f"checkpoints are for {', '.join(sorted(LEARNED))}")
        if not isinstance(self.curves, dict) or not all(
                isinstance(k, str) and isinstance(v, str) for k, v in self.curves.items()):
            raise ConfigError("curves must map policy names to CSV file names")
        # (the figure was drawn without it); NAME:TAG is a second curve of NAME
        if stray := sorted(k for k in self.curves if k.partition(":")[0] not in LEARNED
                           or k.endswith(":")):
            raise ConfigError(f"--curve {stray[0]}=...: not a learned policy (or NAME:TAG); "
                              f"curves are for {', '.join(sorted(LEARNED))}")

    def checkpoint(self, name: str) -> str | None:
        """The checkpoint of policy `name`: given, else shipped (learned policies), else None."""
        from swarm.common.policy_spec import effective_checkpoint

        try:
            return effective_checkpoint(name, self.checkpoints.get(name))
        except ConfigError:
            raise ConfigError(f"no checkpoint for {name}: pass --checkpoint {name}=FILE") from None

    def curve(self, name: str) -> Path:
        return Path(self.curves.get(name, SHIPPED / f"{name}_curve.csv"))

    def curve_files(self, names: Sequence[str]) -> dict[str, Path]:
        """Fig. 8's curves: each of `names` (given, or shipped), then each `NAME:TAG` given."""
        return {**{n: self.curve(n) for n in names},
                **{k: Path(v) for k, v in self.curves.items() if ":" in k}}


def table1(world: WorldConfig, cfg: ReproConfig, command: str,
           progress: ProgressSink) -> dict[str, Any]:
    """Planning ms per decision of N robots (G = 1) next to the paper's Table 1."""
    rows: list[dict[str, Any]] = []
    for name in cfg.policies:
        progress.start(f"table1 {name}", cfg.decisions)
        ms = time_decisions(world, name, cfg.decisions, cfg.seed, 1, ckpt := cfg.checkpoint(name),
                            progress)
        paper = PAPER_TABLE1.get(name, (None, None))
        rows.append({"policy": name, "robots": world.n_robots, "checkpoint": shown(ckpt) or "",
                     **timing_stats(ms), "paper_mean_ms": paper[0], "paper_std_ms": paper[1]})
    md = header("Table 1: planning time per decision, ms", command, cfg.seed,
                f"{world.n_robots} robots, one episode at a time, every robot deciding; "
                f"{cfg.decisions} decisions per policy. The paper's figures are from its own "
                "hardware and implementation.", checkpoints_of(rows))
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
            policy = build_policy(name, wc, ckpt := cfg.checkpoint(name))
            res = evaluate(wc, policy, cfg.seed, cfg.episodes, batch=cfg.batch,
                           on_progress=progress.advance)
            s = res.summary(wc)
            rows.append({"policy": name, x_name: x, "episodes": cfg.episodes,
                         "checkpoint": shown(ckpt) or "", **{k: s[k] for k in SWEEP_KEYS}})
    t = world.horizon
    if item == "fig4":
        title = f"Fig. 4: exploration rate in {t} steps vs number of robots (static map)"
        note, xlabel = "Paper: learned > nearest > coordinated > cost-utility.", "number of robots"
        short = f"Fig. 4: static map, T = {t}"
    else:
        title = (f"Fig. 5: exploration rate in {t} steps vs block-adding period m "
                 f"(dynamic map, {world.n_robots} robots, {world.n_dynamic} blocks)")
        note = "Paper: CommAttn most stable."
        xlabel = "block-adding period m (steps between batches)"
        short = f"Fig. 5: dynamic map, {world.n_robots} robots, T = {t}"
    md = header(title, command, cfg.seed,
                f"elratio mean ± std over {cfg.episodes} episodes per point. {note}",
                checkpoints_of(rows))
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


def learned_of(cfg: ReproConfig) -> list[str]:
    return [p for p in cfg.policies if p in LEARNED]


def table2_notes(rows: list[dict[str, Any]], cfg: ReproConfig) -> str:
    """Table 2's words on the planners and the gap column: only those in the table."""
    says = [SAYS.get(r["policy"], f"`{r['policy']}`").format(r["episodes"]) for r in rows]
    text = "".join(f" {s[0].upper()}{s[1:]}." for r, s in zip(rows, says, strict=True)
                   if r["decentralized"] and r["policy"] in SAYS)
    if starred := [s for r, s in zip(rows, says, strict=True) if not r["decentralized"]]:
        text += f" Rows marked * are not decentralized: {'; '.join(starred)}."
    if any(r["gap_closed"] is not None for r in rows):
        text += " 'gap' is the share of the oracle-to-random elratio gap a policy closes."
    return text


def table2(world: WorldConfig, cfg: ReproConfig, command: str,
           progress: ProgressSink) -> dict[str, Any]:
    """Table 2: every policy on the same held-out dynamic-map episodes, next to the paper's."""
    wc = replace(world, dynamic=True)
    default = tuple(cfg.policies) == ALL_POLICIES  # --policies given: exactly those
    names = list(cfg.policies) + [r for r in REFERENCE
                                  if cfg.reference and default and r not in cfg.policies]
    progress.start("table2", len(names) * cfg.table2_episodes)
    rows: list[dict[str, Any]] = []
    first: np.ndarray | None = None  # the first policy's per-episode elratio (paired reference)
    for name in names:
        ckpt = cfg.checkpoint(name)
        policy = build_policy(name, wc, ckpt)
        episodes = min(cfg.table2_episodes, cfg.oracle_episodes) if name == "oracle" \
            else cfg.table2_episodes
        res = evaluate(wc, policy, cfg.seed, episodes, batch=cfg.batch,
                       on_progress=progress.advance)
        progress.advance(cfg.table2_episodes - episodes)
        s = res.summary(wc)
        paper = PAPER_TABLE2.get(name)
        if first is None:
            first = res.elratio
        lead, se = paired(first[:episodes], res.elratio)  # same episodes
        rows.append({"policy": name, "robots": wc.n_robots, "episodes": episodes,
                     "checkpoint": shown(ckpt) or "", "decentralized": bool(policy.decentralized),
                     **{k: s[k] for k in SWEEP_KEYS}, "robot_collisions_mean":
                     float(res.robot_collisions.mean()),
                     "first_minus_elratio": lead, "first_minus_elratio_se": se,
                     "paper_reward": paper[0] if paper else None,
                     "paper_collisions": paper[1] if paper else None,
                     "paper_elratio_pct": paper[2] if paper else None,
                     "paper_elratio_std_pct": paper[3] if paper else None})
    by = {r["policy"]: r["elratio_mean"] for r in rows}
    lo, hi = by.get("random"), by.get("oracle")
    for r in rows:  # the share of the oracle-to-random gap each policy closes
        r["gap_closed"] = (r["elratio_mean"] - lo) / (hi - lo) if lo is not None and hi and \
            hi > lo else None
    md = header(f"Table 2: {wc.n_robots} robots, {wc.horizon} steps, dynamic map", command,
                cfg.seed,
                f"{counted(cfg.table2_episodes, 'held-out episode')} per policy (evaluation "
                f"seed {cfg.seed}; training used seeds from 1,000,000 up), greedy actions. Our "
                "rewards are the SPEC's (negative for good policies); the paper's are from its "
                "own reward scale. Collisions = block + robot collisions per episode. Column "
                f"`{names[0]} - this (paired)` is {names[0]}'s elratio minus the row's, episode "
                "by episode, with the standard error of that paired mean."
                + table2_notes(rows, cfg), checkpoints_of(rows))

    def paper_cell(r: dict[str, Any]) -> str:
        if r["paper_reward"] is None:
            return "-"
        std = f" ± {r['paper_elratio_std_pct']:g}" if r["paper_elratio_std_pct"] else ""
        return (f"{r['paper_reward']:g} / {r['paper_collisions']:g} / "
                f"{r['paper_elratio_pct']:g}{std} %")

    def lead(r: dict[str, Any]) -> str:
        if r is rows[0]:
            return "-"
        return paired_cell(r["first_minus_elratio"], r["first_minus_elratio_se"])

    gap = any(r["gap_closed"] is not None for r in rows)  # (random and oracle both played)
    md += md_table(
        ["policy", "reward / robot", "collisions (block)", "elratio", "success",
         "paper: reward / collisions / elratio", f"{cfg.policies[0]} - this (paired)",
         *(["gap"] if gap else [])],
        [[r["policy"] + ("" if r["decentralized"] else " *"), f"{r['reward_mean']:.1f}",
          f"{r['collisions_mean']:.2f} ({r['block_collisions_mean']:.2f})",
          f"{r['elratio_mean']:.3f} ± {r['elratio_std']:.3f}", f"{100 * r['success_rate']:.1f}%",
          paper_cell(r), lead(r),
          *(["-" if r["gap_closed"] is None else f"{100 * r['gap_closed']:.1f}%"] if gap
            else [])] for r in rows])

    def draw(ax: Any) -> None:
        xs = range(len(rows))
        ax.bar(list(xs), [r["elratio_mean"] for r in rows], 0.6,
               yerr=[r["elratio_std"] for r in rows], capsize=3, label="ours")
        paper = [(x, r) for x, r in zip(xs, rows, strict=True) if r["paper_elratio_pct"]]
        ax.scatter([x for x, _ in paper], [r["paper_elratio_pct"] / 100 for _, r in paper],
                   color="k", marker="_", s=400, zorder=3, label="paper")
        ax.set_xticks(list(xs), [r["policy"] for r in rows], rotation=25, ha="right")
        ax.set_ylim(0.5, 1.0)
        ax.set_ylabel("elratio at the last step")
        ax.set_title(f"Table 2: {wc.n_robots} robots, dynamic map, {cfg.table2_episodes} "
                     "episodes")
        ax.grid(alpha=0.3, axis="y")
        ax.legend()

    meta = {"item": "table2", "command": command, "seed": cfg.seed, "world": to_dict(wc)}
    return {"item": "table2", "rows": rows,
            "files": write_item(Path(cfg.out or "."), "table2", rows, md, draw, meta)}


def analysis(item: str, cfg: ReproConfig, world: WorldConfig | None = None,
             command: str = "") -> dict[str, Any]:
    """Fig. 10 (t-SNE of decoder states, with a silhouette and a linear probe) or Fig. 11
    (communication-vector norm per cell) of CommAttn, by swarm.studies.commviz."""
    from swarm.studies import commviz

    out = Path(cfg.out or ".")
    if item == "comm":  # only the checkpoints given here: else it picks one per map size
        return cs.comm(world or WorldConfig(), out, command, cfg.seed, cfg.comm_episodes,
                    policies=cfg.comm_policies, checkpoints=cfg.checkpoints, batch=cfg.batch,
                    resume=cfg.resume)
    ckpt = cfg.checkpoint("commattn")
    static = None if world is None else replace(world, dynamic=False)  # (static studies, on
    study = commviz.fig10 if item == "fig10" else commviz.fig11  # the run's map and team)
    res = study(out, seed=cfg.seed, episodes=getattr(cfg, f"{item}_episodes"), checkpoint=ckpt,
                cfg=static)
    title, _, rest = (md := out / item_files(item)[3]).read_text().partition("\n\n")
    ran = {"commattn": [shown(ckpt) or ""]}  # (its Made by line, as every other item's)
    atomic.write_text(md, header(title[2:], command, cfg.seed, "", ran)[:-2] + rest)
    return {"item": item, "rows": [{**res, "checkpoint": shown(ckpt) or ""}],
            "files": [str(out / n) for n in item_files(item)]}


def expand(item: str) -> list[str]:
    """`all` -> every item; otherwise the one item (ConfigError if unknown)."""
    if item == "all":
        return list(ITEMS)
    if item not in ITEMS:
        raise ConfigError(f"unknown repro item {item!r}; choose from {', '.join(ITEMS)}, all")
    return [item]


def prepare(items: Sequence[str], world: WorldConfig, cfg: ReproConfig) -> list[str]:
    """The items `run` will make, every configuration of them validated (ConfigError)."""
    if not cfg.out:
        raise ConfigError("repro needs an output directory (--out DIR)")
    asked = list(items)
    if len(items) > 1 and "fig8" in items and not learned_of(cfg):
        items = [i for i in items if i != "fig8"]  # `all` without learned policies: no curves
    if len(items) > 1 and "commattn" not in cfg.policies:  # `all` without CommAttn
        items = [i for i in items if i not in ANALYSES]
    from swarm.studies.fig9 import check_fig9_checkpoints, fig9_items

    # (fig9 alone: --policies it cannot draw refused)
    items = fig9_items(items, cfg.policies, tuple(cfg.policies) == ALL_POLICIES)
    if left := [i for i in asked if i not in items]:
        why = {"fig8": "no learned policy", "fig9": "neither commnet nor commattn"}
        said = "; ".join(f"{i} ({why.get(i, 'not commattn')} among --policies)" for i in left)
        print(f"swarm: warning: repro leaves out {said}: run `swarm repro ITEM` on its own, or "
              "add the policy to --policies", file=sys.stderr, flush=True)
    if "fig9" in items:
        check_fig9_checkpoints(world, cfg)
    for item in items:
        if item not in ("table1", "fig9", *ANALYSES):
            sweep_worlds(world, item, cfg)  # raises ConfigError on an impossible point
    for name in cfg.policies if set(items) - {"fig8", "fig9", *ANALYSES} else ():  # fail early
        build_policy(name, world, cfg.checkpoint(name))
    if set(items) & {"fig10", "fig11"}:
        build_policy("commattn", world, cfg.checkpoint("commattn"))
    if cfg.resume and items != ["comm"]:  # (`all` would make every other item again first)
        raise ConfigError("--resume (or [repro] resume) goes on with an interrupted comm, alone:"
                          f" `swarm repro comm --resume`, not {', '.join(items)}")
    if "comm" in items:
        for name in cfg.comm_policies:
            build_policy(name, world, cfg.checkpoint(name))
        if cfg.resume:  # (its settings held before it runs)
            cs.resumed_cells(Path(cfg.out), cs.repro_key(world, cfg))
    if "fig8" in items:
        if not learned_of(cfg):
            raise ConfigError("fig8 needs at least one learned policy in --policies")
        if stray := sorted(k for k in cfg.curves if k.partition(":")[0] not in learned_of(cfg)):
            raise ConfigError(f"--curve {stray[0]}=...: {stray[0].partition(':')[0]} is not "
                              f"among --policies {','.join(cfg.policies)}")
        for name, path in cfg.curve_files(learned_of(cfg)).items():
            if not path.exists():
                raise ConfigError(f"no training curve for {name}: {path} not found")
            read_curve(path)  # (one that is not a curve: before any other item)
    for name in (n for item in items for n in item_files(item)) if cfg.json else ():
        if Path(cfg.json).resolve() == (Path(cfg.out) / name).resolve():
            raise ConfigError(f"--json {cfg.json} is a file repro writes ({name}); give "
                              "another path for the summary")
    return list(items)


def run(items: Sequence[str], world: WorldConfig, cfg: ReproConfig, command: str,
        progress: ProgressSink | None = None, prepared: bool = False) -> dict[str, Any]:
    """Reproduce `items` into `cfg.out`; every configuration is validated before any runs
    (`prepared`: the caller has had `prepare` do it)."""
    items = items if prepared else prepare(items, world, cfg)
    progress = progress or NullProgress()
    out = Path(cfg.out or ".")  # a killed repro's temp files (these items': another may run)
    atomic.remove_stale(out, tuple(n for i in items for n in item_files(i)) + (cs.PARTIAL,))
    results: dict[str, Any] = {}
    for item in items:
        for name in item_files(item):  # old files go at its start, new ones come at its end
            (out / name).unlink(missing_ok=True)
        if item == "table1":
            results[item] = table1(world, cfg, command, progress)
        elif item == "table2":
            results[item] = table2(world, cfg, command, progress)
        elif item == "fig8":  # the learned policies' training curves
            results[item] = curves_figure(cfg.curve_files(learned_of(cfg)), cfg.smooth, out,
                                          command, cfg.seed)
        elif item in ANALYSES:
            results[item] = analysis(item, cfg, world, command)
        elif item == "fig9":
            from swarm.studies.fig9 import fig9_item

            results[item] = fig9_item(world, cfg, command)
        else:
            results[item] = sweep(world, item, cfg, command, progress)
    if cfg.json:
        atomic.write_json(cfg.json, {"command": command, "seed": cfg.seed,
                                     "provenance": provenance(),
                                     "items": {k: v["rows"] for k, v in results.items()}})
    return results
