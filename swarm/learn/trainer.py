"""`swarm train`: the batched training loop (paper sections 3 and 4.3), top to bottom.

Per update: `batch` episodes are collected (swarm.learn.rollout) at the curriculum's level and one
REINFORCE step is taken (swarm.learn.update), in one process or split over `workers`
(swarm.learn.parallel). Episodes of update u are episodes u*batch .. of the training seed
`train_seed_offset + seed`, disjoint from the evaluation seeds (0, 1, ...): a run is a pure
function of its config, and `--resume` continues exactly from the checkpoint of every epoch.
"""

from __future__ import annotations

import contextlib
import dataclasses
import sys
import time
from collections.abc import Collection
from pathlib import Path
from typing import Any

import numpy as np
import torch

from policies import LEARNED, make_policy
from policies.checkpoint import load_checkpoint, save_checkpoint
from policies.learned import LearnedPolicy
from swarm.common.report import printable, provenance
from swarm.learn.config import TrainConfig, resume_point
from swarm.learn.curriculum import Curriculum
from swarm.learn.curves import CurveLog, plot_curve
from swarm.learn.evaluate import evaluate
from swarm.learn.parallel import ParallelUpdater
from swarm.learn.rollout import collect, train_faults
from swarm.learn.update import update
from world.config import ConfigError, WorldConfig


def _progress_line(row: dict[str, Any], total: int) -> str:
    return (f"epoch {row['epoch']} update {row['update']}/{total}  "
            f"{row['episodes_per_s']:.0f} ep/s  elratio {row['elratio']:.3f}  "
            f"success {row['success']:.2f}  reward {row['reward']:.1f}  "
            f"loss {row['loss']:.3f}  dyn {row['n_dynamic']}")


def earlier_commands(meta: dict[str, Any]) -> list[str]:
    """The commands that made a checkpoint's epochs, first to last: `meta.commands`, or the one
    `meta.command` of a checkpoint written before runs kept their history."""
    commands = meta.get("commands")
    if isinstance(commands, list) and all(isinstance(c, str) for c in commands):
        return list(commands)
    return [meta["command"]] if isinstance(meta.get("command"), str) else []


# ---------------------------------------------------------------------------------- the loop
def main(cfg: TrainConfig, world: WorldConfig, out: Path, resume: bool = False,
         console: Any | None = None, given: Collection[str] | None = None,
         world_given: Collection[str] | None = None) -> dict[str, Any]:
    """Train (or resume) into `out`: checkpoint.pt, log.jsonl, curve.csv. Returns the last row.

    Resuming, the checkpoint's config and world stand: `given` names the fields of `cfg` the
    caller set (None: all of them), and only `RESUME_MAY_CHANGE` of them may differ from the
    checkpoint's; the `world_given` fields of `world` (None: all) must equal the checkpoint's
    (ConfigError otherwise, before anything is written)."""
    # Denormal floats slow CPU math ~10x in late training; flushing them is process-global
    # state, so it is on for the run only (not in the policy: other code shares the process).
    torch.set_flush_denormal(True)
    try:
        return _main(cfg, world, out, resume, console, given, world_given)
    finally:
        torch.set_flush_denormal(False)


def _main(cfg: TrainConfig, world: WorldConfig, out: Path, resume: bool,
          console: Any | None, given: Collection[str] | None,
          world_given: Collection[str] | None) -> dict[str, Any]:
    from rich.console import Console
    from rich.progress import (
        BarColumn,
        MofNCompleteColumn,
        Progress,
        TextColumn,
        TimeRemainingColumn,
    )

    console = console or Console(stderr=True)
    out = Path(out)
    ckpt_path = out / "checkpoint.pt"
    if not (resume and ckpt_path.exists()) and cfg.policy not in LEARNED:
        raise ConfigError(f"policy {cfg.policy!r} is not a learned policy")
    curves = CurveLog(out)
    cur = Curriculum()
    epoch0, upd, elapsed0, commands = 0, 0, 0.0, [printable(" ".join(sys.argv))]
    if resume and ckpt_path.exists():
        data = load_checkpoint(ckpt_path)
        cfg, world, tr = resume_point(data, cfg, given, world, world_given, str(out))
        torch.set_num_threads(cfg.threads)
        policy = make_policy(cfg.policy, world, checkpoint=ckpt_path)
        opt = torch.optim.Adam(policy.net.parameters(), lr=cfg.lr)
        opt.load_state_dict(tr["optimizer"])
        torch.set_rng_state(tr["rng"])
        epoch0, upd = tr["epoch"], tr["update"]
        cur = Curriculum(**tr["curriculum"])
        curves.resume(upd)
        elapsed0 = float(tr["elapsed_s"]) if isinstance(tr.get("elapsed_s"), float) \
            else curves.last_elapsed()  # (a checkpoint from before it was kept: its curve's)
        commands = earlier_commands(data.get("meta", {})) + commands
        console.print(f"resuming {cfg.policy} from epoch {epoch0}, update {upd}" +
                      (f": all {cfg.epochs} epochs are done (--epochs N goes on)"
                       if epoch0 >= cfg.epochs else ""))
    else:
        if ckpt_path.exists() and not resume:
            raise ConfigError(f"{out} already holds a run; resume it (--resume, resume=True) or "
                              "choose another output folder (--out)")
        torch.set_num_threads(cfg.threads)
        torch.manual_seed(cfg.seed)
        policy = make_policy(cfg.policy, world, **({"model": cfg.model_config()} if cfg.model
                                                    else {}))
        if not isinstance(policy, LearnedPolicy):
            raise ConfigError(f"policy {cfg.policy!r} is not a learned policy")
        if cfg.init:
            policy = make_policy(cfg.policy, world, checkpoint=cfg.init)
        if cfg.team_memory:
            policy.set_model(team_memory=True)
        widen = {k: True for k in ("belief", "hint")
                 if getattr(cfg, k) and not getattr(policy.model_cfg, k)}
        if widen:  # (one call: the new inputs come last, in the featurizer's order)
            policy.widen(**widen)
        if cfg.hint_planner:
            if not policy.model_cfg.hint:
                raise ConfigError("train hint_planner needs a network with the hint (--hint true)")
            policy.set_model(hint_planner=cfg.hint_planner)
        if cfg.hint_prior != -1.0:
            if not policy.model_cfg.hint:
                raise ConfigError("train hint_prior needs a network with the hint (--hint true)")
            policy.set_model(hint_prior=cfg.hint_prior)
        opt = torch.optim.Adam(policy.net.parameters(), lr=cfg.lr)
        out.mkdir(parents=True, exist_ok=True)  # (only once the run is known to start)
        curves.start()
    train_seed = cfg.train_seed_offset + cfg.seed
    total = cfg.epochs * cfg.updates
    last: dict[str, Any] = {}
    start = time.perf_counter()
    columns = [TextColumn("[bold]{task.description}"), BarColumn(), MofNCompleteColumn(),
               TimeRemainingColumn(), TextColumn("{task.fields[stats]}")]
    pool = ParallelUpdater(policy, world, cfg.workers, cfg.threads) if cfg.workers > 1 else None
    with Progress(*columns, console=console, disable=not console.is_terminal) as bar, \
            pool or contextlib.nullcontext():
        task = bar.add_task(f"train {cfg.policy}", total=total, completed=upd, stats="")
        for epoch in range(epoch0, cfg.epochs):
            for _ in range(cfg.updates):
                t0 = time.perf_counter()
                level_world = cur.world(world, cfg)
                episodes = upd * cfg.batch + np.arange(cfg.batch)
                if pool is None:
                    roll = collect(policy, level_world, train_seed, episodes, train_faults(cfg),
                                   cfg.tick_s, cfg.imitate, cfg.imitate_samples)
                    m, parts = roll.metrics, update(policy, opt, roll, cfg)
                else:
                    m, parts = pool.update(policy, opt, level_world, train_seed, episodes, cfg,
                                           train_faults(cfg))
                upd += 1
                dt = time.perf_counter() - t0
                row = {"update": upd, "epoch": epoch + 1, "episodes": upd * cfg.batch,
                       "n_dynamic": level_world.n_active_dynamic,
                       "elratio": float(m.elratio.mean()), "success": float(m.success.mean()),
                       "reward": float(m.reward.mean()), "collisions": float(m.collisions.mean()),
                       "block_collisions": float(m.block_collisions.mean()), **parts,
                       "episodes_per_s": cfg.batch / dt,
                       "elapsed_s": elapsed0 + time.perf_counter() - start}
                cur.observe(row["elratio"], world, cfg)
                curves.append(row, algo=cfg.algo)
                bar.update(task, advance=1, stats=_progress_line(row, total))
                if not console.is_terminal and upd % 10 == 0:
                    console.print(_progress_line(row, total), highlight=False, soft_wrap=True)
                last = row
            val: dict[str, Any] = {}
            for greedy, prefix in ((True, "val_"), (False, "val_sampled_")):
                if cfg.val_episodes > 0:
                    res = evaluate(world, policy, 2 * cfg.train_seed_offset + cfg.seed,
                                   cfg.val_episodes, batch=min(cfg.val_episodes, 288),
                                   greedy=greedy)
                    val |= {prefix + k: v for k, v in res.summary(world).items()
                            if k in ("elratio_mean", "success_rate", "reward_mean",
                                     "collisions_mean", "block_collisions_mean")}
            meta = {"command": commands[-1], "commands": commands, "seed": cfg.seed,
                    "epoch": epoch + 1, "update": upd, "episodes": upd * cfg.batch,
                    "provenance": provenance(), **val}
            payload = policy.payload(meta)
            payload["train"] = {"config": dataclasses.asdict(cfg), "optimizer": opt.state_dict(),
                                "rng": torch.get_rng_state(), "epoch": epoch + 1, "update": upd,
                                "curriculum": dataclasses.asdict(cur),
                                "elapsed_s": elapsed0 + time.perf_counter() - start}
            # the epoch's row first: a kill before the checkpoint lands drops it on resume (it is
            # past the last checkpoint's update); one after keeps it
            curves.note({"kind": "epoch", "update": upd, "epoch": epoch + 1,
                         "curriculum_level": cur.level, **val})
            save_checkpoint(ckpt_path, payload)
            plot_curve(curves.csv, out / "curve.png", f"{cfg.policy}: {commands[0]}" + (
                f" (resumed {len(commands) - 1}x)" if len(commands) > 1 else ""))
            console.print(f"epoch {epoch + 1}/{cfg.epochs}  update {upd}  train elratio "
                          f"{last.get('elratio', float('nan')):.3f}  "
                          + "  ".join(f"{k} {v:.3f}" for k, v in val.items()), highlight=False,
                          soft_wrap=True)
    return last
