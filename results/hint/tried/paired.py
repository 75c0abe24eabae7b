"""Per-episode elratio of policies on episodes 0..K-1 of seed 0 (greedy). A policy is
NAME[=CHECKPOINT[@MODE]], MODE swapping the hint for `tbhint.TBHint(MODE)`. From the
repository root:

    .venv/bin/python results/hint/tried/paired.py 200 results/hint/tried/team_beam_hint_200.json \
        "commattn=results/hint/hint_checkpoint.pt@tb" team-beam \
        "commattn=results/hint/hint_checkpoint.pt" "commattn=results/hint/hint_checkpoint.pt@and"
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

from swarm.common.policy_spec import build_policy
from world import core
from world.config import WorldConfig
from world.decentral import batch_view

sys.path.insert(0, str(Path(__file__).parent))
from tbhint import TBHint  # noqa: E402


def per_episode(cfg: WorldConfig, policy: object, episodes: int) -> list[float]:
    state = core.reset(cfg, 0, np.arange(episodes))
    policy.reset(episodes)  # type: ignore[attr-defined]
    while not state.done:
        core.step(cfg, state, policy.act(batch_view(cfg, state), greedy=True))  # type: ignore[attr-defined]
    return core.metrics(cfg, state).elratio.tolist()


def main(argv: list[str]) -> None:
    cfg, k, out = WorldConfig(), int(argv[0]), {}
    for spec in argv[2:]:
        name, _, rest = spec.partition("=")
        ck, _, mode = rest.partition("@")
        p = build_policy(name, cfg, ck or None)
        if mode:
            p.features.hint = TBHint(cfg, mode)  # type: ignore[attr-defined]
        out[spec] = per_episode(cfg, p, k)
        print(spec, np.mean(out[spec]), flush=True)
    Path(argv[1]).write_text(json.dumps(out))


if __name__ == "__main__":
    main(sys.argv[1:])
