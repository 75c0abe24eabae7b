"""`swarm bench swarm`: real swarm runs per (policy, team size): ticks/s, seconds to the first
tick, RSS and PSS of a robot and of the world, CPU ms per tick by process kind, and where a
tick's wall time goes in the world (observations out, trajectories in, radio, decisions with the
hidden-state chain, step and status).

This machine's speed drifts by a third from run to run (and more between hours), so a speed
ratio of two runs made a minute apart says little. `repeats` runs every (policy, team size) once
per round, the rounds interleaved, and reports the median over rounds of each figure and of
each policy's per-round ratio to the first policy (the two runs of a round are seconds apart).
"""

from __future__ import annotations

import dataclasses
import statistics
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
    repeats: int = 1
    """Interleaved rounds: every (policy, team size) runs once per round; the summary gives
    medians over rounds (ticks/s and the per-round ratio to the first policy)."""
    delivery: str = "radio"
    """`radio` (the world's radio delivers, the default of `swarm run`) or `direct`."""

    def __post_init__(self) -> None:
        if self.episodes < 1 or not self.robots or min(self.robots) < 1:
            raise ConfigError("bench swarm needs episodes >= 1 and robot counts >= 1")
        if not 1 <= self.repeats <= 100:
            raise ConfigError(f"bench swarm repeats must be in 1..100, got {self.repeats}")
        if self.delivery not in ("radio", "direct"):
            raise ConfigError(f"bench swarm delivery must be 'radio' or 'direct', "
                              f"got {self.delivery!r}")


def bench_swarm(world: WorldConfig, cfg: SwarmBenchConfig, progress: Any = None) -> dict[str, Any]:
    rows = []
    for rnd in range(cfg.repeats):
        for policy in cfg.policies:
            for n in cfg.robots:
                rows.append({**_one_run(world, cfg, policy, n), "round": rnd})
                if progress is not None:
                    progress(rows[-1])
    return {"rows": rows, "episodes": cfg.episodes, "seed": cfg.seed, "repeats": cfg.repeats,
            "delivery": cfg.delivery, "summary": summarize(rows, cfg.policies, cfg.robots)}


def _one_run(world: WorldConfig, cfg: SwarmBenchConfig, policy: str, n: int) -> dict[str, Any]:
    wcfg = dataclasses.replace(world, n_robots=n)
    run = RunConfig(run_id=f"bench-{policy}-{n}"[:60], policy=policy, episodes=cfg.episodes,
                    seed=cfg.seed, checkpoint=cfg.checkpoint, delivery=cfg.delivery)
    opts = SuperviseOptions(headless=True, status_lines=False)
    res = Supervisor(wcfg, run, opts).supervise()
    return {"policy": policy, "robots": n, "size": f"{wcfg.height}x{wcfg.width}",
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
            "bad": res.get("messages", {}).get("bad")}


def summarize(rows: list[dict[str, Any]], policies: tuple[str, ...],
              robots: tuple[int, ...]) -> list[dict[str, Any]]:
    """Per (policy, team size): ticks/s of every round and their median, and the median over
    rounds of its ticks/s divided by the first policy's in the same round."""
    speed = {(r["policy"], r["robots"], r["round"]): r["ticks_per_s"] for r in rows}
    rounds = sorted({r["round"] for r in rows})
    out = []
    for policy in policies:
        for n in robots:
            tps = [speed[(policy, n, k)] for k in rounds if (policy, n, k) in speed]
            ratios = [speed[(policy, n, k)] / speed[(policies[0], n, k)] for k in rounds
                      if (policy, n, k) in speed and speed.get((policies[0], n, k), 0) > 0]
            out.append({"policy": policy, "robots": n, "ticks_per_s": tps,
                        "ticks_per_s_median": statistics.median(tps) if tps else None,
                        "vs_first": ratios,
                        "vs_first_median": statistics.median(ratios) if ratios else None})
    return out
