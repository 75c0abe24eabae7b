"""`swarm bench swarm`: real swarm runs per (policy, team size): ticks/s, seconds to the first
tick, RSS and PSS of a robot and of the world, CPU ms per tick by process kind, and where a
tick's wall time goes in the world (observations out, trajectories in, radio, decisions with the
hidden-state chain, step and status)."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

from swarm.procs.runconfig import RunConfig
from swarm.procs.supervisor import SuperviseOptions, Supervisor
from world.config import ConfigError, WorldConfig


@dataclass(frozen=True)
class SwarmBenchConfig:
    """Options of `swarm bench swarm` (TOML table `[bench.swarm]`)."""

    robots: tuple[int, ...] = (10, 25, 50)
    """Team sizes to run."""
    policies: tuple[str, ...] = ("nearest-frontier",)
    """Policies to run (each robot process runs the policy)."""
    episodes: int = 5
    """Episodes per run (ticks/s is measured over all of them)."""
    seed: int = 0
    """Episode seed."""
    checkpoint: str | None = None
    """Checkpoint for a learned policy."""
    json: str | None = None
    """Write the figures here."""

    def __post_init__(self) -> None:
        if self.episodes < 1 or not self.robots or min(self.robots) < 1:
            raise ConfigError("bench swarm needs episodes >= 1 and robot counts >= 1")


def bench_swarm(world: WorldConfig, cfg: SwarmBenchConfig, progress: Any = None) -> dict[str, Any]:
    rows = []
    for policy in cfg.policies:
        for n in cfg.robots:
            wcfg = dataclasses.replace(world, n_robots=n)
            run = RunConfig(run_id=f"bench-{policy}-{n}"[:60], policy=policy, episodes=cfg.episodes,
                            seed=cfg.seed, checkpoint=cfg.checkpoint)
            opts = SuperviseOptions(headless=True, status_lines=False)
            res = Supervisor(wcfg, run, opts).supervise()
            rows.append({"policy": policy, "robots": n, "size": f"{wcfg.height}x{wcfg.width}",
                         "ticks_per_s": res["ticks_per_s"], "startup_s": res["startup_s"],
                         "rss_mb_per_robot": res["rss_mb_per_robot"],
                         "pss_mb_per_robot": res.get("pss_mb_per_robot"),
                         "rss_mb_world": res["rss_mb_world"],
                         "pss_mb_world": res.get("pss_mb_world"),
                         "cpu_ms_per_tick": res.get("cpu_ms_per_tick", {}),
                         "tick_ms": res.get("tick_ms", {}),
                         "chain_ms_by_depth": res.get("chain_ms_by_depth"),
                         "elratio_mean": res["elratio_mean"],
                         "timeouts": res["timeouts"], "ticks": res["ticks"],
                         "completed": res.get("completed"), "robots_lost": res.get("robots_lost"),
                         "bad": res.get("messages", {}).get("bad")})
            if progress is not None:
                progress(rows[-1])
    return {"rows": rows, "episodes": cfg.episodes, "seed": cfg.seed}
