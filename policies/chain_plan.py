"""`chain-plan`: whole-horizon planning passed down SPEC 3's chain (ours, not the paper's).

Why. A robot that plans its whole heard team alone (results/planners/replan.py, decentralized)
follows its part of a joint plan that its teammates, planning alone on slightly different
beliefs, do not share: near-optimal team plans differ a lot, so the parts overlap, and a deeper
search does not help (0.941 full, 0.943 light, against 0.962 for the same search on the pooled
belief, episodes 0-19 of seed 0). The chain of SPEC 3.5 is a place to agree: robot i hears its
predecessor p(i) = max{j heard, j < i} before it acts, as CommAttn's decoder does.

What. The hidden-state message carries the joint plan as p(i) left it: a path of cells over the
steps left for every robot p(i) knows of (its heard team and what its own predecessor sent).
Robot i keeps those paths (the robots before it act on theirs), plans the robots it hears that
the plan lacks, then its own path around all of them (`horizon_search`: the oracle's beam on
its own belief, unknown cells free, no block foreseen), improves the paths of the robots after
it with `iters` local-search rounds, takes its own first move and sends the plan on. A robot
with no predecessor this tick (none heard below it, or its message lost or late: `chain_ok`)
heads a chain: it plans its heard team itself, starting from the plan it sent last tick (`warm`:
each path that the robot's move kept on course, shifted one step) and improving it with
`head_iters` rounds of beam `head_beam`. So each chain acts on one plan, and a plan is refined
over ticks instead of remade.

Decentralized by the policy contract: a decision reads the robot's own belief (the frontier
baselines' `policies.belief`), the messages it heard, its predecessor's hidden-state message,
its own memory of what it sent, and noise keyed by (seed, episode, tick, robot). The message has
a row per robot: its id, its first cell and its moves packed six to a float (base 9, below
the message's 1e6 bound), -1 rows after the plan's robots: `n_robots x (2 + ceil(horizon /
6))` floats, 70 (280 bytes) for 10 robots and 30 steps. It is checked on arrival
(`state_ok`): ids in range and distinct, every field an integer in range, the path on the
grid. A message that fails is treated as lost (the robot heads a chain).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from policies.base import Decision, Policy
from policies.belief import Belief, Snapshot
from policies.horizon_search import belief_episode, fill, improve, zobrist
from policies.oracle import to_actions
from world.config import ConfigError, WorldConfig
from world.decentral import View, predecessor_of

MAX_FLOATS = 4096  # a hidden-state message's limit (swarm.net.messages.Hidden)
BASE, MOVES_PER_FLOAT = 9, 6  # a move is (dy + 1) * 3 + dx + 1; 9**6 < 1e6 (messages.Hidden)
PLACES = BASE ** np.arange(MOVES_PER_FLOAT, dtype=np.int64)


@dataclass(frozen=True)
class ChainConfig:
    """Search settings of `chain-plan` (defaults measured on episodes 0-19 of seed 0:
    results/planners/chain_plan.py)."""

    head_iters: int = 4
    """Local-search rounds of a robot that heads its chain."""
    head_beam: int = 32
    """Beam width of a chain head's searches."""
    iters: int = 0
    """Local-search rounds over the robots after it, for a robot inside a chain."""
    beam: int = 16
    """Beam width of a robot inside a chain (its own path and the paths it fills in)."""
    warm: bool = True
    """A chain head starts from the plan it sent last tick."""

    def __post_init__(self) -> None:
        for name, lo, hi in (("head_iters", 0, 64), ("head_beam", 1, 256), ("iters", 0, 64),
                             ("beam", 1, 256)):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or not lo <= v <= hi:
                raise ConfigError(f"chain-plan {name} must be an integer in [{lo}, {hi}], "
                                  f"got {v!r}")


class Prepared(NamedTuple):
    """`prepare_chain`'s output: the beliefs folded and each receiver's predecessor."""

    view: View
    snap: Snapshot
    pred: np.ndarray  # [R] each receiver's predecessor id (-1: none), chain_ok not applied


Plan = dict[int, np.ndarray]  # robot id -> path of cells over the steps left


class ChainPlan(Policy):
    """Whole-horizon planning down the id chain; the plan rides in the hidden-state message."""

    name = "chain-plan"
    chained = True

    def __init__(self, cfg: WorldConfig, search: ChainConfig | None = None) -> None:
        super().__init__(cfg)
        self.search = search or ChainConfig()
        if self.state_size > MAX_FLOATS:
            raise ConfigError(f"chain-plan's message would carry {self.state_size} floats "
                              f"(robots x (2 + horizon / 6)); at most {MAX_FLOATS}")
        self.belief = Belief(cfg)
        # (group, robot) -> (episode, tick, the plan it sent): one entry per robot of a group,
        # so a long run does not grow it (a key per episode would)
        self.memory: dict[tuple[int, int], tuple[int, int, Plan]] = {}
        # as a network's hint in a robot process (policies.infer.policy): the predecessors'
        # plans received, (group, predecessor) -> plan, and what the last chain sent
        self.given: dict[tuple[int, int], Plan] = {}
        self.last_sent: dict[tuple[int, int], Plan] = {}
        self._decoded: tuple[tuple[int, bytes], Plan | None] | None = None  # see decode

    @property
    def words(self) -> int:
        """Floats of packed moves in a robot's row: a path's horizon moves, 6 to a float."""
        return -(-self.cfg.horizon // MOVES_PER_FLOAT)

    @property
    def state_size(self) -> int:
        """Floats in a hidden-state message: a row (robot id, first cell, packed moves) per
        robot."""
        return self.cfg.n_robots * (2 + self.words)

    def reset(self, groups: int) -> None:
        self.belief.reset(groups)
        self.memory.clear()

    # ------------------------------------------------------------- the batch: the whole chain
    def act(self, view: View, greedy: bool = True) -> np.ndarray:
        snap = self.belief.snapshot(view)
        actions = np.zeros(view.receivers.shape, dtype=np.int64)
        actions[snap.g, snap.i] = self.moves(view, snap)  # no messages encoded: nobody reads them
        return actions

    def decide(self, view: View, greedy: bool = True) -> Decision:
        """Actions [G, N] and the message [G, N, S] every receiver sends on."""
        snap = self.belief.snapshot(view)
        moves, sent = self._chain(view, snap)
        actions = np.zeros(view.receivers.shape, dtype=np.int64)
        actions[snap.g, snap.i] = moves
        state = np.zeros(view.receivers.shape + (self.state_size,), dtype=np.float32)
        for (g, i), plan in sent.items():
            state[g, i] = self.encode(plan)
        return Decision(actions, state)

    def moves(self, view: View, snap: Snapshot) -> np.ndarray:
        """Every receiver's move [R] (in `snap`'s order): a network's planner hint."""
        return self._chain(view, snap)[0]

    def first_moves(self, view: View, snap: Snapshot) -> np.ndarray:
        """`moves` as a one-hot [R, 9] bool: a network's planner hint (policies.infer.tokens,
        `hint_planner` "chain-plan")."""
        out = np.zeros((snap.size, 9), dtype=bool)
        if snap.size:
            out[np.arange(snap.size), self.moves(view, snap)] = True
        return out

    def _chain(self, view: View, snap: Snapshot) -> tuple[np.ndarray, dict[tuple[int, int], Plan]]:
        """The chain run in id order: moves [R] and the plan each (group, receiver) sends."""
        pred = view.predecessor()
        if view.chain_ok is not None:
            pred = np.where(view.chain_ok, pred, -1)
        out = np.zeros(snap.size, dtype=np.int64)
        sent: dict[tuple[int, int], Plan] = dict(self.given)  # (plans from outside the view)
        for k in np.lexsort((snap.i, snap.g)):  # down the chain: ids in order within a group
            g, i = int(snap.g[k]), int(snap.i[k])
            got = sent.get((g, int(pred[g, i])), {}) if pred[g, i] >= 0 else {}
            out[k], sent[(g, i)] = self._decide(view, snap, int(k), got)
        self.last_sent = sent
        return out, sent

    # ------------------------------------------------------------- one robot (a robot process)
    def prepare_chain(self, view: View, greedy: bool = True) -> Prepared:
        """Fold this tick's messages and find each receiver's predecessor (before waiting)."""
        if (view.receivers.sum(1) != 1).any():
            raise ValueError("act_with_chain needs exactly one receiver per group")
        snap = self.belief.snapshot(view)
        return Prepared(view, snap, predecessor_of(view.hears[snap.g, snap.i], snap.i))

    def act_with_chain(self, view: View, pred_state: np.ndarray | None,
                       pred_action: np.ndarray | None, greedy: bool = True,
                       prepared: Prepared | None = None) -> tuple[np.ndarray, np.ndarray]:
        """One receiver per group given its predecessor's hidden-state message ([G, S] floats,
        rows of receivers without a predecessor ignored). Returns actions [G, N] and the
        receivers' messages [G, S] (the plan they send on)."""
        if prepared is None:
            prepared = self.prepare_chain(view, greedy)
        elif prepared.view is not view:
            raise ValueError("prepared for another view")
        snap, pred = prepared.snap, prepared.pred
        if view.chain_ok is not None:
            pred = np.where(view.chain_ok[snap.g, snap.i], pred, -1)
        actions = np.zeros(view.receivers.shape, dtype=np.int64)
        state = np.zeros((view.groups, self.state_size), dtype=np.float32)
        for k in range(snap.size):
            g = int(snap.g[k])
            got = {}
            if pred[k] >= 0:
                if pred_state is None:
                    raise ValueError("a receiver has a predecessor but no hidden-state message "
                                     "was given")
                got = self.decode(np.asarray(pred_state, np.float32).reshape(view.groups, -1)[g],
                                  view.tick)
                if got is None:
                    raise ValueError("the predecessor's plan fails its checks (state_ok)")
            actions[g, snap.i[k]], plan = self._decide(view, snap, k, got)
            state[g] = self.encode(plan)
        return actions, state

    def state_ok(self, state: np.ndarray, tick: int) -> bool:
        """Whether a received hidden-state message is a plan this policy can read."""
        return self.decode(state, tick) is not None

    # ------------------------------------------------------------- the message
    def encode(self, plan: Plan) -> np.ndarray:
        """A plan as the message: a row per robot (id, first cell, its moves packed base 9,
        MOVES_PER_FLOAT to a float; unused digits 0), rows in id order, -1 rows after them."""
        cfg = self.cfg
        rows = np.full((cfg.n_robots, 2 + self.words), -1.0, dtype=np.float32)
        for row, (r, path) in enumerate(sorted(plan.items())):
            y, x = np.divmod(np.asarray(path, dtype=np.int64), cfg.width)
            digits = np.zeros(self.words * MOVES_PER_FLOAT, dtype=np.int64)
            digits[:len(path) - 1] = (np.diff(y) + 1) * 3 + np.diff(x) + 1
            rows[row, 0], rows[row, 1] = r, path[0]
            rows[row, 2:] = digits.reshape(self.words, MOVES_PER_FLOAT) @ PLACES
        return rows.ravel()

    def decode(self, state: np.ndarray, tick: int) -> Plan | None:
        """The plan in a message for tick `tick`, or None if any field is out of range. The
        last message's result is kept: a robot checks its predecessor's message on arrival
        (`state_ok`) and then reads it, one decode (callers do not change a plan)."""
        key = (tick, np.asarray(state).tobytes())
        if self._decoded is not None and self._decoded[0] == key:
            return self._decoded[1]
        plan = self._decode(state, tick)
        self._decoded = (key, plan)
        return plan

    def _decode(self, state: np.ndarray, tick: int) -> Plan | None:
        cfg = self.cfg
        rows = np.asarray(state, dtype=np.float64)
        if rows.shape != (self.state_size,) or not np.isfinite(rows).all():
            return None
        rows = rows.reshape(cfg.n_robots, 2 + self.words)
        used = rows[:, 0] >= 0
        ids, start, packed = rows[used, 0], rows[used, 1], rows[used, 2:]
        if ((rows[~used] != -1).any() or (rows[used] != np.round(rows[used])).any()
                or (ids >= cfg.n_robots).any() or len(np.unique(ids)) != len(ids)
                or (start < 0).any() or (start >= cfg.cells).any() or (packed < 0).any()
                or (packed >= BASE ** MOVES_PER_FLOAT).any()):
            return None
        digits = (packed.astype(np.int64)[..., None] // PLACES) % BASE
        digits = digits.reshape(len(ids), -1)
        moves = cfg.horizon - tick  # a path at this tick has horizon - tick + 1 cells
        if moves < 0 or (digits[:, moves:] != 0).any():
            return None
        y0, x0 = np.divmod(start.astype(np.int64), cfg.width)
        y = np.concatenate([y0[:, None], digits[:, :moves] // 3 - 1], axis=1).cumsum(1)
        x = np.concatenate([x0[:, None], digits[:, :moves] % 3 - 1], axis=1).cumsum(1)
        if (y < 0).any() or (y >= cfg.height).any() or (x < 0).any() or (x >= cfg.width).any():
            return None
        return {int(r): p for r, p in zip(ids, y * cfg.width + x, strict=True)}

    # ------------------------------------------------------------- one decision
    def _decide(self, view: View, snap: Snapshot, k: int, got: Plan) -> tuple[int, Plan]:
        """Receiver k's move and the plan it sends, given its predecessor's plan `got`."""
        cfg, s = self.cfg, self.search
        g, i = int(snap.g[k]), int(snap.i[k])
        heard = np.flatnonzero(view.hears[g, i])
        ids = np.union1d(heard, np.fromiter(got, dtype=np.int64, count=len(got)))
        cells = np.array([got[r][0] if r in got else
                          view.msgs.pos[g, r, 0] * cfg.width + view.msgs.pos[g, r, 1]
                          for r in ids], dtype=np.int64)
        me = int(np.flatnonzero(ids == i)[0])
        cells[me] = snap.cells[k, 0] * cfg.width + snap.cells[k, 1]  # my own, whatever it heard
        ep = belief_episode(cfg, snap.known[k].ravel().copy(), snap.explored[k].ravel(), cells,
                            view.tick)
        episode = int(view.episodes[g])
        rng = np.random.default_rng([int(view.seed), episode, view.tick, i, 31])
        zob = zobrist(cfg, rng)
        paths = np.repeat(cells[:, None], cfg.horizon - view.tick + 1, axis=1)
        ep_sent, tick, last = self.memory.get((g, i), (-1, -1, {}))
        if ep_sent != episode:
            tick = -1
        kept = np.zeros(len(ids), dtype=bool)
        for n, r in enumerate(ids):
            if n != me and r in got:
                paths[n], kept[n] = got[r], True
            elif s.warm and tick == view.tick - 1 and r in last and last[r][1] == cells[n]:
                paths[n], kept[n] = last[r][1:], True
        if got:  # the robots the plan lacks, my path around everyone's, the robots after me
            guess = [n for n in range(len(ids)) if not kept[n] and n != me]
            paths = fill(ep, paths, guess + [me], s.beam, rng, zob)
            paths = improve(ep, paths, ids >= i, s.iters, s.beam, rng, zob)
        else:  # the head of a chain: the whole heard team
            order = [me] + [n for n in range(len(ids)) if n != me and not kept[n]]
            paths = fill(ep, paths, order, s.head_beam, rng, zob)
            paths = improve(ep, paths, np.ones(len(ids), dtype=bool), s.head_iters, s.head_beam,
                            rng, zob)
        plan = {int(r): paths[n] for n, r in enumerate(ids)}
        self.memory[(g, i)] = (episode, view.tick, plan)
        return int(to_actions(ep.cfg, paths[me:me + 1, :2])[0, 0]), plan  # type: ignore[arg-type]
