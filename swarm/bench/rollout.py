"""`swarm bench rollout --workers 1,2`: episodes/s a gather-only learner receives from K rollout
workers over Zenoh on loopback (real processes: one learner as the router, K worker clients).

For each K the learner starts, then K workers; once the first episode has arrived the bench
waits `warmup` seconds and then counts the episodes the learner reports over `seconds`. Every
process is stopped before the next K. Figures are medians of `repeats` windows of that length.
"""

from __future__ import annotations

import dataclasses
import shutil
import statistics
import subprocess
import tempfile
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import zenoh

from swarm.bench.micro import int_list
from swarm.common.spawn import child_env, cli_args, last_error, start_child, wait_port
from swarm.learn.config import check_worker
from swarm.net.keys import Keys
from swarm.net.messages import K_LSTATUS, BadMessage, unpack_record
from swarm.net.zconfig import ZenohOptions, free_port
from world.config import ConfigError


@dataclass(frozen=True)
class RolloutBenchConfig:
    """Options of `swarm bench rollout` (TOML table `[bench.rollout]`)."""

    workers: tuple[int, ...] = (1, 2)
    """Worker counts to measure."""
    policy: str = "commattn"
    """Learned policy the workers run."""
    batch: int = 16
    """Episodes per worker batch."""
    threads: int = 1
    """torch threads per worker."""
    seconds: float = 10.0
    """Length of one measuring window."""
    repeats: int = 3
    """Windows per worker count (the median is reported)."""
    warmup: float = 3.0
    """Seconds after the first episode before measuring."""
    json: str | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "workers", int_list(self.workers, "workers", 64))
        if not 1 <= self.repeats <= 1000:
            raise ConfigError(f"bench rollout: repeats must lie in [1, 1000], got {self.repeats}")
        for name, lo_open in (("seconds", True), ("warmup", False)):
            v = getattr(self, name)  # (NaN fails both comparisons)
            if not ((0 < v) if lo_open else (0 <= v)) or not v <= 3600:
                raise ConfigError(f"bench rollout: {name} must lie in "
                                  f"{'(' if lo_open else '['}0, 3600], got {v}")
        # what the learner and every worker would refuse, refused before any is spawned
        check_worker(0, self.batch, self.threads, 0, 30.0)
        from policies import check_learned

        # (the workers sample it and a learner takes its weights)
        check_learned(self.policy, "bench rollout")


def measure(k: int, cfg: RolloutBenchConfig, tmp: Path) -> dict[str, Any]:
    port = free_port()
    hub = f"tcp/127.0.0.1:{port}"
    run_id = f"benchroll{k}"
    procs: list[subprocess.Popen[bytes]] = []
    status: list[tuple[float, int, int]] = []  # (monotonic, episodes, bytes)
    lock = threading.Lock()

    def on_status(s: zenoh.Sample) -> None:
        try:
            rec = unpack_record(s.payload.to_bytes(), K_LSTATUS)
        except BadMessage:
            return
        with lock:
            status.append((time.monotonic(), int(rec["episodes"]), int(rec["rollout_bytes"])))

    log = open(tmp / f"bench-{k}.log", "ab")  # noqa: SIM115
    try:
        procs.append(start_child(
            cli_args("learner", "--run-id", run_id, "--policy", cfg.policy, "--gather-only",
                     "--out", str(tmp / f"learner{k}"), "--zenoh-mode", "router", "--listen", hub),
            stdout=subprocess.DEVNULL, stderr=log, stdin=subprocess.DEVNULL, env=child_env()))
        try:
            wait_port("127.0.0.1", port, procs[0], 60.0, "learner")
        except (RuntimeError, TimeoutError) as exc:
            why = last_error(Path(log.name))
            raise RuntimeError(f"{exc}{': ' + why if why else ''}; see {log.name}") from None
        with zenoh.open(ZenohOptions(mode="client", connect=[hub]).to_config()) as session:
            sub = session.declare_subscriber(Keys(run_id).learner_status, on_status)
            for w in range(k):
                procs.append(start_child(
                    cli_args("rollout-worker", "--run-id", run_id, "--worker-id", str(w),
                             "--batch", str(cfg.batch), "--threads", str(cfg.threads),
                             "--connect", hub, "--zenoh-mode", "client"),
                    stdout=subprocess.DEVNULL, stderr=log, stdin=subprocess.DEVNULL,
                    env=child_env()))
            deadline = time.monotonic() + 120
            while time.monotonic() < deadline:
                with lock:
                    if status and status[-1][1] > 0:
                        break
                if any(p.poll() is not None for p in procs):
                    why = last_error(Path(log.name))
                    raise RuntimeError(f"a bench process exited early"
                                       f"{': ' + why if why else ''}; see {log.name}")
                time.sleep(0.1)
            else:
                raise RuntimeError(f"no episode reached the learner within 120 s; see {log.name}")
            time.sleep(cfg.warmup)
            rates, byte_rates = [], []
            for _ in range(cfg.repeats):
                with lock:
                    t0, e0, b0 = status[-1]
                time.sleep(cfg.seconds)
                with lock:
                    t1, e1, b1 = status[-1]
                rates.append((e1 - e0) / max(t1 - t0, 1e-9))
                byte_rates.append((b1 - b0) / max(t1 - t0, 1e-9))
            sub.undeclare()
    finally:
        for p in procs:
            if p.poll() is None:
                p.terminate()
        for p in procs:
            try:
                p.wait(timeout=5)
            except subprocess.TimeoutExpired:
                p.kill()
        log.close()
    return {"workers": k, "episodes_per_s": statistics.median(rates),
            "episodes_per_s_windows": rates, "rollout_bytes_per_s": statistics.median(byte_rates)}


def bench_rollout(cfg: RolloutBenchConfig, on_row: Any = None) -> dict[str, Any]:
    """Every worker count of `cfg`, measured; the processes' logs go to a temporary folder,
    removed after a good run and kept after a failed one (its error names the log)."""
    rows = []
    tmp = Path(tempfile.mkdtemp(prefix="swarm-bench-rollout-"))
    ok = False
    try:
        for k in cfg.workers:
            row = measure(k, cfg, tmp)
            if rows:
                row["speedup"] = row["episodes_per_s"] / max(rows[0]["episodes_per_s"], 1e-9)
            else:
                row["speedup"] = 1.0
            rows.append(row)
            if on_row:
                on_row(row)
        ok = True
    except KeyboardInterrupt:
        ok = True  # nothing failed: nothing to read
        raise
    finally:
        if ok:
            shutil.rmtree(tmp, ignore_errors=True)
    return {"config": dataclasses.asdict(cfg), "rows": rows}
