"""Data-parallel REINFORCE updates: a batch's episodes split over `workers` processes.

Each process holds a copy of the policy, collects its contiguous slice of the update's episodes
(the counter-based action noise makes an episode's rollout independent of which process runs
it), and accumulates its share of the gradient; the parent sums the shares and takes the one
optimizer step. Two small exchanges per update keep the loss exactly the single-process one:

1. every part reports its advantages' moments and decision count, from which the parent forms
   the batch mean / std (advantage normalisation) and the total decision count (the loss scale);
2. every part backpropagates with those batch-wide constants and sends its gradient.

Workers are fresh interpreters (multiprocessing's spawn: forking a process with torch threads
or a Zenoh session open is unsafe), each with `threads` torch threads. They get the current
weights with every request, so they never drift from the parent. A worker that dies is a
RuntimeError in the parent with its exit code, never a hang.
"""

from __future__ import annotations

import dataclasses
import multiprocessing as mp
from multiprocessing.connection import Connection
from typing import Any

import numpy as np
import torch

from policies import policy_class
from policies.learned import LearnedPolicy
from swarm.learn.config import TrainConfig
from world import core
from world.config import ConfigError, WorldConfig


def split(episodes: np.ndarray, parts: int) -> list[np.ndarray]:
    """Contiguous slices, the first ones one longer when the batch does not divide evenly."""
    return [a for a in np.array_split(episodes, parts) if len(a)]


def _worker(conn: Connection, policy_name: str, world: dict[str, Any], model: dict[str, Any],
            threads: int) -> None:
    """Worker loop: (weights, request) in, moments, then gradients out."""
    from swarm.learn import update as train
    from swarm.learn.rollout import collect
    from world.config import from_dict

    torch.set_num_threads(threads)
    torch.set_flush_denormal(True)
    wcfg = from_dict(WorldConfig, world, where="worker world")
    cls = policy_class(policy_name)
    pol = cls(wcfg, model=from_dict(cls.config_cls, model, where="worker model"))
    last: tuple[Any, ...] | None = None  # the batch of the last request (PPO passes reuse it)
    try:
        while True:
            msg = conn.recv()
            if msg is None:
                return
            if msg[0] == "again":  # another PPO pass over the same batch with new weights
                if last is None:
                    raise RuntimeError("a PPO pass before any batch")
                pol.net.load_state_dict(msg[1])
                pol.net.zero_grad(set_to_none=True)
                totals = train.backward(pol, *last)
                conn.send(([p.grad for p in pol.net.parameters()], totals, None))
                continue
            state, level_world, seed, episodes, cfg_d, faults = msg
            cfg = TrainConfig(**cfg_d)
            pol.net.load_state_dict(state)
            roll = collect(pol, from_dict(WorldConfig, level_world, where="level"), seed,
                           episodes, faults, cfg.tick_s, cfg.imitate, cfg.imitate_samples)
            adv = train.advantages(roll, cfg)
            conn.send(adv.moments())
            moments = conn.recv()
            if moments is None:  # the parent stopped between the two halves (Ctrl-C)
                return
            mean, std, decisions = moments
            pol.net.zero_grad(set_to_none=True)
            last = (roll, adv, cfg, mean, std, decisions)
            totals = train.backward(pol, *last)
            grads = [None if p.grad is None else p.grad for p in pol.net.parameters()]
            m = roll.metrics
            conn.send((grads, totals, {k: getattr(m, k) for k in core.METRIC_NAMES}))
    except (EOFError, BrokenPipeError, ConnectionResetError, KeyboardInterrupt):
        return  # the parent is gone (killed, even with SIGKILL) or stopping: leave quietly


class ParallelUpdater:
    """`update(policy, opt, level_world, seed, episodes, cfg, faults)` over this process and
    `workers - 1` spawned ones; use as a context manager (workers end with it)."""

    def __init__(self, policy: LearnedPolicy, world: WorldConfig, workers: int,
                 threads: int = 1) -> None:
        if workers < 1:
            raise ConfigError(f"workers must be >= 1, got {workers}")
        from world.config import to_dict

        ctx = mp.get_context("spawn")
        self.procs: list[Any] = []
        self.conns: list[Connection] = []
        for _ in range(workers - 1):
            parent, child = ctx.Pipe()
            proc = ctx.Process(target=_worker, daemon=True,
                               args=(child, policy.name, to_dict(world),
                                     dataclasses.asdict(policy.model_cfg), threads))
            proc.start()
            child.close()
            self.procs.append(proc)
            self.conns.append(parent)

    def __enter__(self) -> ParallelUpdater:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        for conn in self.conns:
            try:
                conn.send(None)
            except (BrokenPipeError, OSError):
                pass
        for proc in self.procs:
            proc.join(timeout=5)
            if proc.is_alive():
                proc.kill()
        self.procs, self.conns = [], []

    def _recv(self, k: int) -> Any:
        try:
            return self.conns[k].recv()
        except EOFError:
            code = self.procs[k].exitcode
            raise RuntimeError(f"training worker {k + 1} died (exit code {code})") from None

    def update(self, policy: LearnedPolicy, opt: torch.optim.Optimizer,
               level_world: WorldConfig, seed: int, episodes: np.ndarray, cfg: TrainConfig,
               faults: Any = None) -> tuple[core.EpisodeMetrics, dict[str, float]]:
        """Collect `episodes` across the processes and take one REINFORCE step (PPO: its passes)."""
        from swarm.learn import update as train
        from swarm.learn.rollout import collect
        from world.config import to_dict

        slices = split(episodes, len(self.conns) + 1)
        mine, theirs = slices[0], slices[1:]
        state = {k: v.detach().clone() for k, v in policy.net.state_dict().items()}
        cfg_d = dataclasses.asdict(cfg)
        for conn, eps in zip(self.conns, theirs, strict=False):
            conn.send((state, to_dict(level_world), seed, eps, cfg_d, faults))
        roll = collect(policy, level_world, seed, mine, faults, cfg.tick_s, cfg.imitate,
                       cfg.imitate_samples)
        adv = train.advantages(roll, cfg)
        moments = [adv.moments()] + [self._recv(k) for k in range(len(theirs))]
        mean, std, decisions = train.normaliser(moments)
        for conn in self.conns[:len(theirs)]:
            conn.send((mean, std, decisions))
        opt.zero_grad(set_to_none=True)
        totals = train.backward(policy, roll, adv, cfg, mean, std, decisions)
        m = roll.metrics
        metrics = {k: [getattr(m, k)] for k in core.METRIC_NAMES}
        params = list(policy.net.parameters())
        for k in range(len(theirs)):
            grads, part, met = self._recv(k)
            self._add(params, grads)
            for key, val in part.items():
                totals[key] = totals.get(key, 0.0) + val
            for key in core.METRIC_NAMES:
                metrics[key].append(met[key])
        totals["grad_norm"] = train.step(policy, opt, cfg)
        passes = [totals]
        for _ in range(cfg.ppo_epochs - 1 if cfg.algo == "ppo" else 0):
            state = {k: v.detach().clone() for k, v in policy.net.state_dict().items()}
            for conn in self.conns[:len(theirs)]:
                conn.send(("again", state))
            opt.zero_grad(set_to_none=True)
            again = train.backward(policy, roll, adv, cfg, mean, std, decisions)
            for k in range(len(theirs)):
                grads, part, _ = self._recv(k)
                self._add(params, grads)
                for key, val in part.items():
                    again[key] = again.get(key, 0.0) + val
            again["grad_norm"] = train.step(policy, opt, cfg)
            passes.append(again)
        joined = core.EpisodeMetrics(**{k: np.concatenate(v) for k, v in metrics.items()})
        return joined, train.merge_passes(passes)

    @staticmethod
    def _add(params: list[torch.nn.Parameter], grads: list[torch.Tensor | None]) -> None:
        for p, g in zip(params, grads, strict=True):
            if g is not None:
                p.grad = g.clone() if p.grad is None else p.grad.add_(g)
