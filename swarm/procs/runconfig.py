"""Configuration of one distributed run: `RunConfig` (what the run does) and `RunRecord`, the one
record every process of a run agrees on (world + run + faults + learner + train), served by the
world's and the learner's queryables, fetched by robots and rollout workers, and written by the
supervisor as the spec file its children read."""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import msgpack

from swarm.learn.config import MAX_WORKER_ID
from swarm.net.messages import BIG
from world.config import ConfigError, WorldConfig, from_dict, to_dict

if TYPE_CHECKING:
    from swarm.net.kernel.netns import NetnsConfig


@dataclass(frozen=True)
class RunConfig:
    """What a swarm run does; the world serves it (with the world config) to every robot."""

    run_id: str = "run"
    """Namespaces every key: `swarm/<run_id>/...`."""
    policy: str = "commattn"
    """Registry name of the policy every robot runs (default: the paper's CommAttn, from the
    shipped checkpoint)."""
    checkpoint: str | None = None
    """Checkpoint file of a learned policy (a path the robots can read)."""
    seed: int = 0
    """Episode seed: episode e of the run is episode e of `swarm eval --seed`."""
    episodes: int = 5
    """Episodes to run, numbered first_episode, first_episode + 1, ..."""
    first_episode: int = 0
    """Number of the first episode."""
    greedy: bool = True
    """Greedy (argmax) decisions; False samples with the counter-based noise."""
    clock: str = "virtual"
    """`virtual`: message timing (latency, jitter, bandwidth queues, compute time) is decided in
    virtual time against the tick's virtual deadline, so a run is a function of its seed and
    fault plan (swarm.net.channel); `real`: against the wall clock (forced by --netns)."""
    delivery: str = "radio"
    """`radio`: the world's radio owns robot-to-robot delivery (range, faults, bundles);
    `direct`: robots subscribe to one another's messages and apply range and the fault plan's
    seeded draws themselves (swarm.net.direct), for hosts where nobody owns the channel. Both
    decide identically in virtual time; on the real clock each robot times its copies on its own
    wall clock (from when each came, against its own deadline), as the radio does on its."""
    tick_timeout: float = 2.0
    """The tick's length: trajectory messages arriving after 0.8 of it (hidden-state ones after
    0.9) are late. Virtual seconds with the virtual clock; with the real clock, wall seconds the
    world waits for a tick's actions before stepping without the missing ones."""
    watchdog: float = 10.0
    """Virtual clock: wall seconds the world waits for a hung or slow robot before it steps
    without it (counted as a timeout); nobody waits this long for a lost message. At least
    MIN_WATCHDOG_S: a robot gives up on a predecessor's hidden-state message (or, with direct
    delivery, a peer's trajectory message) after a share of it, by the wall clock, so a short
    one let a loaded machine change decisions with no timeout counted."""
    restart_crashed: bool = False
    """A robot process that dies is started again. On the virtual clock a crash of the fault
    plan (or a live one) at tick t is then followed by a restart at t + 1: the world waits for
    the new process there, as for a planned restart."""
    start_timeout: float = 60.0
    """Seconds the world waits for every robot to come alive before the first tick."""
    pace: float = 0.0
    """Cap on ticks per second so a person can watch (0: as fast as the swarm goes)."""
    train: bool = False
    """Learning in the field: robots record their episodes for the learner and adopt its
    weights at episode boundaries; the world publishes each episode's rewards."""
    rollout_loss: float = 0.0
    """With `train`: each robot drops its episode record with this probability (seeded, like
    the radio's loss), a fault on the rollout traffic to the learner."""
    train_sync: bool = False
    """With `train`: lockstep. The world starts an episode only once the learner has settled
    every earlier one (trained on it, or counted it dropped) and made any update due, and every
    robot acts with that weights version; the run is then a function of its seed, like the
    batched trainer (swarm.net.learning.LearnerGate). The world waits `start_timeout` at most."""

    def __post_init__(self) -> None:
        from swarm.net.keys import check_run_id

        try:
            check_run_id(self.run_id)
        except ValueError as exc:
            raise ConfigError(str(exc)) from None
        def check(name: str, lo: float, hi: float) -> None:
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and lo <= v <= hi):  # also NaN
                raise ConfigError(f"{name} must lie in [{lo}, {hi}], got {v!r}")

        big = 2**31 - 1
        check("seed", 0, big)
        check("episodes", 1, 1_000_000)
        check("first_episode", 0, big - 1_000_000)
        check("tick_timeout", 1e-3, 3600.0)
        check("start_timeout", 1e-3, 3600.0)
        check("pace", 0.0, 1000.0)
        check("rollout_loss", 0.0, 1.0)
        check("watchdog", 0.01, 3600.0)  # (a recording of an older run: check_new_run)
        if self.clock not in ("virtual", "real"):
            raise ConfigError(f"clock must be 'virtual' or 'real', got {self.clock!r}")
        if self.delivery not in ("radio", "direct"):
            raise ConfigError(f"delivery must be 'radio' or 'direct', got {self.delivery!r}")
        if self.train_sync and not self.train:
            raise ConfigError("--train-sync is a training setting: it needs --train ([run] "
                              "train_sync needs train)")
        if self.rollout_loss and not self.train:
            raise ConfigError("--rollout-loss is a training setting: it needs --train ([run] "
                              "rollout_loss needs train)")
        if not isinstance(self.policy, str) or not self.policy:
            raise ConfigError("policy must be a registry name")


def check_new_run(run: RunConfig) -> RunConfig:
    """What a run started now must meet beyond what a recorded or fetched record may hold: a
    watchdog of at least MIN_WATCHDOG_S (older runs took 0.01 s; their recordings replay)."""
    if run.watchdog < MIN_WATCHDOG_S:
        raise ConfigError(f"watchdog must lie in [{MIN_WATCHDOG_S}, 3600.0], got "
                          f"{run.watchdog!r} (a robot gives up on a stalled peer's message "
                          "after a share of it, by the wall clock)")
    return run


def check_real_clock(why: str, watchdog_given: bool, faults: dict[str, Any], seed: int,
                     watchdog: str = "--watchdog") -> None:
    """A run on the real clock (`why`: what puts it there, as the refusal names it) given a
    virtual-clock setting is refused: the watchdog (named `watchdog`), a compute time."""
    from swarm.net.faults import plan_from_table

    if watchdog_given:
        raise ConfigError(f"{watchdog} is a virtual-clock setting (the real clock waits "
                          f"--tick-timeout for a tick's actions): not with {why}")
    plan = plan_from_table(faults, seed)
    if any(f.compute_ms for f in (plan.default, *plan.per_robot.values(),
                                  *plan.per_link.values())):
        raise ConfigError(f"--compute-ms (faults compute) models compute time on the virtual "
                          f"clock; with {why} the robots' own compute time counts: drop it")


def check_fault_ticks(faults: dict[str, Any], run: RunConfig, world: WorldConfig,
                      at_tick: int | None = None,
                      flags: Iterable[str] = ("crash", "hang", "restart")) -> None:
    """A fault for a run tick the run never reaches is refused: its ticks are 0 .. episodes x
    horizon - 1. The refusal names a process fault as given: its flag for the kinds in
    `flags`, else its `[faults]` key."""
    from swarm.net.faults import plan_from_table

    flags = set(flags)

    def named(kind: str, robot: int, tick: int) -> str:
        return f"--{kind} {robot}@{tick}" if kind in flags else \
            f'[faults] {kind} "{robot}@{tick}"'

    last = run.episodes * world.horizon - 1
    process = plan_from_table(faults, at_once=True).process  # (a live change's may strike now)
    late = [named(p.kind, p.robot, p.tick) for p in process
            if p.tick > last] + ([f"--at-tick {at_tick}"] if (at_tick or 0) > last else [])
    if late:
        raise ConfigError(f"{late[0]} is beyond the run's last tick {last} ({run.episodes} "
                          f"episode(s) x {world.horizon} ticks)")
    at0 = {(p.kind, p.robot) for p in process if p.tick == 0}
    both = sorted(r for k, r in at0 if k == "crash" and ("restart", r) in at0)
    if both:  # (the world waits at tick 0 for a new process the supervisor only starts later)
        raise ConfigError(f"{named('crash', both[0], 0)} {named('restart', both[0], 0)}: a "
                          "robot restarted at tick 0 is one that never crashed; give the crash "
                          "or the restart a later tick")


def leave_grace(n_robots: int) -> float:
    """Seconds a world stays up after its run's end while robots are still in it (their final
    statuses route through its session), and its supervisor waits for those statuses: 2 s, and
    0.05 s a robot past 40 (200 robots on two cores took ~7.5 s to send theirs and go; both
    waits end as soon as every robot has left or every final is in)."""
    return max(2.0, 0.05 * n_robots)


MIN_WATCHDOG_S = 0.5
"""The shortest `--watchdog` taken (it was 0.01 s: at 0.1-0.25 s a 12-robot CommAttn run
differed from its batched twin on a loaded machine, no timeout counted; review helper 99). Half
the default 1 s lease: a watchdog still catches a stopped robot before its token goes."""
MAX_WORKERS = 4096
"""Rollout workers whose next episode a learner keeps (`RunRecord.workers`); one of a further id
still works, but starts from its seed's episode 0 when restarted."""


def check_worker_next(table: Any, where: str) -> dict[int, int] | None:
    """`RunRecord.workers` (or a learner checkpoint's copy): worker ids in [0, MAX_WORKER_ID] (an
    integer or its decimal string, as JSON keys are) to episode numbers in [0, BIG], at most
    MAX_WORKERS of them; anything else a ConfigError."""
    if table is None:
        return None
    if not isinstance(table, dict) or len(table) > MAX_WORKERS:
        raise ConfigError(f"{where}: must be a table of at most {MAX_WORKERS} worker ids")
    out = {}
    for k, v in table.items():
        key = int(k) if isinstance(k, str) and k.isascii() and k.isdigit() and len(k) < 12 else k
        for what, x, hi in (("worker id", key, MAX_WORKER_ID), ("episode", v, BIG)):
            if isinstance(x, bool) or not isinstance(x, int) or not 0 <= x <= hi:
                raise ConfigError(f"{where}: {what} {x!r} is not an integer in [0, {hi}]")
        out[key] = v
    return out


@dataclass(frozen=True)
class RunRecord:
    """What every process of a run needs to agree on, as one record."""

    world: WorldConfig
    run: RunConfig = field(default_factory=RunConfig)
    faults: dict[str, Any] = field(default_factory=dict)
    """The `[faults]` table in human units (swarm.net.faults.plan_from_table reads it)."""
    learner: dict[str, Any] | None = None
    """LearnerConfig fields (swarm.procs.learning.learner) of a run that trains, else None."""
    train: dict[str, Any] | None = None
    """TrainConfig fields (swarm.learn.config) of a run that trains, else None."""
    model: dict[str, Any] | None = None
    """The learned network's config (served by the learner to rollout workers)."""
    version: int = 0
    """The learner's weights version when it answered."""
    workers: dict[int, int] | None = None
    """Rollout worker id -> the episode it plays next (served by a learner: one past the last
    episode it heard from that worker), so a worker restarted with its id goes on where it
    stopped instead of replaying its seed's episodes from 0."""
    supervised: bool = False
    """Served by a world `swarm run` started: its supervisor owns the robot processes, so a process
    fault (crash, hang, restart) has someone to carry it out; `swarm fault` refuses process faults
    to a world started by hand."""

    def to_record(self) -> dict[str, Any]:
        """A JSON- and msgpack-safe map (inf as the string 'inf')."""
        out: dict[str, Any] = {"world": to_dict(self.world), "run": dataclasses.asdict(self.run),
                               "faults": dict(self.faults), "version": self.version}
        for key in ("learner", "train", "model"):
            if getattr(self, key) is not None:
                out[key] = dict(getattr(self, key))
        if self.workers:  # (string keys, as JSON has them)
            out["workers"] = {str(k): v for k, v in dict(self.workers).items()}
        if self.supervised:
            out["supervised"] = True
        return out

    @classmethod
    def from_record(cls, rec: Any, where: str = "run record") -> RunRecord:
        """Validate and rebuild; anything missing, unknown or out of range is a ConfigError."""
        if not isinstance(rec, dict) or not isinstance(rec.get("world"), dict):
            raise ConfigError(f"{where}: not a run record (no world table)")
        unknown = set(rec) - {"world", "run", "faults", "learner", "train", "model", "version",
                              "workers", "supervised"}
        if unknown:
            raise ConfigError(f"{where}: unknown key(s) {', '.join(sorted(unknown))}")
        for key in ("run", "faults", "learner", "train", "model"):
            if rec.get(key) is not None and not isinstance(rec[key], dict):
                raise ConfigError(f"{where}: {key} must be a table")
        version = rec.get("version", 0)
        if not isinstance(version, int) or isinstance(version, bool) or version < 0:
            raise ConfigError(f"{where}: version must be a non-negative integer")
        if not isinstance(rec.get("supervised", False), bool):
            raise ConfigError(f"{where}: supervised must be true or false")
        workers = check_worker_next(rec.get("workers"), f"{where} workers")
        try:
            return cls(world=from_dict(WorldConfig, rec["world"], f"{where} world"),
                       run=from_dict(RunConfig, rec.get("run") or {}, f"{where} run"),
                       faults=dict(rec.get("faults") or {}), learner=rec.get("learner"),
                       train=rec.get("train"), model=rec.get("model"), version=version,
                       workers=workers, supervised=rec.get("supervised", False))
        except (TypeError, ValueError) as exc:
            raise ConfigError(f"{where}: {exc}") from None

    def pack(self) -> bytes:
        return msgpack.packb(self.to_record(), use_bin_type=True)

    @classmethod
    def unpack(cls, payload: bytes, where: str = "run record") -> RunRecord:
        try:
            rec = msgpack.unpackb(payload, raw=False, strict_map_key=False)
        except Exception as exc:  # msgpack raises several types; all mean "not msgpack"
            raise ConfigError(f"{where}: not msgpack ({type(exc).__name__})") from None
        return cls.from_record(rec, where)

    def write(self, path: str | Path) -> None:
        """The spec file the supervisor hands its children (atomically)."""
        from swarm.common.atomic import write_json

        write_json(path, self.to_record())

    @classmethod
    def read(cls, path: str | Path) -> RunRecord:
        try:
            with open(path) as fh:
                rec = json.load(fh)
        except (OSError, ValueError) as exc:
            raise ConfigError(f"cannot read spec {path}: {exc}") from None
        return cls.from_record(rec, f"spec {path}")


@dataclass
class SuperviseOptions:
    headless: bool = False
    """No live dashboard."""
    status_lines: bool = True
    """With `headless`: write each world status as a JSON line on stdout."""
    json_path: str | None = None
    """Write the run's result (one JSON object) here, atomically."""
    log_dir: str | None = None
    """Children's stderr goes to files here (default: a temporary directory)."""
    netns: NetnsConfig | None = None
    """Kernel-level realism (swarm/net/kernel/netns.py): world and robots in network namespaces
    joined by veth pairs, with these kernel faults on the robot links; None: everything on
    loopback."""
    secure: str | None = None
    """Certificate directory (`swarm certs`): every session on TLS with its own identity and the
    run's access control (swarm/net/security/); configs in LOG_DIR/zenoh/. None: plain TCP."""
    record: str | None = None
    """Record every message of the run into this MCAP file (a `swarm record` child process)."""
    attention: int | None = -1
    """Whose strongest attention the dashboard's map draws: -1 all, k robot k, None nobody."""
    hosts: int = 0
    """Emulated hosts (swarm/net/kernel/hosts.py): K namespaces on a bridge, a Zenoh router each."""
    command: str | None = None
    """The command line that started the run, for the result's record."""
