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
import hashlib
import json
import shutil
import statistics
from dataclasses import dataclass
from typing import Any

from swarm.common.spawn import TROUBLE
from swarm.procs.runconfig import RunConfig
from swarm.procs.supervisor import SuperviseOptions, Supervisor
from world.config import ConfigError, WorldConfig, check_seed


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
    hosts: int = 0
    """Emulated hosts (`swarm run --hosts K`, root); 0: one host, loopback."""
    secure: str | None = None
    """Certificate directory: every run is made twice a round, without and with `--secure DIR`
    (order alternating), the second listed as POLICY+secure; its ratio to the first policy is
    the secure mode's speed cost."""

    def __post_init__(self) -> None:
        check_seed(self.seed)
        if self.episodes < 1 or not self.robots or min(self.robots) < 1:
            raise ConfigError("bench swarm needs episodes >= 1 and robot counts >= 1")
        if len(set(self.robots)) != len(self.robots) or \
                len(set(self.policies)) != len(self.policies):
            raise ConfigError("bench swarm robots and policies must be distinct (a repeat is a "
                              "typo, not a row to run twice: --repeats runs rounds)")
        if not 1 <= self.repeats <= 100:
            raise ConfigError(f"bench swarm repeats must be in 1..100, got {self.repeats}")
        if self.delivery not in ("radio", "direct"):
            raise ConfigError(f"bench swarm delivery must be 'radio' or 'direct', "
                              f"got {self.delivery!r}")
        if self.hosts < 0:
            raise ConfigError(f"bench swarm hosts must be >= 0, got {self.hosts}")

    def check(self) -> None:
        """Hosts and certificates usable for every team size, before any run (one line)."""
        if self.hosts:
            from swarm.net.kernel.hosts import MAX_HOSTS, check_host_count, hosts_reason

            check_host_count(self.hosts, min(self.robots), "bench swarm hosts")
            reason = hosts_reason() if self.hosts <= MAX_HOSTS else f"at most {MAX_HOSTS} hosts"
            if reason:
                raise ConfigError(reason)
        if self.secure:
            from swarm.net.security.tls import Secure, topology_secure

            n = max(self.robots)
            if self.hosts:
                topology_secure(self.secure, "bench", n, self.hosts)
            else:
                Secure.load(self.secure, "supervisor", "bench", n,
                            need=("world", *(f"robot-{i}" for i in range(n))))


def bench_swarm(world: WorldConfig, cfg: SwarmBenchConfig, progress: Any = None) -> dict[str, Any]:
    cfg.check()
    modes = (False, True) if cfg.secure else (False,)
    rows = []
    for rnd in range(cfg.repeats):
        for policy in cfg.policies:
            for n in cfg.robots:
                for secure in modes if rnd % 2 == 0 else modes[::-1]:
                    rows.append({**_one_run(world, cfg, policy, n, secure), "round": rnd})
                    if progress is not None:
                        progress(rows[-1])
    names = tuple(f"{p}{tag}" for p in cfg.policies for tag in ("", "+secure")[:len(modes)])
    return {"rows": rows, "episodes": cfg.episodes, "seed": cfg.seed, "repeats": cfg.repeats,
            "delivery": cfg.delivery, "hosts": cfg.hosts, "secure": cfg.secure,
            "summary": summarize(rows, names, cfg.robots)}


def _one_run(world: WorldConfig, cfg: SwarmBenchConfig, policy: str, n: int,
             secure: bool = False) -> dict[str, Any]:
    wcfg = dataclasses.replace(world, n_robots=n)
    run = RunConfig(run_id=f"bench-{policy}-{n}{'s' if secure else ''}"[:60], policy=policy,
                    episodes=cfg.episodes, seed=cfg.seed, checkpoint=cfg.checkpoint,
                    delivery=cfg.delivery)
    opts = SuperviseOptions(headless=True, status_lines=False, hosts=cfg.hosts,
                            secure=cfg.secure if secure else None)
    res = Supervisor(wcfg, run, opts).supervise()
    if res.get("logs") and not any(res.get(k) for k in TROUBLE):  # a clean secure run's session
        shutil.rmtree(res.pop("logs"), ignore_errors=True)  # configs: kept by a run, not here
    return {"policy": f"{policy}+secure" if secure else policy, "robots": n,
            "logs": res.get("logs"),  # (a run in trouble keeps its folder: named)
            "size": f"{wcfg.height}x{wcfg.width}",
            "actions_sha1": hashlib.sha1(json.dumps(res["actions"]).encode()).hexdigest()[:12],
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
    rounds of its ticks/s divided by the first policy's in the same round (for `P+secure`: by
    `P`'s without --secure, the secure mode's cost)."""
    speed = {(r["policy"], r["robots"], r["round"]): r["ticks_per_s"] for r in rows}
    rounds = sorted({r["round"] for r in rows})
    out = []
    for policy in policies:
        for n in robots:
            tps = [speed[(policy, n, k)] for k in rounds if (policy, n, k) in speed]
            ref = policy.removesuffix("+secure") if policy.endswith("+secure") else policies[0]
            ratios = [speed[(policy, n, k)] / speed[(ref, n, k)] for k in rounds
                      if (policy, n, k) in speed and speed.get((ref, n, k), 0) > 0]
            out.append({"policy": policy, "robots": n, "ticks_per_s": tps,
                        "ticks_per_s_median": statistics.median(tps) if tps else None,
                        "vs_first": ratios,
                        "vs_first_median": statistics.median(ratios) if ratios else None})
    return out
