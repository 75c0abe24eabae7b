"""How much could a network that overrides `chain-plan` buy? At sampled decision points (tick
t, robot i) of held-out episodes, every one of robot i's 9 moves is tried in place of the
plan's move, the rest of the team and every later tick acting as `chain-plan` (robot i's
message is the plan as it sent it, so this is exactly a hint network overriding its hint), and
the episode's final elratio is taken. The gain of a move is its elratio minus the plan's on the
same episode, same world, same future.

This is a ceiling, not an estimate of what learning can reach: each alternative is scored on the
episode's true future (the block schedule), which no policy knows, and the best of 8 noisy
alternatives is picked after the fact. If even the ceiling is small, overrides of the plan are
not where a learned policy gets above it.

    .venv/bin/python results/hint_chain/override_ceiling.py run SEED FIRST COUNT K OUT.json
    .venv/bin/python results/hint_chain/override_ceiling.py sum OUT.json PART.json [PART.json ...]

K decision points per episode (tick uniform in 0..T-2, robot uniform; seeded by SEED, episode).
About 10 s a point on one core (8 continuations of the rest of the episode).
"""

from __future__ import annotations

import copy
import json
import sys

import numpy as np

from policies import make_policy
from swarm.common.atomic import write_json
from world import core
from world.config import WorldConfig
from world.decentral import batch_view


def finish(cfg: WorldConfig, state: core.WorldState, policy, first: np.ndarray | None
           ) -> tuple[float, bool]:
    """Step `state` to the end with `policy`, `first` [1, N] the actions of its current tick."""
    a = first
    while not state.done:
        if a is None:
            a = policy.act(batch_view(cfg, state), greedy=True)
        core.step(cfg, state, a)
        a = None
    m = core.metrics(cfg, state)
    return float(m.elratio[0]), bool(m.success[0])


def run(seed: int, first: int, count: int, k: int, out: str) -> None:
    cfg = WorldConfig()
    points = []
    for e in range(first, first + count):
        rng = np.random.default_rng([seed, e, 17])
        picks: dict[int, list[int]] = {}
        for t, i in zip(rng.integers(0, cfg.horizon - 1, k).tolist(),
                        rng.integers(0, cfg.n_robots, k).tolist(), strict=True):
            picks.setdefault(t, []).append(i)
        policy = make_policy("chain-plan", cfg)
        state = core.reset(cfg, seed, np.array([e]))
        policy.reset(1)
        rows = []
        while not state.done:
            a = policy.act(batch_view(cfg, state), greedy=True)
            for i in picks.get(state.t, []):
                snap = copy.deepcopy((state, policy))
                el = np.zeros(9)
                ok = np.zeros(9, dtype=bool)
                for m in range(9):
                    st, pol = copy.deepcopy(snap)
                    alt = a.copy()
                    alt[0, i] = m
                    el[m], ok[m] = finish(cfg, st, pol, alt)
                rows.append({"episode": e, "tick": int(state.t), "robot": i,
                             "plan_move": int(a[0, i]), "elratio": el.tolist(),
                             "success": ok.tolist()})
            core.step(cfg, state, a)
        base = float(core.metrics(cfg, state).elratio[0])
        for r in rows:  # the plan's own move must replay the episode exactly
            assert r["elratio"][r["plan_move"]] == base, (r, base)
            points.append(r)
        print(e, len(points), flush=True)
        write_json(out, {"command": f"override_ceiling.py run {seed} {first} {count} {k} {out}",
                         "seed": seed, "points": points})


def summarize(out: str, parts: list[str]) -> None:
    points = [p for f in parts for p in json.load(open(f))["points"]]
    gains = np.array([np.array(p["elratio"]) - p["elratio"][p["plan_move"]] for p in points])
    alt = gains.copy()
    for r, p in enumerate(points):
        alt[r, p["plan_move"]] = -np.inf
    best = alt.max(1)
    others = np.stack([np.delete(g, p["plan_move"]) for g, p in zip(gains, points, strict=True)])
    ticks = np.array([p["tick"] for p in points])
    by_tick = {}
    for lo, hi in ((0, 10), (10, 20), (20, 30)):
        s = (ticks >= lo) & (ticks < hi)
        by_tick[f"ticks {lo}-{hi - 1}"] = {
            "points": int(s.sum()), "best_alternative_gain": float(best[s].mean()),
            "mean_gain_of_an_alternative": float(others[s].mean()),
            "share_of_alternatives_equal": float((others[s] == 0).mean())}
    spread = float(others.std(1, ddof=1).mean())
    mu = float(others.mean())
    per_episode = {}
    for p, b in zip(points, best, strict=True):
        per_episode.setdefault(p["episode"], []).append(b)
    result = {
        "command": "override_ceiling.py sum " + " ".join([out, *parts]),
        "points": len(points), "episodes": len(per_episode),
        "best_alternative_gain": {"mean": float(best.mean()),
                                  "se": float(best.std(ddof=1) / np.sqrt(len(best))),
                                  "median": float(np.median(best))},
        "share_of_points_with_a_better_move": float((best > 0).mean()),
        "share_where_the_plan_move_is_strictly_best": float((best < 0).mean()),
        "mean_gain_of_a_random_alternative": mu,
        "alternatives_better_equal_worse": [float((others > 0).mean()),
                                            float((others == 0).mean()),
                                            float((others < 0).mean())],
        "spread_of_alternatives_within_a_point": spread,
        # the best of 8 draws of a normal with that mean and spread (E[max] = 1.4236 sd)
        "best_of_8_if_pure_noise": mu + 1.4236 * spread,
        "by_tick": by_tick,
        "largest_gain": float(best.max()),
        "one_cell": 1.0 / WorldConfig().cells,
        "note": "gains in elratio; a ceiling: each move scored on the episode's true future",
    }
    write_json(out, {**result, "parts": parts})
    print(json.dumps(result, indent=1))


if __name__ == "__main__":
    argv = sys.argv[1:]
    if argv[0] == "run":
        run(int(argv[1]), int(argv[2]), int(argv[3]), int(argv[4]), argv[5])
    else:
        summarize(argv[1], argv[2:])
