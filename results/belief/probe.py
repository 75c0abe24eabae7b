"""Is the planner's choice learnable from what a CommAttn robot reads? A supervised probe for
issue 17: label the states the shipped CommAttn visits with `team-beam`'s action sets (4 draws
of its tie-break noise, as `swarm train --imitate team-beam --imitate-samples 4`), then fit the
shipped network to those sets offline, once with its own inputs and once with the belief
features (`--belief`), from the same start, and report how often its greedy action falls in
the set on held-out states. Usage, from the repository root:

    .venv/bin/python results/belief/probe.py label DATA.pkl EPISODES FIRST  # a labelled shard
    .venv/bin/python results/belief/probe.py fit OUT.json EPOCHS SHARD.pkl ...  # last: held out

Labels: episodes FIRST .. FIRST + EPISODES - 1 of seed 3,000,000 (outside training, validation
and evaluation seeds), the shipped CommAttn acting (sampled), ~4 core-seconds an episode.
"""

from __future__ import annotations

import json
import pickle
import sys

import numpy as np
import torch

from policies import make_policy
from swarm.common.atomic import write_json
from swarm.learn.rollout import collect
from world.config import WorldConfig

SEED, CKPT, BATCH = 3_000_000, "checkpoints/commattn.pt", 20
STEP_TICKS = 5  # ticks of one labelled batch per optimizer step (48 steps an epoch)


def label(out: str, episodes: int, first: int) -> None:
    torch.set_num_threads(1)
    world = WorldConfig()
    policy = make_policy("commattn", world, checkpoint=CKPT)
    shards = []
    for lo in range(first, first + episodes, BATCH):
        eps = np.arange(lo, min(lo + BATCH, first + episodes))
        roll = collect(policy, world, SEED, eps, teacher="team-beam", teacher_samples=4)
        shards.append((roll.views, roll.actions, roll.labels))
        print(f"labelled episodes {eps[0]}..{eps[-1]}", flush=True)
    with open(out, "wb") as f:
        pickle.dump(shards, f)


def prepared(policy, part):
    """The features of every view of `part`, memories refolded for this network."""
    out = []
    for _, views, actions, labels in part:
        for v in views:
            v.belief = v.team_visited = None
        policy.remember_episode(views)
        out.append((views, actions, labels, [policy.features(v) for v in views]))
    return out


def agreement(policy, part) -> float:
    """How often the greedy action is in the teacher's set."""
    with torch.no_grad():
        agree = [policy.evaluate(v, a, f, targets=lab).agree for v, a, lab, f in part]
    return float(np.concatenate(agree).mean())


def fit(out: str, epochs: int, paths: list[str]) -> None:
    torch.set_num_threads(1)
    world = WorldConfig()
    batches = []
    for path in paths:
        with open(path, "rb") as f:
            batches += [(path, *b) for b in pickle.load(f)]
    held = [b for b in batches if b[0] == paths[-1]]
    train = [b for b in batches if b[0] != paths[-1]]
    rows = []
    for belief in (False, True):
        torch.manual_seed(0)
        policy = make_policy("commattn", world, checkpoint=CKPT)
        if belief:
            policy.widen(belief=True)
        opt = torch.optim.Adam(policy.net.parameters(), lr=1e-3)
        tr, ho = prepared(policy, train), prepared(policy, held)
        curve = [(0, agreement(policy, tr), agreement(policy, ho))]
        for epoch in range(1, epochs + 1):
            for v, a, lab, f in tr:
                for t in range(0, len(v), STEP_TICKS):  # ticks are independent given features
                    span = slice(t, t + STEP_TICKS)
                    ev = policy.evaluate(v[span], a[span], f[span], targets=lab[span])
                    loss = -ev.logp.mean()
                    opt.zero_grad()
                    loss.backward()
                    opt.step()
            curve.append((epoch, agreement(policy, tr), agreement(policy, ho)))
            print(json.dumps({"belief": belief, "epoch": epoch, "train_in_set": curve[-1][1],
                              "held_out_in_set": curve[-1][2]}), flush=True)
        rows.append({"belief": belief, "curve": curve})
    write_json(out, {"command": " ".join(["results/belief/probe.py", "fit", out, str(epochs),
                                          *paths]),
                     "decisions": {"train": int(sum(np.count_nonzero(lab) for *_, labs in train
                                                    for lab in labs)),
                                   "held_out": int(sum(np.count_nonzero(lab) for *_, labs in held
                                                       for lab in labs))},
                     "rows": rows})


if __name__ == "__main__":
    if len(sys.argv) >= 5 and sys.argv[1] == "label":
        label(sys.argv[2], int(sys.argv[3]), int(sys.argv[4]))
    elif len(sys.argv) >= 5 and sys.argv[1] == "fit":
        fit(sys.argv[2], int(sys.argv[3]), sys.argv[4:])
    else:
        sys.exit(__doc__)
