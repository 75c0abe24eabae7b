"""PettingZoo `ParallelEnv` adapter over `world.core`; the only module that imports pettingzoo.

    from world.pettingzoo import parallel_env
    env = parallel_env(n_robots=4, comm_range=5.0)  # WorldConfig fields; unknown keys are errors
    obs, infos = env.reset(seed=7)  # episode 0 of seed 7; then reset() -> episode 1, 2, ...

Agents are "robot_0" .. "robot_{N-1}"; actions Discrete(9) (0 stay, 1 N, 2 NE, 3 E, 4 SE, 5 S,
6 SW, 7 W, 8 NW; see `world.core.ACTIONS`); rewards are `core.step`'s. Every episode runs the
horizon T: terminations stay False, truncations turn True at step T, then `agents` empties and the
infos carry each robot's episode metrics. A missing agent in the action dict stays in place, as a
robot that missed the tick deadline does (SPEC 3.6).

Observation of robot i: one float32 Box in [0, 1] of size 3 + 3 v^2 + 2 H W (see `obs_slices`),
built from what robot i knows under SPEC section 3, i.e. its own message and those it heard:

    position         2      own (y / (H-1), x / (W-1))
    tick             1      t / T
    patch            3 v^2  own v x v patch as three row-major planes: block, off-grid, robot there
    team_visited     H W    union of the visited-cell bitmaps of the robots i heard (i included)
    heard_positions  H W    cells where a robot i heard, other than itself, stands

`encode` computes it from a `world.decentral.View`, so a batched view and one robot's own view
(`robot_view(heard_by(...))`) give the same vector.

A policy of this project inside it, on the episodes `swarm eval --robots 4 --episodes 3` plays
(seed 0), gives the same elratio (tests/test_pettingzoo.py runs this recipe):

    from swarm.common.policy_spec import build_policy  # a learned one: its shipped checkpoint
    from world.decentral import batch_view
    env = parallel_env(n_robots=4)
    policy = build_policy("nearest-frontier", env.cfg)
    elratio = []
    for ep in range(3):
        env.reset(seed=0, options={"episode": ep})
        policy.reset(1)
        while env.agents:
            a = policy.act(batch_view(env.cfg, env.world))[0]  # every robot: what it heard
            *_, infos = env.step({f"robot_{i}": int(a[i]) for i in range(4)})
        elratio.append(infos["robot_0"]["elratio"])
"""

from __future__ import annotations

import dataclasses
import warnings
from typing import Any, ClassVar

import numpy as np

try:
    from gymnasium import spaces
    from pettingzoo import ParallelEnv
except ImportError as exc:  # pragma: no cover - exercised only without the extra
    raise ImportError("world.pettingzoo needs the optional extra: "
                      "pip install 'commattn-swarm[pettingzoo]'") from exc

from world import core
from world.config import WorldConfig, check_seed, from_dict
from world.decentral import View, batch_view


def obs_slices(cfg: WorldConfig) -> dict[str, slice]:
    """Where each feature group lies in an observation vector."""
    sizes = {"position": 2, "tick": 1, "patch": 3 * cfg.vision ** 2,
             "team_visited": cfg.cells, "heard_positions": cfg.cells}
    out, lo = {}, 0
    for name, size in sizes.items():
        out[name] = slice(lo, lo + size)
        lo += size
    return out


def obs_size(cfg: WorldConfig) -> int:
    """Length of one robot's observation vector (the feature groups of `obs_slices`)."""
    return obs_slices(cfg)["heard_positions"].stop


def encode(cfg: WorldConfig, view: View) -> np.ndarray:
    """Observation vectors [G, N, obs_size] float32 of every robot slot of `view`.

    Only the rows of `view.receivers` are meaningful; each reads just its own `hears` row.
    """
    m = view.msgs
    g, n = view.hears.shape[:2]
    pos = m.pos.astype(np.float32) / np.array([cfg.height - 1, cfg.width - 1], dtype=np.float32)
    tick = np.full((g, n, 1), view.tick / cfg.horizon, dtype=np.float32)
    code = m.patch & 3
    patch = np.stack([code == 1, code == 2, (m.patch & core.ROBOT_BIT) != 0], axis=2)
    hears = view.hears.astype(np.float32)
    team = (hears @ m.visited.astype(np.float32)) > 0
    onehot = np.zeros((g, n, cfg.cells), dtype=np.float32)
    cell = m.pos[..., 0] * cfg.width + m.pos[..., 1]
    gi, ni = np.nonzero(m.present)
    onehot[gi, ni, cell[gi, ni]] = 1.0
    others = hears * (1.0 - np.eye(n, dtype=np.float32))
    heard_pos = (others @ onehot) > 0
    return np.concatenate([pos, tick, patch.reshape(g, n, -1), team, heard_pos],
                          axis=-1, dtype=np.float32)


def _whole(v: Any, name: str) -> int:
    """A seed or an episode number: an int (numpy's too) in [0, 2**31 - 1], never truncated
    (1.5 is not seed 1); a one-line ValueError (ConfigError) otherwise."""
    if isinstance(v, np.integer):
        v = int(v)
    check_seed(v, name)
    return int(v)


class SwarmParallelEnv(ParallelEnv[str, np.ndarray, int]):
    """N robots exploring one generated episode; a thin per-agent view of `world.core`."""

    metadata: ClassVar[dict[str, Any]] = {
        "name": "commattn_swarm_v0", "render_modes": ["ansi"], "is_parallelizable": True}

    def __init__(self, cfg: WorldConfig, render_mode: str | None = None) -> None:
        if render_mode not in (None, "ansi"):
            raise ValueError(f"render_mode must be None or 'ansi', got {render_mode!r}")
        self.cfg = cfg
        self.render_mode = render_mode
        self.possible_agents = [f"robot_{i}" for i in range(cfg.n_robots)]
        self.agents: list[str] = []
        self._index = {a: i for i, a in enumerate(self.possible_agents)}
        size = obs_size(cfg)
        self.observation_spaces = {
            a: spaces.Box(0.0, 1.0, shape=(size,), dtype=np.float32) for a in self.possible_agents}
        self.action_spaces = {a: spaces.Discrete(core.N_ACTIONS) for a in self.possible_agents}
        self.world_seed = 0
        self.episode = -1
        self.world: core.WorldState | None = None

    def observation_space(self, agent: str) -> spaces.Box:
        """Every agent's: a Box [obs_size] float32 in [0, 1] (see `encode`)."""
        return self.observation_spaces[agent]

    def action_space(self, agent: str) -> spaces.Discrete:
        """Every agent's: Discrete(9), the moves of `world.core.ACTIONS` (0 stays)."""
        return self.action_spaces[agent]

    def reset(self, seed: int | None = None,
              options: dict[str, Any] | None = None) -> tuple[dict[str, np.ndarray], dict]:
        """Start episode `options["episode"]`, else the next one, of `seed` (kept when None).

        A new seed restarts the episode counter at 0, so reset(seed=s) is always episode 0 of s.
        """
        if options is not None and not isinstance(options, dict):
            raise ValueError(f"options must be None or a dict, got {options!r:.80}")
        if options and set(options) - {"episode"}:  # (PettingZoo's own api test passes others)
            warnings.warn(f"reset options {sorted(map(str, set(options) - {'episode'}))} are not "
                          "used (known: episode)", stacklevel=2)
        if seed is not None:
            self.world_seed = _whole(seed, "seed")
            self.episode = -1
        if options and "episode" in options:
            self.episode = _whole(options["episode"], "episode")
        else:
            self.episode += 1
        self.world = core.reset(self.cfg, self.world_seed, [self.episode])
        self.agents = self.possible_agents[:]
        info = {"seed": self.world_seed, "episode": self.episode}
        return self._observe(), {a: dict(info) for a in self.agents}

    def step(self, actions: dict[str, int]) -> tuple[dict[str, np.ndarray], dict[str, float],
                                                     dict[str, bool], dict[str, bool], dict]:
        """One world step; agents absent from `actions` stay in place."""
        if self.world is None or not self.agents:
            raise RuntimeError("the episode is over (or never started): call reset()")
        if not isinstance(actions, dict):
            raise ValueError(f"actions must be a dict of agent name to action, got "
                             f"{type(actions).__name__}")
        a = np.zeros((1, self.cfg.n_robots), dtype=np.int64)
        for agent, action in actions.items():
            if agent not in self._index:
                raise ValueError(f"unknown agent {agent!r}; agents are {self.possible_agents}")
            if isinstance(action, (bool, np.bool_)) or \
                    not self.action_spaces[agent].contains(action):
                raise ValueError(f"{agent}: action must be an int in 0..8, got {action!r}")
            a[0, self._index[agent]] = int(action)
        rewards = core.step(self.cfg, self.world, a)[0]
        done = self.world.done
        agents = self.agents
        obs = self._observe()
        infos: dict[str, dict[str, Any]] = {ag: {} for ag in agents}
        if done:
            infos = self._final_infos()
            self.agents = []
        return (obs, {ag: float(rewards[self._index[ag]]) for ag in agents},
                dict.fromkeys(agents, False), dict.fromkeys(agents, done), infos)

    def _observe(self) -> dict[str, np.ndarray]:
        assert self.world is not None
        vec = encode(self.cfg, batch_view(self.cfg, self.world))[0]
        return {a: vec[self._index[a]] for a in self.possible_agents}

    def _final_infos(self) -> dict[str, dict[str, Any]]:
        w = self.world
        assert w is not None
        m = core.metrics(self.cfg, w)
        team = {"elratio": float(m.elratio[0]), "success": bool(m.success[0]),
                "team_reward_mean": float(m.reward[0]),
                "team_block_collisions": int(m.block_collisions[0]),
                "team_robot_collisions": int(m.robot_collisions[0]),
                "repeat_ratio": float(m.repeat_ratio[0]), "seed": self.world_seed,
                "episode": self.episode}
        return {a: {"episode_return": float(w.reward_sum[0, i]),
                    "block_collisions": int(w.block_coll[0, i]),
                    "robot_collisions": int(w.robot_coll[0, i]),
                    "repeat_visits": int(w.back_count[0, i]), **team}
                for a, i in self._index.items()}

    def render(self) -> str | None:
        """ANSI text of the grid: '#' block, '.' explored, ' ' unexplored, robot ids mod 10."""
        if self.render_mode != "ansi" or self.world is None:
            return None
        lay = core.Layout.of(self.cfg)
        grid = lay.inner(self.world.grid[0])
        explored = lay.inner(self.world.explored[0])
        rows = [["#" if grid[y, x] & 1 else "." if explored[y, x] else " "
                 for x in range(self.cfg.width)] for y in range(self.cfg.height)]
        for i, (y, x) in enumerate(lay.to_yx(self.world.pos[0]).tolist()):
            rows[y][x] = str(i % 10)
        return "\n".join("".join(r) for r in rows)

    def close(self) -> None:
        """Drop the episode (nothing else is held); `reset` starts a new one."""
        self.world = None
        self.agents = []


def parallel_env(config: WorldConfig | None = None, *, render_mode: str | None = None,
                 **overrides: Any) -> SwarmParallelEnv:
    """The env on `config` (default: the paper's world) with WorldConfig field overrides."""
    if config is not None and not isinstance(config, WorldConfig):
        raise ValueError(f"config must be a WorldConfig (or give fields as keywords: "
                         f"parallel_env(n_robots=3)), got {type(config).__name__}")
    base = {} if config is None else dataclasses.asdict(config)
    cfg = from_dict(WorldConfig, {**base, **overrides}, "parallel_env")
    return SwarmParallelEnv(cfg, render_mode=render_mode)
