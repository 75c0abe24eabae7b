"""`chain_prior_checkpoint.pt`: `results/hint_tb/hint_tb_checkpoint.pt`'s weights (trained on
`team-beam`'s hint, never on this one) reading `chain-plan`'s move with its own search (model
fields hint_planner "chain-plan", hint_beam 32, hint_passes 4) and a prior of 8 on it
(hint_prior), so `swarm eval` and `swarm run` run what `held_out.py` measured as
`prior8_1000.json`. From the repository root:

    .venv/bin/python results/hint_chain/prior_checkpoint.py
"""

from __future__ import annotations

from policies import make_policy
from policies.checkpoint import save_checkpoint
from world.config import WorldConfig

cfg = WorldConfig()
policy = make_policy("commattn", cfg, checkpoint="results/hint_tb/hint_tb_checkpoint.pt")
policy.set_model(hint_planner="chain-plan", hint_prior=8.0, hint_beam=32, hint_passes=4)
save_checkpoint("results/hint_chain/chain_prior_checkpoint.pt",
                policy.payload({"made_by": "results/hint_chain/prior_checkpoint.py",
                                "weights_of": "results/hint_tb/hint_tb_checkpoint.pt"}))
