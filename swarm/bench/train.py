"""`swarm bench train`: seconds per REINFORCE update (rollout + step) of a learned policy."""

from __future__ import annotations

import statistics
import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from policies import make_policy
from swarm.learn.config import TrainConfig
from world.config import ConfigError, WorldConfig, check_seed


@dataclass(frozen=True)
class TrainBenchConfig:
    """Options of `swarm bench train` (TOML table `[bench.train]`)."""

    policy: str = "commattn"
    """Learned policy timed."""
    batch: int = 288
    """Episodes per update (rollout of `batch` 30-step episodes + the REINFORCE step)."""
    updates: int = 3
    """Timed updates after one untimed warm-up; the figures are medians."""
    threads: int = 2
    """torch threads per process."""
    workers: int = 1
    """Training processes (see `swarm train --workers`)."""
    seed: int = 0
    """Seed of the network and the training episodes."""
    json: str | None = None
    """Write the figures to this JSON file."""

    def __post_init__(self) -> None:
        check_seed(self.seed)
        for key, hi in (("batch", 100_000), ("updates", 100_000), ("threads", 256),
                        ("workers", 64)):
            if not 1 <= getattr(self, key) <= hi:
                raise ConfigError(f"{key} must lie in [1, {hi}], got {getattr(self, key)}")
        from policies import check_learned

        check_learned(self.policy, "bench train")


def bench_train(policy: str = "commattn", batch: int = 288, updates: int = 3, threads: int = 2,
                world: WorldConfig | None = None, seed: int = 0,
                workers: int = 1) -> dict[str, Any]:
    """Seconds per update (rollout of `batch` episodes + REINFORCE step) on the full world;
    the first update is a warm-up and not counted. Median figures. With one process the
    rollout and learning parts are timed apart; with several they overlap."""
    import torch  # here, not at import: the CLI builds this parser in every process

    from swarm.learn.parallel import ParallelUpdater
    from swarm.learn.rollout import collect
    from swarm.learn.update import update

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
