"""Benchmarks that print figures (`swarm bench env|policy`): world throughput and planning time.

`bench_env` times the batched world step *with* the decentralized view (observation patches and
trajectory messages, `world.decentral.batch_view`), as the evaluator and trainer pay it every
tick. `bench_policy` times one team decision (G = 1, every robot a receiver) on states reached
by the policy itself on seeded maps, the per-decision figure of the paper's Table 1.
"""

from __future__ import annotations

import dataclasses
import statistics
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from policies import PLUGINS, loadable
from swarm.common.policy_spec import build_inference, build_policy, resolve_policies
from swarm.learn.evaluate import acted
from world import core
from world.config import ConfigError, WorldConfig, check_seed
from world.decentral import View, batch_view, heard_by, robot_view

# Project bars for `bench policy` (median ms per team decision, 10 robots).
POLICY_BARS_MS: dict[str, float] = {
    "nearest-frontier": 1.0, "coordinated-frontier": 3.0, "cost-utility": 3.0,
    "commattn": 3.0,  # (the README's Speed table: its bar for the learned policy)
}
ENV_BAR = (1024, 4_000_000.0)  # agent-steps/s wanted at this batch size (N = 10)


class ProgressSink(Protocol):
    """Where long runs report progress; the CLI passes a rich progress bar, tests pass nothing."""

    def start(self, label: str, total: int) -> None: ...

    def advance(self, n: int = 1) -> None: ...


class NullProgress:
    """A progress sink that shows nothing."""

    def start(self, label: str, total: int) -> None:
        pass

    def advance(self, n: int = 1) -> None:
        pass


def int_list(value: Any, name: str, hi: int = 16384) -> tuple[int, ...]:
    """'1,64,1024', [1, 64] or 5 -> a non-empty tuple of distinct ints in [1, hi] (ConfigError
    otherwise: an empty entry or a repeat is a typo, not a row to drop or run twice)."""
    items = value.split(",") if isinstance(value, str) else value
    items = items if isinstance(items, (list, tuple)) else [items]
    try:
        out = tuple(int(str(v).strip()) for v in items)
    except (TypeError, ValueError):
        raise ConfigError(f"{name} must be comma-separated integers, got {value!r}") from None
    if not out or min(out) < 1 or max(out) > hi or len(set(out)) != len(out):
        shown = value if isinstance(value, str) else ",".join(str(v) for v in items)
        raise ConfigError(f"{name} must be distinct integers in [1, {hi}], got {shown}")
    return out


def name_list(value: Any) -> tuple[str, ...]:
    """Policy names from 'a,b', ['a', 'b'] or 'all', checked against the registry."""
    return tuple(resolve_policies(value if isinstance(value, str) else list(value)))


def _positive(name: str, value: int, hi: int = 1_000_000) -> None:
    """A count in [1, hi]: a huge one would run for days, not fail."""
    if not 1 <= value <= hi:
        raise ConfigError(f"{name} must lie in [1, {hi}], got {value}")


@dataclass(frozen=True)
class EnvBenchConfig:
    """Options of `swarm bench env` (TOML table `[bench.env]`)."""

    batches: tuple[int, ...] = (1, 64, 1024)
    """Batch sizes B to time."""
    repeats: int = 5
    """Timed repeats per batch size; the figure is their median."""
    episodes: int = 2
    """Full episodes (T steps each) per repeat."""
    seed: int = 0
    """Seed of the maps and of the random actions."""
    json: str | None = None
    """Write the figures to this JSON file."""

    def __post_init__(self) -> None:
        object.__setattr__(self, "batches", int_list(self.batches, "batches"))
        check_seed(self.seed)
        _positive("repeats", self.repeats, 1000)
        _positive("episodes", self.episodes)


@dataclass(frozen=True)
class PolicyBenchConfig:
    """Options of `swarm bench policy` (TOML table `[bench.policy]`)."""

    policies: tuple[str, ...] = field(default_factory=loadable)
    """Policies to time (default: every registered one; a plugin that does not import is
    skipped with a warning line)."""
    decisions: int = 150
    """Timed team decisions per policy (whole episodes are run; surplus ticks are dropped)."""
    warmup: int = 1
    """Untimed warm-up episodes per policy."""
    seed: int = 0
    """Seed of the maps."""
    one_robot: bool = False
    """Time one robot's decision as a robot process makes it (numpy networks; its own view of
    what it heard; a chained policy prepares, then decodes with its predecessor's message)
    instead of the team's."""
    json: str | None = None
    """Write the figures to this JSON file."""

    def __post_init__(self) -> None:
        object.__setattr__(self, "policies", name_list(self.policies))
        check_seed(self.seed)
        _positive("decisions", self.decisions)
        if not 0 <= self.warmup <= 100_000:
            raise ConfigError(f"warmup must lie in [0, 100000], got {self.warmup}")


def copy_state(state: core.WorldState) -> core.WorldState:
    """A deep copy of a batched world state (every array copied)."""
    changes = {f.name: getattr(state, f.name).copy() for f in dataclasses.fields(state)
               if isinstance(getattr(state, f.name), np.ndarray)}
    return dataclasses.replace(state, **changes)


def bench_env(world: WorldConfig, cfg: EnvBenchConfig,
              progress: ProgressSink | None = None) -> dict[str, Any]:
    """Agent-steps/s of `batch_view` + `core.step` for each batch size (median over repeats).

    Maps are generated once per batch size (untimed, reported as `reset_ms_per_episode`); each
    episode restarts from a copy of them with fresh uniformly random actions.
    """
    progress = progress or NullProgress()
    rows: list[dict[str, Any]] = []
    _episode_loop(world, copy_state(core.reset(world, cfg.seed, [0])), np.zeros(  # warm-up
        (world.horizon, 1, world.n_robots), dtype=np.int64))
    for b in cfg.batches:
        progress.start(f"env B={b}", cfg.repeats)
        t0 = time.perf_counter()
        start = core.reset(world, cfg.seed, np.arange(b))
        reset_s = time.perf_counter() - t0
        rng = np.random.default_rng([cfg.seed, b])
        rates: list[float] = []
        cpu_rates: list[float] = []
        for _ in range(cfg.repeats):
            wall = cpu = 0.0
            for _ in range(cfg.episodes):
                state = copy_state(start)
                actions = rng.integers(0, core.N_ACTIONS, size=(world.horizon, b, world.n_robots))
                w, c = _episode_loop(world, state, actions)
                wall += w
                cpu += c
            agent_steps = cfg.episodes * world.horizon * b * world.n_robots
            rates.append(agent_steps / wall)
            cpu_rates.append(agent_steps / max(cpu, 1e-9))
            progress.advance(1)
        med = statistics.median(rates)
        rows.append({
            "batch": b, "agent_steps_per_s": med, "min": min(rates), "max": max(rates),
            "agent_steps_per_cpu_s": statistics.median(cpu_rates),
            "step_ms": 1e3 * b * world.n_robots / med,
            "reset_ms_per_episode": 1e3 * reset_s / b,
        })
    return {
        "robots": world.n_robots, "horizon": world.horizon, "seed": cfg.seed,
        "repeats": cfg.repeats, "episodes_per_repeat": cfg.episodes,
        "agent_steps_per_s": {str(r["batch"]): r["agent_steps_per_s"] for r in rows},
        "bar": {"batch": ENV_BAR[0], "agent_steps_per_s": ENV_BAR[1]},
        "rows": rows,
    }


def _episode_loop(world: WorldConfig, state: core.WorldState,
                  actions: np.ndarray) -> tuple[float, float]:
    """Run one batched episode (view, then step, every tick); (wall s, process CPU s)."""
    w0, c0 = time.perf_counter(), time.process_time()
    for t in range(world.horizon):
        batch_view(world, state)
        core.step(world, state, actions[t])
    return time.perf_counter() - w0, time.process_time() - c0


def time_decisions(world: WorldConfig, name: str, decisions: int, seed: int, warmup: int = 1,
                   checkpoint: str | None = None, progress: ProgressSink | None = None,
                   one_robot: bool = False) -> np.ndarray:
    """Wall ms of `decisions` team decisions of policy `name`, one episode (G = 1) at a time
    (`one_robot`: single-robot decisions, see `robot_decider`).

    The policy plays seeded episodes from tick 0 so its memory (maps built from what it heard)
    is what it would be mid-mission; every tick's decisions are timed, warm-up episodes' not.
    """
    reset, decide = (robot_decider if one_robot else team_decider)(world, name, checkpoint)
    progress = progress or NullProgress()
    samples: list[float] = []
    episode = 0
    while len(samples) < decisions:
        state = core.reset(world, seed, [episode])
        reset()
        timed = episode >= warmup
        while not state.done:
            actions, seconds = decide(batch_view(world, state))
            for dt in (seconds[:decisions - len(samples)] if timed else []):
                samples.append(1e3 * dt)
                progress.advance(1)
            core.step(world, state, actions)
        episode += 1
    return np.asarray(samples)


Decider = tuple[Callable[[], None], Callable[[View], tuple[np.ndarray, list[float]]]]


def team_decider(world: WorldConfig, name: str, checkpoint: str | None) -> Decider:
    """(reset, decide) timing one team decision (every robot a receiver) per tick, its answer
    checked as `swarm eval` checks it (`acted`: a few microseconds), so a plugin that raises or
    answers no move is one line naming it."""
    policy = build_policy(name, world, checkpoint)

    def decide(view: View) -> tuple[np.ndarray, list[float]]:
        t0 = time.perf_counter()
        actions = acted(policy, view)
        return actions, [time.perf_counter() - t0]

    return lambda: policy.reset(1), decide


def robot_decider(world: WorldConfig, name: str, checkpoint: str | None) -> Decider:
    """(reset, decide) timing single-robot decisions as robot processes make them: every robot
    keeps its own policy (its memory), decides on `robot_view` of what it heard, and a chained
    policy runs `prepare_chain` then `act_with_chain` with its predecessor's state and action
    from the team's decision (what its message would carry). The team's decision, untimed and
    checked as `swarm eval` checks it (`acted`), drives the episode."""
    team = build_inference(name, world, checkpoint)
    robots = [build_inference(name, world, checkpoint) for _ in range(world.n_robots)]

    def reset() -> None:
        for p in (team, *robots):
            p.reset(1)

    def decide(view: View) -> tuple[np.ndarray, list[float]]:
        d = team.decide(view) if team.chained else None  # type: ignore[attr-defined]
        actions = d.actions if d is not None else acted(team, view)
        seconds = []
        for i in np.flatnonzero(view.receivers[0]).tolist():
            rv = robot_view(world, view.seed, int(view.episodes[0]), view.tick, i,
                            heard_by(world, view, 0, i), float(view.last_reward[0, i]))
            t0 = time.perf_counter()
            if d is not None:
                prepared = robots[i].prepare_chain(rv)  # type: ignore[attr-defined]
                p = int(prepared.pred[0])
                robots[i].act_with_chain(  # type: ignore[attr-defined]
                    rv, None if p < 0 else d.state[0, p][None],
                    None if p < 0 else d.actions[0, p:p + 1], prepared=prepared)
            else:
                robots[i].act(rv)
            seconds.append(time.perf_counter() - t0)
        return actions, seconds

    return reset, decide


def timing_stats(ms: np.ndarray) -> dict[str, float]:
    """Median, p90, mean, std, min, max and count of a sample of milliseconds."""
    return {
        "median_ms": float(np.median(ms)), "p90_ms": float(np.percentile(ms, 90)),
        "mean_ms": float(ms.mean()), "std_ms": float(ms.std()),
        "min_ms": float(ms.min()), "max_ms": float(ms.max()), "decisions": int(ms.size),
    }


def bench_policy(world: WorldConfig, cfg: PolicyBenchConfig, progress: ProgressSink | None = None,
                 checkpoints: dict[str, str] | None = None,
                 skip_failing_plugins: bool = False) -> dict[str, Any]:
    """Planning ms per team decision for each policy of `cfg.policies`. A policy that raises or
    answers no move is a one-line ConfigError naming it; with `skip_failing_plugins` (the
    command times every policy, none asked for) such a plugin is skipped with a warning line,
    as one that does not import or cannot be built (`policies.loadable`)."""
    progress = progress or NullProgress()
    checkpoints = checkpoints or {}
    rows: list[dict[str, Any]] = []
    for name in cfg.policies:
        progress.start(f"plan {name}", cfg.decisions)
        try:
            ms = time_decisions(world, name, cfg.decisions, cfg.seed, cfg.warmup,
                                checkpoints.get(name), progress, cfg.one_robot)
        except ConfigError as exc:
            if not skip_failing_plugins or name not in PLUGINS:
                raise
            print(f"swarm: warning: {exc}; skipped", file=sys.stderr)
            continue
        row: dict[str, Any] = {"policy": name, **timing_stats(ms)}
        bar = None if cfg.one_robot else POLICY_BARS_MS.get(name)
        row["bar_ms"] = bar
        row["meets_bar"] = None if bar is None else row["median_ms"] <= bar
        rows.append(row)
    return {"robots": world.n_robots, "seed": cfg.seed, "decisions": cfg.decisions,
            "one_robot": cfg.one_robot, "rows": rows}
