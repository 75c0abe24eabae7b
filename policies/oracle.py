"""`oracle`: a reference planner with full knowledge of the episode (not decentralized).

It regenerates the episode from (seed, episode) with `world.core` (the same map, starts and
dynamic-block schedule the world will run) and plans every robot's whole trajectory at tick 0;
`act` then replays the plan. It bounds from above what any communication scheme can buy.

Model. Only cells that are free, not a start and not a dynamic block score: a start is explored
at reset and a dynamic-block cell is counted by elratio whatever the robots do (it ends as a
final block, or a robot stands on it at the end). A robot may enter cell c at step t iff c is not
static and, when c is a dynamic block due at step d_c, t <= d_c (the world activates a due block
only on an unoccupied cell, so a robot may stand on c at time d_c; staying put is always legal,
since an occupied cell never activates). Entering a cell that some other robot holds open past
its due step is also legal in the world but never planned (conservative), so a plan never makes
a block collision and its replay explores exactly the planned cells.

Search (anytime, deterministic for a given config): every robot is planned by a beam search over
its 30-step paths against the cells the others already cover (`_beam`); robots are planned one
after another, then a large-neighbourhood local search re-plans `group` robots at a time against
the others' fixed plans and keeps the result when the team covers at least as many cells. It
stops at the reachability upper bound (every scoring cell some robot can reach in time), after
`iters` rounds (or after `budget_s` seconds, a cap that is off by default: it would make the plan
depend on the machine's speed). `certify` bounds the optimum with an integer
program (scipy's HiGHS). Every plan is replayed through `world.core.step` and the replay's
elratio and collisions are what `plans` reports.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from policies.base import Policy
from world import core
from world.config import WorldConfig
from world.decentral import View


@dataclass(frozen=True)
class OracleConfig:
    """Search budget of the oracle planner."""

    budget_s: float = math.inf
    """Wall-clock seconds of search per episode at most (default: no cap). A cap makes the plan
    depend on the machine's speed: 3 s, the old default, cut 17 of 60 held-out searches short."""
    iters: int = 200
    """Local-search rounds per episode: the search budget (rounds are seeded, so a plan is a
    function of the seed and this config; 4.7 s median an episode, 11.5 s at most, on a busy
    2-core machine: results/reference/oracle_60.json)."""
    beam: int = 96
    """Beam width of the single-robot path search."""
    groups: tuple[int, ...] = (2, 2, 3, 4)
    """Sizes (drawn per round) of the team of robots re-planned together."""
    boosts: tuple[int, ...] = (1, 1, 3, 10)
    """Weights (drawn per round) of the cells nobody covers for the first re-planned robot: above
    1 it may give up its own cells (which its partners then re-plan) to reach isolated ones."""


@dataclass
class Episode:
    """One regenerated episode in the planner's terms (grid flat indices y*W+x, no padding)."""

    cfg: WorldConfig
    starts: np.ndarray  # [N] cells
    nbr: np.ndarray  # [HW, 9] cell after each action, -1 off-grid or static
    due: np.ndarray  # [HW] last time a robot may arrive: d_c for dynamic, T+1 free, -1 static
    value: np.ndarray  # [HW] bool scoring cells (free, not dynamic, not a start)
    base: int  # cells elratio counts whatever the robots do (static, dynamic, starts)

    @classmethod
    def generate(cls, cfg: WorldConfig, seed: int, episode: int) -> Episode:
        blocks, starts, dyn = core.generate_episode(cfg, seed, episode)
        h, w = cfg.height, cfg.width
        due = np.where(blocks.ravel(), -1, cfg.horizon + 1).astype(np.int64)
        dcells = dyn[:, 0] * w + dyn[:, 1]
        due[dcells] = core.dynamic_due(cfg)
        y, x = np.divmod(np.arange(h * w), w)
        ny = y[:, None] + core.ACTIONS[None, :, 0]
        nx = x[:, None] + core.ACTIONS[None, :, 1]
        ok = (ny >= 0) & (ny < h) & (nx >= 0) & (nx < w)
        nbr = np.where(ok, ny * w + nx, -1)
        nbr[ok] = np.where(due[nbr[ok]] < 0, -1, nbr[ok])
        s = starts[:, 0] * w + starts[:, 1]
        value = due > cfg.horizon
        value[s] = False
        base = int(blocks.sum()) + len(dcells) + len(np.unique(s))
        return cls(cfg, s.astype(np.int64), nbr, due, value, base)

    def reachable(self) -> np.ndarray:
        """[HW] bool cells some robot can stand on at some time (an over-approximation that also
        lets a robot hold a dynamic cell open forever once it reached it in time)."""
        reach = np.zeros(len(self.due), dtype=bool)
        reach[self.starts] = True
        ever = reach.copy()
        for t in range(1, self.cfg.horizon + 1):
            nb = self.nbr[reach]
            nb = nb[nb >= 0]
            grown = reach.copy()
            grown[nb] = True
            grown &= (self.due >= t) | ever
            reach = grown
            ever |= reach
        return ever

    def elratio(self, covered: np.ndarray) -> float:
        """elratio of a plan that visits the scoring cells `covered` [HW] bool."""
        return (self.base + int((covered & self.value).sum())) / self.cfg.cells


def _beam(ep: Episode, start: int, weight: np.ndarray, width: int, rng: np.random.Generator,
          zob: np.ndarray) -> np.ndarray:
    """Best path [T+1] cells of one robot from `start` collecting the most `weight` [HW] int
    (each cell counts once; 0 for cells worth nothing).

    The beam holds (cell, set of cells gained) states, deduplicated by (cell, Zobrist hash of the
    set), ranked by cells gained, then a look-ahead (scoring neighbours still to gain), then
    noise. Moves follow the planner's model: a dynamic cell is entered at step t only if t <= d_c.
    """
    hw = len(ep.due)
    words = (hw + 63) // 64
    wt = weight.astype(np.int64)
    wt[start] = 0
    gm = wt > 0
    pos = np.array([start], dtype=np.int64)
    bits = np.zeros((1, words), dtype=np.uint64)
    score = np.zeros(1, dtype=np.int64)
    key = np.zeros(1, dtype=np.uint64)
    parents: list[np.ndarray] = []
    cells: list[np.ndarray] = [pos]
    stay = np.arange(9)[None] == 0
    rows = np.repeat(np.arange(max(width, 1))[:, None], 9, axis=1)  # [B, 9] parent of each move
    for t in range(1, ep.cfg.horizon + 1):
        q = ep.nbr[pos]  # [B, 9]
        valid = (q >= 0) & (stay | (ep.due[np.maximum(q, 0)] >= t))
        q = np.where(valid, q, pos[:, None])
        q, par = q[valid], rows[:len(pos)][valid]
        w_, b_ = q >> 6, (q & 63).astype(np.uint64)
        seen = ((bits[par, w_] >> b_) & np.uint64(1)).astype(bool)
        gain = gm[q] & ~seen
        sc = score[par] + gain * wt[q]
        k = key[par] ^ np.where(gain, zob[q], np.uint64(0))
        k2 = k ^ (q.astype(np.uint64) * np.uint64(0x9E3779B97F4A7C15))
        # the first of each distinct state in key order: np.unique(k2, return_index=True)'s
        # index, without its overhead (a third of a step's time at beam 8)
        perm = k2.argsort(kind="mergesort")
        ks = k2[perm]
        distinct = np.empty(len(ks), dtype=bool)
        distinct[:1] = True
        np.not_equal(ks[1:], ks[:-1], out=distinct[1:])
        first = perm[distinct]
        q, par, gain, sc, k = q[first], par[first], gain[first], sc[first], k[first]
        if len(q) > width:
            # look-ahead: scoring neighbours of the new cell not gained yet (ignoring the move)
            nb = ep.nbr[q]
            nb0 = np.maximum(nb, 0)
            nbv = gm[nb0] & (nb >= 0)
            nbw, nbb = nb0 >> 6, (nb0 & 63).astype(np.uint64)
            nseen = ((bits[par[:, None], nbw] >> nbb) & np.uint64(1)).astype(bool)
            look = (nbv & ~nseen).sum(1)
            rank = sc * 256 + np.minimum(look, 4) * 8 + rng.integers(0, 8, len(q))
            # a stable sort, ties by key order: np.argpartition picks among equal ranks by its
            # SIMD kernel (AVX2, AVX-512 or none give three different plans of one episode)
            keep = np.argsort(-rank, kind="stable")[:width]
            q, par, gain, sc, k = q[keep], par[keep], gain[keep], sc[keep], k[keep]
        nbits = bits[par].copy()
        gi = np.flatnonzero(gain)
        nbits[gi, q[gi] >> 6] |= np.uint64(1) << (q[gi] & 63).astype(np.uint64)
        pos, bits, score, key = q, nbits, sc, k
        parents.append(par)
        cells.append(pos)
    best = int(np.argmax(score + rng.random(len(score)) * 0.5))
    path = np.empty(ep.cfg.horizon + 1, dtype=np.int64)
    for t in range(ep.cfg.horizon, 0, -1):
        path[t] = cells[t][best]
        best = int(parents[t - 1][best])
    path[0] = start
    return path


@dataclass
class Plan:
    """A whole-episode plan and what its replay through `world.core.step` measured."""

    paths: np.ndarray  # [N, T+1] cells y*W+x
    actions: np.ndarray  # [T, N] int64
    planned_elratio: float
    upper_bound: int  # scoring cells reachable at all (reachability bound)
    covered: int  # scoring cells the plan visits
    elratio: float  # replayed
    block_collisions: int  # replayed
    robot_collisions: int  # replayed
    seconds: float
    rounds: int


def _cover(ep: Episode, paths: np.ndarray) -> np.ndarray:
    """[N, HW] bool scoring cells visited by each path."""
    n, hw = len(paths), len(ep.due)
    cov = np.zeros((n, hw), dtype=bool)
    cov[np.repeat(np.arange(n), paths.shape[1]), paths.ravel()] = True
    return cov & ep.value


def to_actions(cfg: WorldConfig, paths: np.ndarray) -> np.ndarray:
    """Paths [N, T+1] of cells -> actions [T, N]."""
    y, x = np.divmod(paths, cfg.width)
    dy, dx = np.diff(y, axis=1), np.diff(x, axis=1)
    code = (dy + 1) * 3 + dx + 1  # [N, T]
    table = np.full(9, -1, dtype=np.int64)
    table[(core.ACTIONS[:, 0] + 1) * 3 + core.ACTIONS[:, 1] + 1] = np.arange(9)
    acts = table[code]
    if (acts < 0).any():
        raise ValueError("a path makes a move longer than one cell")
    return acts.T.copy()


def replay(cfg: WorldConfig, seed: int, episode: int, actions: np.ndarray) -> core.WorldState:
    """Run actions [T, N] through the world's own step; returns the final state."""
    state = core.reset(cfg, seed, [episode])
    for t in range(cfg.horizon):
        core.step(cfg, state, actions[t][None])
    return state


def _pick_team(yx: np.ndarray, paths: np.ndarray, missing: np.ndarray, size: int,
               rng: np.random.Generator) -> np.ndarray:
    """Robots to re-plan: the one whose path passes nearest a random cell nobody covers yet
    (Chebyshev distance), then robots whose paths pass near its path (they can take over its
    cells) or random ones; all random when nothing is missing."""
    n = len(paths)
    size = min(size, n)
    miss = np.flatnonzero(missing)
    if len(miss) == 0:
        return rng.choice(n, size=size, replace=False)
    u = yx[rng.choice(miss)]
    d = np.abs(yx[paths] - u).max(-1).min(1).astype(np.float64)  # [N]
    first = int(np.argmin(d + rng.random(n) * 2.0))
    rest = np.delete(np.arange(n), first)
    if rng.random() < 0.5:
        return np.concatenate([[first], rng.permutation(rest)[:size - 1]])
    mine = yx[paths[first]]  # [T+1, 2]
    gap = np.abs(yx[paths[rest]][:, :, None] - mine[None, None]).max(-1).min((1, 2))
    near = np.argsort(gap + rng.random(len(rest)) * 3.0, kind="stable")
    return np.concatenate([[first], rest[near][:size - 1]])


def plan_episode(cfg: WorldConfig, seed: int, episode: int,
                 search: OracleConfig | None = None) -> Plan:
    """Plan every robot's trajectory of one episode, then validate it by replay."""
    search = search or OracleConfig()
    t0 = time.perf_counter()
    ep = Episode.generate(cfg, seed, episode)
    rng = np.random.default_rng([int(seed), int(episode), 17])
    zob = rng.integers(0, np.iinfo(np.int64).max, len(ep.due), dtype=np.int64).astype(np.uint64)
    bound = int((ep.reachable() & ep.value).sum())
    n = cfg.n_robots
    paths = np.repeat(ep.starts[:, None], cfg.horizon + 1, axis=1)
    cov = _cover(ep, paths)
    for r in range(n):  # sequential first plan
        others = cov[np.arange(n) != r].any(0)
        paths[r] = _beam(ep, int(ep.starts[r]), ep.value & ~others, search.beam, rng, zob)
        cov[r] = _cover(ep, paths[r:r + 1])[0]
    value = int(cov.any(0).sum())
    rounds = 0
    yx = np.stack(np.divmod(np.arange(len(ep.due)), cfg.width), axis=-1)
    reach = ep.reachable() & ep.value
    while (value < bound and rounds < search.iters
           and time.perf_counter() - t0 < search.budget_s):
        rounds += 1
        size = int(rng.choice(search.groups))
        team = _pick_team(yx, paths, reach & ~cov.any(0), size, rng)
        new_paths, new_cov = paths.copy(), cov.copy()
        new_cov[team] = False
        missing = reach & ~cov.any(0)
        boost = int(rng.choice(search.boosts))
        for k, r in enumerate(team):
            others = new_cov[np.arange(n) != r].any(0)
            weight = (ep.value & ~others).astype(np.int64)
            if k == 0:  # the first robot may sacrifice its own gain for cells nobody covers
                weight[missing & ~others] = boost
            new_paths[r] = _beam(ep, int(ep.starts[r]), weight, search.beam, rng, zob)
            new_cov[r] = _cover(ep, new_paths[r:r + 1])[0]
        new_value = int(new_cov.any(0).sum())
        if new_value >= value:
            paths, cov, value = new_paths, new_cov, new_value
    actions = to_actions(cfg, paths)
    state = replay(cfg, seed, episode, actions)
    m = core.metrics(cfg, state)
    return Plan(paths=paths, actions=actions, planned_elratio=ep.elratio(cov.any(0)),
                upper_bound=bound, covered=value, elratio=float(m.elratio[0]),
                block_collisions=int(m.block_collisions[0]),
                robot_collisions=int(m.robot_collisions[0]),
                seconds=time.perf_counter() - t0, rounds=rounds)


class OraclePolicy(Policy):
    """Plays the oracle's whole-episode plan; plans each (seed, episode) once, on first sight."""

    name = "oracle"
    decentralized: ClassVar[bool] = False
    learned: ClassVar[bool] = False

    def __init__(self, cfg: WorldConfig, search: OracleConfig | None = None) -> None:
        super().__init__(cfg)
        self.search = search or OracleConfig()
        self.plans: dict[tuple[int, int], Plan] = {}

    def reset(self, groups: int) -> None:
        self.plans.clear()

    def plan(self, seed: int, episode: int) -> Plan:
        key = (int(seed), int(episode))
        if key not in self.plans:
            self.plans[key] = plan_episode(self.cfg, *key, search=self.search)
        return self.plans[key]

    def act(self, view: View, greedy: bool = True) -> np.ndarray:
        out = np.zeros(view.receivers.shape, dtype=np.int64)
        if view.tick >= self.cfg.horizon:
            return out
        for g, episode in enumerate(view.episodes):
            acts = self.plan(view.seed, int(episode)).actions[view.tick]
            out[g] = np.where(view.receivers[g], acts, 0)
        return out


@dataclass
class Certificate:
    """Upper bound on the scoring cells any plan can visit, and whether `plan` attains it."""

    plan_value: int  # scoring cells the plan visits
    bound: float  # upper bound on that number for any action sequences
    proven: bool  # plan_value == optimum
    method: str  # "reachability" (no IP needed), "milp" or "milp-time-limit"
    seconds: float
    variables: int
    elratio_bound: float


def _time_expanded(ep: Episode) -> np.ndarray:
    """[T+1, HW] bool nodes (c, t) some robot might occupy (over-approximation: holds allowed)."""
    t_max = ep.cfg.horizon
    reach = np.zeros((t_max + 1, len(ep.due)), dtype=bool)
    reach[0, ep.starts] = True
    ever = reach[0].copy()
    for t in range(1, t_max + 1):
        nb = ep.nbr[reach[t - 1]]
        reach[t, nb[nb >= 0]] = True
        reach[t] &= (ep.due >= t) | ever
        ever |= reach[t]
    return reach


def certify(cfg: WorldConfig, seed: int, episode: int, plan: Plan | np.ndarray,
            time_limit: float = 20.0, force_milp: bool = False) -> Certificate:
    """Upper-bound the scoring cells of episode (seed, episode) and test `plan` (a Plan or paths
    [N, T+1]) for optimality.

    The max-coverage integer program over the time-expanded grid: integer robot flow on arcs
    (c, t) -> (c', t+1) (robots may share cells), one binary x_c per scoring cell with x_c <= flow
    into (c, t) summed over t, and the world's exact dynamic-block rule: entering a dynamic cell
    after its due step needs a binary hold h_{c,t} (the cell occupied at every step since due).
    scipy's `milp` takes no start solution, so the plan enters as an objective cutoff
    sum x >= value + 1: HiGHS then prunes every node whose bound cannot beat the plan, and an
    infeasible answer proves the plan optimal. On the time limit the dual bound is reported.
    When the plan already covers every reachable scoring cell no IP is needed.
    """
    t0 = time.perf_counter()
    ep = Episode.generate(cfg, seed, episode)
    paths = plan.paths if isinstance(plan, Plan) else np.asarray(plan)
    value = int(_cover(ep, paths).any(0).sum())
    hw = cfg.cells
    reach_bound = int((ep.reachable() & ep.value).sum())

    def done(bound: float, proven: bool, method: str, nvar: int) -> Certificate:
        return Certificate(value, bound, proven, method, time.perf_counter() - t0, nvar,
                           (ep.base + bound) / hw)

    if value >= reach_bound and not force_milp:
        return done(float(reach_bound), True, "reachability", 0)
    try:
        from scipy.optimize import Bounds, LinearConstraint, milp
        from scipy.sparse import coo_matrix
    except ImportError:
        raise ImportError("certify needs scipy: pip install 'commattn-swarm[planning]'") from None
    t_max, n = cfg.horizon, cfg.n_robots
    node = _time_expanded(ep)
    # arcs (t, c -> q) with both ends existing
    tt, cc, aa = np.nonzero(node[:-1][:, :, None] & (ep.nbr[None] >= 0))
    qq = ep.nbr[cc, aa]
    ok = node[tt + 1, qq]
    tt, cc, aa, qq = tt[ok], cc[ok], aa[ok], qq[ok]
    n_arc = len(tt)
    dyn = np.flatnonzero((ep.due >= 0) & (ep.due <= t_max))
    # hold variables h[c, t] for dynamic c and due <= t < T, numbered after the arcs and x
    scoring = np.flatnonzero(ep.value & node.any(0))
    x_of = np.full(hw, -1, dtype=np.int64)
    x_of[scoring] = n_arc + np.arange(len(scoring))
    hold = [(c, t) for c in dyn for t in range(int(ep.due[c]), t_max) if node[t, c]]
    h_of = {ct: n_arc + len(scoring) + k for k, ct in enumerate(hold)}
    nvar = n_arc + len(scoring) + len(hold)
    rows: list[np.ndarray] = []
    cols: list[np.ndarray] = []
    vals: list[np.ndarray] = []
    lo: list[np.ndarray] = []
    hi: list[np.ndarray] = []
    nrow = 0

    def add(r: np.ndarray, c: np.ndarray, v: np.ndarray, lb: np.ndarray, ub: np.ndarray) -> None:
        nonlocal nrow
        rows.append(r + nrow)
        cols.append(c)
        vals.append(v.astype(np.float64))
        lo.append(lb)
        hi.append(ub)
        nrow += len(lb)

    arc = np.arange(n_arc)
    nid = tt * hw + cc  # tail node id
    hid = (tt + 1) * hw + qq  # head node id
    # flow: out(c, 0) = 1 at starts; in(c, t) = out(c, t) for 0 < t < T
    uniq, inv = np.unique(np.concatenate([nid, hid]), return_inverse=True)
    tail_r, head_r = inv[:n_arc], inv[n_arc:]
    ut = uniq // hw
    keep = ut < t_max
    rmap = np.cumsum(keep) - 1
    rhs = np.zeros(keep.sum())
    start_rows = rmap[np.searchsorted(uniq, ep.starts)]
    np.add.at(rhs, start_rows, -1.0)  # in - out = -1 at a start
    m_t = keep[tail_r]
    m_h = keep[head_r]
    add(np.concatenate([rmap[head_r[m_h]], rmap[tail_r[m_t]]]),
        np.concatenate([arc[m_h], arc[m_t]]),
        np.concatenate([np.ones(m_h.sum()), -np.ones(m_t.sum())]), rhs, rhs)
    # coverage: x_c - sum_{arcs into c} f <= 0
    into = x_of[qq] >= 0
    add(np.concatenate([np.arange(len(scoring)), (x_of[qq[into]] - n_arc)]),
        np.concatenate([x_of[scoring], arc[into]]),
        np.concatenate([np.ones(len(scoring)), -np.ones(into.sum())]),
        np.full(len(scoring), -np.inf), np.zeros(len(scoring)))
    # holds: h_{c,t} <= in(c,t); h_{c,t} <= h_{c,t-1}; entering c at t+1 > due needs h_{c,t}
    for c, t in hold:
        hv = h_of[(c, t)]
        arr = arc[(qq == c) & (tt == t - 1)]
        add(np.zeros(len(arr) + 1, dtype=np.int64), np.concatenate([[hv], arr]),
            np.concatenate([[1.0], -np.ones(len(arr))]), np.array([-np.inf]), np.zeros(1))
        if (c, t - 1) in h_of:
            add(np.zeros(2, dtype=np.int64), np.array([hv, h_of[(c, t - 1)]]),
                np.array([1.0, -1.0]), np.array([-np.inf]), np.zeros(1))
        enter = arc[(qq == c) & (tt == t) & (cc != c)]
        if len(enter):
            add(np.zeros(len(enter) + 1, dtype=np.int64), np.concatenate([enter, [hv]]),
                np.concatenate([np.ones(len(enter)), [-float(n)]]), np.array([-np.inf]),
                np.zeros(1))
    # entering a dynamic cell after due without a hold variable (never reached by due): forbid
    late = (ep.due[qq] >= 0) & (ep.due[qq] <= t_max) & (tt + 1 > ep.due[qq]) & (cc != qq)
    late &= np.array([(int(q), int(t)) not in h_of for q, t in zip(qq, tt, strict=True)])
    ub = np.concatenate([np.full(n_arc, float(n)), np.ones(nvar - n_arc)])
    ub[:n_arc][late] = 0.0
    # cutoff: beat the plan
    add(np.zeros(len(scoring), dtype=np.int64), x_of[scoring], np.ones(len(scoring)),
        np.array([value + 1.0]), np.array([np.inf]))
    a = coo_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                   shape=(nrow, nvar)).tocsr()
    obj = np.zeros(nvar)
    obj[x_of[scoring]] = -1.0
    res = milp(obj, integrality=np.ones(nvar), bounds=Bounds(np.zeros(nvar), ub),
               constraints=LinearConstraint(a, np.concatenate(lo), np.concatenate(hi)),
               options={"time_limit": float(time_limit)})
    if res.status == 2:  # nothing beats the plan
        return done(float(value), True, "milp", nvar)
    if res.status == 0:  # the plan was not optimal: the IP found the optimum
        return done(float(-res.fun), False, "milp", nvar)
    dual = getattr(res, "mip_dual_bound", None)
    bound = float(reach_bound) if dual is None or not np.isfinite(dual) else min(-dual, reach_bound)
    return done(max(bound, float(value)), False, "milp-time-limit", nvar)
