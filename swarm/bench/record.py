"""`swarm bench record`: what recording a run costs. Pairs of the same headless swarm run, one
plain and one with `--record`, interleaved so that a shared machine's drift hits both alike;
medians of ticks/s and of the CPU seconds per tick of the whole process tree (the supervisor
and every child, the recorder's JSON pass after the run included), and the file sizes."""

from __future__ import annotations

import dataclasses
import resource
import shutil
import statistics
import tempfile
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from swarm.procs.runconfig import RunConfig
from swarm.procs.supervisor import SuperviseOptions, Supervisor
from world.config import ConfigError, WorldConfig, check_seed


@dataclass(frozen=True)
class RecordBenchConfig:
    """Options of `swarm bench record` (TOML table `[bench.record]`)."""

    policy: str = "nearest-frontier"
    """Policy every robot runs."""
    checkpoint: str | None = None
    """Checkpoint of a learned policy."""
    episodes: int = 3
    """Episodes per run."""
    pairs: int = 5
    """(plain, recorded) pairs; run k uses seed `seed + k` in both."""
    seed: int = 0
    """Episode seed of the first pair."""
    out: str | None = None
    """Directory for the recordings (default: a temporary one, removed at the end)."""
    json: str | None = None
    """Write the figures here."""

    def __post_init__(self) -> None:
        for name, hi in (("episodes", 10_000), ("pairs", 1000)):
            if not 1 <= getattr(self, name) <= hi:
                raise ConfigError(f"bench record: {name} must lie in [1, {hi}], got "
                                  f"{getattr(self, name)}")
        check_seed(self.seed)
        check_seed(self.seed + self.pairs - 1, "seed + pairs - 1")  # (pair k runs seed + k)


def _cpu() -> float:
    """CPU seconds of this process (the supervisor runs in it) and its children, so far."""
    return sum(ru.ru_utime + ru.ru_stime for ru in (resource.getrusage(resource.RUSAGE_SELF),
                                                     resource.getrusage(resource.RUSAGE_CHILDREN)))


def bench_record(world: WorldConfig, cfg: RecordBenchConfig,
                 progress: Callable[[dict[str, Any]], None] | None = None) -> dict[str, Any]:
    """The pairs' rows and their medians; the recordings stay in `cfg.out` if given, else go to
    a temporary folder removed at the end, an interrupted or failed run's too."""
    if cfg.out:
        Path(cfg.out).mkdir(parents=True, exist_ok=True)
        return _bench(world, cfg, Path(cfg.out), progress)
    tmp = Path(tempfile.mkdtemp(prefix="swarm-bench-record-"))
    try:
        return {**_bench(world, cfg, tmp, progress), "recordings": None}
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def _bench(world: WorldConfig, cfg: RecordBenchConfig, out: Path,
           progress: Callable[[dict[str, Any]], None] | None) -> dict[str, Any]:
    rows = []
    for k in range(cfg.pairs):
        for recorded in (False, True):
            path = out / f"run{k}.mcap"
            run = RunConfig(run_id=f"brec-{k}-{int(recorded)}", policy=cfg.policy,
                            checkpoint=cfg.checkpoint, episodes=cfg.episodes, seed=cfg.seed + k)
            opts = SuperviseOptions(headless=True, status_lines=False,
                                    record=str(path) if recorded else None)
            cpu = _cpu()
            res = Supervisor(dataclasses.replace(world), run, opts).supervise()
            cpu = _cpu() - cpu
            rows.append({"pair": k, "recorded": recorded, "ticks_per_s": res["ticks_per_s"],
                         "cpu_ms_per_tick": 1e3 * cpu / max(res["ticks"], 1),
                         "bytes": path.stat().st_size if recorded else None,
                         "recorder_exit": (res.get("recording") or {}).get("exit")})
            if progress is not None:
                progress(rows[-1])
    med = {}
    for recorded in (False, True):
        mine = [r for r in rows if r["recorded"] is recorded]
        key = "recorded" if recorded else "plain"
        med[f"ticks_per_s_{key}"] = statistics.median(r["ticks_per_s"] for r in mine)
        med[f"cpu_ms_per_tick_{key}"] = statistics.median(r["cpu_ms_per_tick"] for r in mine)
    sizes = [r["bytes"] for r in rows if r["recorded"]]
    return {"policy": cfg.policy, "robots": world.n_robots, "episodes": cfg.episodes,
            "pairs": cfg.pairs, **med,
            "ticks_per_s_cost_pct": 100 * (1 - med["ticks_per_s_recorded"] /
                                           med["ticks_per_s_plain"]),
            "cpu_per_tick_cost_pct": 100 * (med["cpu_ms_per_tick_recorded"] /
                                            med["cpu_ms_per_tick_plain"] - 1),
            "median_bytes": statistics.median(sizes), "recordings": str(out), "rows": rows}
