"""Where a policy's robot-steps go, tick by tick (issue 17: what separates the learned policies
from the planners). Every robot-step of held-out episodes (seed 0, greedy) is one of:

- fresh: the robot moved onto a cell the team had not explored before this step;
- shared: it moved onto a fresh cell a lower-id robot also reached this step (one of them
  explores it, the others pay a robot collision);
- revisit: it moved onto a cell already explored (pays r_back);
- stay: it chose to stay (its own cell is explored: pays r_back);
- block: it moved into a block or off the grid (stays in place, a block collision).

    .venv/bin/python results/planners/steps.py 200 results/planners/steps_200.json \
        commattn commattn=results/belief/belief_big_checkpoint.pt commnet \
        coordinated-frontier nearest-frontier team-beam central

A policy is NAME (its shipped checkpoint) or NAME=CHECKPOINT; the JSON has, per policy, the
mean count of each kind per episode, the same per tick, and the mean final elratio.
"""
from __future__ import annotations

import sys

import numpy as np

from swarm.common.atomic import write_json
from swarm.common.policy_spec import build_policy
from world import core
from world.config import WorldConfig
from world.decentral import batch_view

KINDS = ("fresh", "shared", "revisit", "stay", "block")


def classify(actions: np.ndarray, before: np.ndarray, p0: np.ndarray,
             p1: np.ndarray) -> np.ndarray:
    """Kind index [B, N] of each robot-step from the actions, the explored set before the step
    and the positions before and after it."""
    stay = actions == 0
    block = ~stay & (p1 == p0)
    revisit = ~stay & ~block & np.take_along_axis(before, p1, axis=1)
    n = p1.shape[1]
    same = (p1[:, :, None] == p1[:, None, :]) & np.tril(np.ones((n, n), dtype=bool), -1)
    moved_fresh = ~stay & ~block & ~revisit
    # a fresh cell shared with a lower-id robot that also moved onto it this step
    shared = moved_fresh & (same & moved_fresh[:, None, :]).any(axis=2)
    kind = np.full(p1.shape, KINDS.index("fresh"))
    for name, where in (("shared", shared), ("revisit", revisit), ("stay", stay),
                        ("block", block)):
        kind[where] = KINDS.index(name)
    return kind


def run(cfg: WorldConfig, spec: str, episodes: int) -> dict:
    name, _, checkpoint = spec.partition("=")
    policy = build_policy(name, cfg, checkpoint or None)
    state = core.reset(cfg, 0, np.arange(episodes))
    policy.reset(episodes)
    per_tick = np.zeros((cfg.horizon, len(KINDS)))
    while not state.done:
        actions = policy.act(batch_view(cfg, state), greedy=True)
        before, p0, t = state.explored.copy(), state.pos.copy(), state.t
        core.step(cfg, state, actions)
        kind = classify(actions, before, p0, state.pos)[state.alive]
        per_tick[t] = np.bincount(kind, minlength=len(KINDS)) / episodes
    return {"policy": spec, "elratio": float(core.metrics(cfg, state).elratio.mean()),
            "per_episode": dict(zip(KINDS, per_tick.sum(0).round(2).tolist(), strict=True)),
            "per_tick": {k: per_tick[:, i].round(3).tolist() for i, k in enumerate(KINDS)}}


def main(argv: list[str]) -> None:
    if len(argv) < 3:
        sys.exit("usage: steps.py EPISODES OUT.json POLICY[=CHECKPOINT] ...")
    episodes, out, specs = int(argv[0]), argv[1], argv[2:]
    cfg = WorldConfig()
    rows = []
    for spec in specs:
        row = run(cfg, spec, episodes)
        rows.append(row)
        print(f"{spec:60s} elratio {row['elratio']:.4f}  "
              + "  ".join(f"{k} {v:6.2f}" for k, v in row["per_episode"].items()), flush=True)
    write_json(out, {"command": "results/planners/steps.py " + " ".join(argv),
                     "episodes": f"seed 0, episodes 0-{episodes - 1}", "kinds": list(KINDS),
                     "rows": rows})


if __name__ == "__main__":
    main(sys.argv[1:])
