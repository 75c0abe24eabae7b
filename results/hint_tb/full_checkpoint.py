"""`hint_tb_full_checkpoint.pt`: `hint_tb_checkpoint.pt`'s weights with the hint's search set to
`team-beam`'s own (model fields hint_beam 24, hint_passes 2), so `swarm eval` and `swarm run`
run what `full_search.py` measured. From the repository root:

    .venv/bin/python results/hint_tb/full_checkpoint.py
"""

from __future__ import annotations

from policies import make_policy
from policies.checkpoint import save_checkpoint
from world.config import WorldConfig

cfg = WorldConfig()
policy = make_policy("commattn", cfg, checkpoint="results/hint_tb/hint_tb_checkpoint.pt")
policy.set_model(hint_beam=24, hint_passes=2)
save_checkpoint("results/hint_tb/hint_tb_full_checkpoint.pt",
                policy.payload({"made_by": "results/hint_tb/full_checkpoint.py",
                                "weights_of": "results/hint_tb/hint_tb_checkpoint.pt"}))
