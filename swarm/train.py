"""REINFORCE with a state-specific baseline for the learned policies (paper sections 3 and 4.3).

Reads top to bottom: config, rollout, loss, curriculum, the training loop, the benchmark.

Per update: `batch` episodes run batched on the world core with sampled actions (counter-based
noise, the same code path the evaluator and swarm use); per robot j and tick t the return
G_t = sum_{k >= t} gamma^(k - t) r_k; the loss is the paper's

    loss_j = sum_t [ -log p(a_t | s_t) (G_t - b(s_t)) + alpha (G_t - b(s_t))^2 ]

summed over robots and averaged over episodes, with b detached in the first term, plus an
optional entropy bonus. Episodes of update u are episodes u*batch .. of the training seed
`train_seed_offset + seed`, disjoint from the evaluation seeds (0, 1, ...): a run is a pure
function of its config, and `--resume` continues exactly.
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import dataclasses
import io
import json
import math
import statistics
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from policies import make_policy
from policies.checkpoint import CheckpointError, load_checkpoint, save_checkpoint
from policies.features import Members
from policies.learned import LearnedPolicy
from swarm.evaluate import apply_faults, evaluate
from swarm.repro import plot_curve
from swarm.faults import FaultPlan, plan_from_table
from swarm.train_config import TrainConfig, add_arguments, from_args  # noqa: F401
from swarm.train_parallel import ParallelUpdater
from world import core
from world.config import ConfigError, WorldConfig, from_dict, replace
from world.decentral import TrajMessages, View, batch_view


@dataclass
class Rollout:
    """One batch of finished episodes, arrays [T, B, N] unless noted."""

    views: list[View]
    actions: list[np.ndarray]  # T of [B, N]
    inputs: list[Members]  # T features computed at acting time (reused by the update)
    value: np.ndarray  # b(s) at acting time (for the advantage)
    reward: np.ndarray
    metrics: core.EpisodeMetrics
    logp: np.ndarray | None = None  # log pi(a) under the weights that acted (0 off receivers)
    stale: np.ndarray | None = None  # [B] bool: acted by older weights than the learner's now


def frozen(view: View) -> View:
    """A copy of a view that later world steps cannot change (the core mutates state in place)."""
    m = view.msgs
    msgs = TrajMessages(m.pos.copy(), m.visited.copy(), m.recent.copy(), m.patch.copy(),
                        m.present.copy())
    return dataclasses.replace(view, episodes=view.episodes.copy(), msgs=msgs,
                               receivers=view.receivers.copy(), last_reward=view.last_reward.copy())


def train_faults(cfg: TrainConfig) -> FaultPlan | None:
    """The message-fault model applied during rollouts (`--train-loss`)."""
    if cfg.train_loss <= 0:
        return None
    return plan_from_table({"loss": cfg.train_loss, "seed": cfg.seed + 3_000_000})


def collect(policy: LearnedPolicy, world: WorldConfig, seed: int, episodes: np.ndarray,
            faults: FaultPlan | None = None) -> Rollout:
    """Run `episodes` of `seed` to the horizon with sampled actions."""
    state = core.reset(world, seed, episodes)
    policy.reset(len(episodes))
    views, actions, inputs, values, rewards, logp = [], [], [], [], [], []
    while not state.done:
        view = frozen(batch_view(world, state))
        if faults is not None and not faults.zero:
            apply_faults(view, faults)  # the swarm radio's message loss, during training
        d = policy.decide(view, greedy=False, keep_inputs=True)
        rewards.append(core.step(world, state, d.actions))
        views.append(view)
        actions.append(d.actions)
        inputs.append(d.inputs)
        values.append(d.value)
        p = np.take_along_axis(d.probs, d.actions[..., None], -1)[..., 0]
        logp.append(np.log(np.maximum(p, 1e-30), dtype=np.float32) * view.receivers)
    return Rollout(views, actions, inputs, np.stack(values), np.stack(rewards),
                   core.metrics(world, state), np.stack(logp))


def returns(reward: np.ndarray, gamma: float) -> np.ndarray:
    """G_t = r_t + gamma G_{t+1} along axis 0."""
    out = np.zeros_like(reward, dtype=np.float64)
    acc = np.zeros(reward.shape[1:])
    for t in range(reward.shape[0] - 1, -1, -1):
        acc = reward[t] + gamma * acc
        out[t] = acc
    return out


# --------------------------------------------------------------------------------------- loss
@dataclass
class Advantages:
    """Returns and raw advantages of a rollout, arrays [T, B, N], and the live decisions."""

    ret: np.ndarray
    adv: np.ndarray
    live: np.ndarray

    def moments(self) -> tuple[float, float, int]:
        """(sum, sum of squares, count) of the live advantages: what batch normalisation needs
        from each part of a batch split across processes."""
        a = self.adv[self.live]
        return float(a.sum()), float((a * a).sum()), int(a.size)


def advantages(roll: Rollout, cfg: TrainConfig) -> Advantages:
    ret = returns(roll.reward * cfg.reward_scale, cfg.gamma)
    return Advantages(ret, ret - roll.value, np.stack([v.receivers for v in roll.views]))


def normaliser(moments: list[tuple[float, float, int]]) -> tuple[float, float, int]:
    """(mean, std, count) of the advantages of a whole batch from its parts' moments."""
    s1 = sum(m[0] for m in moments)
    s2 = sum(m[1] for m in moments)
    n = sum(m[2] for m in moments)
    mean = s1 / max(n, 1)
    return mean, math.sqrt(max(s2 / max(n, 1) - mean * mean, 0.0)), n


def backward(policy: LearnedPolicy, roll: Rollout, adv: Advantages, cfg: TrainConfig,
             mean: float, std: float, decisions: int) -> dict[str, float]:
    """Accumulate the gradient of this rollout's share of the loss into the parameters' .grad.

    `decisions` counts the whole batch's decisions and (mean, std) are its advantages' moments,
    so the parts of a batch split across processes add up to the gradient of the whole.
    """
    a_all = (adv.adv - mean) / (std + 1e-8) if cfg.adv_norm else adv.adv
    totals = {"loss": 0.0, "pg": 0.0, "baseline": 0.0, "entropy": 0.0}
    for t0 in range(0, len(roll.views), cfg.chunk_ticks):
        span = slice(t0, t0 + cfg.chunk_ticks)
        ev = policy.evaluate(roll.views[span], roll.actions[span], roll.inputs[span])
        at = (t0 + ev.tick, ev.group, ev.robot)
        a = torch.from_numpy(a_all[at].astype(np.float32))
        g = torch.from_numpy(adv.ret[at].astype(np.float32))
        if roll.stale is not None and roll.logp is not None and cfg.is_clip > 0:
            stale = torch.from_numpy(roll.stale[ev.group])  # their decisions: truncated IS weight
            if bool(stale.any()):
                acted = torch.from_numpy(roll.logp[at].astype(np.float32))
                rho = torch.exp(ev.logp.detach() - acted)
                w = torch.where(stale, rho.clamp(max=cfg.is_clip), 1.0)
                a = a * w
                totals["is_weight"] = totals.get("is_weight", 0.0) + float(w[stale].sum())
                totals["stale_decisions"] = totals.get("stale_decisions", 0.0) + float(
                    stale.sum())
        pg = -(ev.logp * a).sum() / decisions
        base = cfg.alpha * ((g - ev.value) ** 2).sum() / decisions
        ent = ev.entropy.sum() / decisions
        loss = pg + base - cfg.ent_coef * ent
        loss.backward()
        for key, val in (("loss", loss), ("pg", pg), ("baseline", base), ("entropy", ent)):
            totals[key] += val.item()
    return totals


def step(policy: LearnedPolicy, opt: torch.optim.Optimizer, cfg: TrainConfig) -> float:
    """Clip the accumulated gradient, take the optimizer step; returns the gradient norm."""
    params = [p for p in policy.net.parameters() if p.grad is not None]
    clip = cfg.max_grad_norm if cfg.max_grad_norm > 0 else math.inf
    norm = torch.nn.utils.clip_grad_norm_(params, clip)
    opt.step()
    return float(norm)


def update(policy: LearnedPolicy, opt: torch.optim.Optimizer, roll: Rollout,
           cfg: TrainConfig) -> dict[str, float]:
    """One REINFORCE step on a rollout; returns the loss parts per decision.

    The loss is the paper's sum over robots and ticks divided by the number of decisions in the
    batch (a constant scale, so that gradient clipping means the same for any batch size).
    """
    adv = advantages(roll, cfg)
    mean, std, decisions = normaliser([adv.moments()])
    opt.zero_grad(set_to_none=True)
    totals = backward(policy, roll, adv, cfg, mean, std, decisions)
    if totals.get("stale_decisions"):  # the mean importance weight of the stale decisions
        totals["is_weight"] /= totals["stale_decisions"]
    totals["grad_norm"] = step(policy, opt, cfg)
    return totals


# --------------------------------------------------------------------------------- curriculum
@dataclass
class Curriculum:
    """Exploration-ratio-based curriculum (paper 4.3): dynamic blocks are introduced in levels.

    Level k trains with min(k * step, n_dynamic) dynamic blocks (same add_every). After each
    update the running mean elratio is ema <- c ema + (1 - c) mean(batch elratio) (reset when a
    level starts); the level advances once it has run `min_updates` and ema >= threshold, or
    after `max_updates` regardless, until the world's own n_dynamic is reached.
    """

    level: int = 0
    updates_at_level: int = 0
    ema: float | None = None

    def world(self, world: WorldConfig, cfg: TrainConfig) -> WorldConfig:
        if cfg.curriculum_step <= 0 or not world.dynamic:
            return world
        return replace(world, n_dynamic=min(self.level * cfg.curriculum_step, world.n_dynamic))

    def observe(self, elratio: float, world: WorldConfig, cfg: TrainConfig) -> bool:
        """Record one update's mean elratio; True when the level advanced."""
        c = cfg.curriculum_ema
        self.ema = elratio if self.ema is None else c * self.ema + (1 - c) * elratio
        self.updates_at_level += 1
        if self.world(world, cfg).n_dynamic >= world.n_dynamic or cfg.curriculum_step <= 0:
            return False
        ready = (self.updates_at_level >= cfg.curriculum_min_updates
                 and self.ema >= cfg.curriculum_threshold)
        forced = 0 < cfg.curriculum_max_updates <= self.updates_at_level
        if ready or forced:
            self.level, self.updates_at_level, self.ema = self.level + 1, 0, None
            return True
        return False


# ------------------------------------------------------------------------------------ logging
CURVE_FIELDS = ["update", "epoch", "episodes", "n_dynamic", "elratio", "success", "reward",
                "collisions", "block_collisions", "entropy", "loss", "pg", "baseline", "grad_norm",
                "episodes_per_s", "elapsed_s"]


def _truncate(path: Path, keep: int, is_csv: bool) -> None:
    """Drop log rows past update `keep` (written after the checkpoint a run resumes from)."""
    if not path.exists():
        return
    lines = path.read_text().splitlines(keepends=True)
    out = lines[:1] if is_csv else []
    for line in lines[1:] if is_csv else lines:
        row = next(csv.reader([line])) if is_csv else None
        upd = int(row[0]) if is_csv else json.loads(line).get("update", 0)
        if upd <= keep:
            out.append(line)
    path.write_text("".join(out))


def _progress_line(row: dict[str, Any], total: int) -> str:
    return (f"epoch {row['epoch']} update {row['update']}/{total}  "
            f"{row['episodes_per_s']:.0f} ep/s  elratio {row['elratio']:.3f}  "
            f"success {row['success']:.2f}  reward {row['reward']:.1f}  "
            f"loss {row['loss']:.3f}  dyn {row['n_dynamic']}")


# ---------------------------------------------------------------------------------- the loop
def main(cfg: TrainConfig, world: WorldConfig, out: Path, resume: bool = False,
         console: Any | None = None) -> dict[str, Any]:
    """Train (or resume) into `out`: checkpoint.pt, log.jsonl, curve.csv. Returns the last row."""
    # Denormal floats slow CPU math ~10x in late training; flushing them is process-global
    # state, so it is on for the run only (not in the policy: other code shares the process).
    torch.set_flush_denormal(True)
    try:
        return _main(cfg, world, out, resume, console)
    finally:
        torch.set_flush_denormal(False)


def _main(cfg: TrainConfig, world: WorldConfig, out: Path, resume: bool,
          console: Any | None) -> dict[str, Any]:
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
    out.mkdir(parents=True, exist_ok=True)
    ckpt_path = out / "checkpoint.pt"
    log_path, curve_path = out / "log.jsonl", out / "curve.csv"
    cur = Curriculum()
    epoch0, upd = 0, 0
    if resume and ckpt_path.exists():
        data = load_checkpoint(ckpt_path)
        tr = data.get("train")
        if tr is None:
            raise CheckpointError(f"{ckpt_path} holds no trainer state; cannot resume")
        epochs = cfg.epochs
        cfg = from_dict(TrainConfig, tr["config"], where="checkpoint train config")
        cfg = dataclasses.replace(cfg, epochs=max(epochs, cfg.epochs))
        world = from_dict(WorldConfig, data["world"], where="checkpoint world")
        torch.set_num_threads(cfg.threads)
        policy = make_policy(cfg.policy, world, checkpoint=ckpt_path)
        opt = torch.optim.Adam(policy.net.parameters(), lr=cfg.lr)
        opt.load_state_dict(tr["optimizer"])
        torch.set_rng_state(tr["rng"])
        epoch0, upd = tr["epoch"], tr["update"]
        cur = Curriculum(**tr["curriculum"])
        _truncate(log_path, upd, is_csv=False)
        _truncate(curve_path, upd, is_csv=True)
        console.print(f"resuming {cfg.policy} from epoch {epoch0}, update {upd}")
    else:
        if ckpt_path.exists() and not resume:
            raise ConfigError(f"{out} already holds a run; pass --resume or choose another --out")
        torch.set_num_threads(cfg.threads)
        torch.manual_seed(cfg.seed)
        policy = make_policy(cfg.policy, world)
        if not isinstance(policy, LearnedPolicy):
            raise ValueError(f"policy {cfg.policy!r} is not a learned policy")
        if cfg.init:
            policy = make_policy(cfg.policy, world, checkpoint=cfg.init)
        if cfg.team_memory:
            policy.set_model(team_memory=True)
        opt = torch.optim.Adam(policy.net.parameters(), lr=cfg.lr)
        log_path.write_text("")
        curve_path.write_text(",".join(CURVE_FIELDS) + "\n")
    train_seed = cfg.train_seed_offset + cfg.seed
    total = cfg.epochs * cfg.updates
    command = " ".join(sys.argv)
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
                    roll = collect(policy, level_world, train_seed, episodes, train_faults(cfg))
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
                       "episodes_per_s": cfg.batch / dt, "elapsed_s": time.perf_counter() - start}
                cur.observe(row["elratio"], world, cfg)
                with log_path.open("a") as fh:
                    fh.write(json.dumps({"kind": "update", **row}) + "\n")
                with curve_path.open("a") as fh:
                    buf = io.StringIO()
                    csv.writer(buf).writerow([_fmt(row[k]) for k in CURVE_FIELDS])
                    fh.write(buf.getvalue())
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
            meta = {"command": command, "seed": cfg.seed, "epoch": epoch + 1, "update": upd,
                    "episodes": upd * cfg.batch, **val}
            payload = policy.payload(meta)
            payload["train"] = {"config": dataclasses.asdict(cfg), "optimizer": opt.state_dict(),
                                "rng": torch.get_rng_state(), "epoch": epoch + 1, "update": upd,
                                "curriculum": dataclasses.asdict(cur)}
            save_checkpoint(ckpt_path, payload)
            plot_curve(curve_path, out / "curve.png", f"{cfg.policy}: {command}")
            with log_path.open("a") as fh:
                fh.write(json.dumps({"kind": "epoch", "update": upd, "epoch": epoch + 1,
                                     "curriculum_level": cur.level, **val}) + "\n")
            console.print(f"epoch {epoch + 1}/{cfg.epochs}  update {upd}  train elratio "
                          f"{last.get('elratio', float('nan')):.3f}  "
                          + "  ".join(f"{k} {v:.3f}" for k, v in val.items()), highlight=False,
                          soft_wrap=True)
    return last


def _fmt(v: Any) -> Any:
    return f"{v:.6g}" if isinstance(v, float) else v


# --------------------------------------------------------------------------------------- CLI
# --------------------------------------------------------------------------------- benchmark
def bench_train(policy: str = "commattn", batch: int = 288, updates: int = 3, threads: int = 2,
                world: WorldConfig | None = None, seed: int = 0,
                workers: int = 1) -> dict[str, Any]:
    """Seconds per update (rollout of `batch` episodes + REINFORCE step) on the full world;
    the first update is a warm-up and not counted. Median figures. With one process the
    rollout and learning parts are timed apart; with several they overlap."""
    world = world or WorldConfig()
    torch.set_num_threads(threads)
    torch.manual_seed(seed)
    torch.set_flush_denormal(True)
    cfg = TrainConfig(policy=policy, batch=batch, threads=threads, workers=workers)
    pol = make_policy(policy, world)
    opt = torch.optim.Adam(pol.net.parameters(), lr=cfg.lr)
    roll_s, learn_s, per = [], [], []
    pool = ParallelUpdater(pol, world, workers, threads) if workers > 1 else None
    try:
        for u in range(updates + 1):
            episodes = u * batch + np.arange(batch)
            t0 = time.perf_counter()
            if pool is None:
                roll = collect(pol, world, cfg.train_seed_offset + seed, episodes)
                t1 = time.perf_counter()
                update(pol, opt, roll, cfg)
            else:
                pool.update(pol, opt, world, cfg.train_seed_offset + seed, episodes, cfg)
                t1 = time.perf_counter()
            t2 = time.perf_counter()
            if u > 0:
                roll_s.append(t1 - t0)
                learn_s.append(t2 - t1)
                per.append(t2 - t0)
    finally:
        torch.set_flush_denormal(False)
        if pool is not None:
            pool.close()
    out = {"policy": policy, "batch": batch, "robots": world.n_robots, "horizon": world.horizon,
           "threads": threads, "workers": workers, "updates": updates,
           "seconds_per_update": statistics.median(per),
           "episodes_per_s": batch / statistics.median(per)}
    if pool is None:
        out |= {"rollout_s": statistics.median(roll_s), "learn_s": statistics.median(learn_s)}
    return out


def cli(argv: list[str] | None = None) -> int:
    """`python -m swarm.train ...` (until `swarm train` is wired into swarm.cli)."""
    parser = argparse.ArgumentParser(prog="python -m swarm.train",
                                     description=__doc__.splitlines()[0])
    add_arguments(parser)
    parser.add_argument("--robots", type=int, default=None, help="robots N")
    parser.add_argument("--static", action="store_true", help="no dynamic blocks")
    args = parser.parse_args(argv)
    world = replace(WorldConfig(), n_robots=args.robots, dynamic=False if args.static else None)
    main(from_args(args), world, args.out, resume=args.resume)
    return 0


if __name__ == "__main__":
    sys.exit(cli())

