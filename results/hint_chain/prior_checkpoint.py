"""`chain_prior_checkpoint.pt` (prior 8) and `chain_prior16_checkpoint.pt` (prior 16):
`results/hint_tb/hint_tb_checkpoint.pt`'s weights (trained on `team-beam`'s hint, never on this
one) reading `chain-plan`'s move with its own search (model fields hint_planner "chain-plan",
hint_beam 32, hint_passes 4) and a prior of 8 or 16 on it (hint_prior), so `swarm eval` and
`swarm run` run what `held_out.py` measured as `prior8_1000.json` and `prior16_1000.json`.
From the repository root:

    .venv/bin/python results/hint_chain/prior_checkpoint.py        # both
"""

from __future__ import annotations

from policies import make_policy
from policies.checkpoint import save_checkpoint
from world.config import WorldConfig

cfg = WorldConfig()
for prior, name in ((8.0, "chain_prior_checkpoint.pt"), (16.0, "chain_prior16_checkpoint.pt")):
    policy = make_policy("commattn", cfg, checkpoint="results/hint_tb/hint_tb_checkpoint.pt")
    policy.set_model(hint_planner="chain-plan", hint_prior=prior, hint_beam=32, hint_passes=4)
    save_checkpoint(f"results/hint_chain/{name}",
                    policy.payload({"made_by": "results/hint_chain/prior_checkpoint.py",
                                    "weights_of": "results/hint_tb/hint_tb_checkpoint.pt"}))
