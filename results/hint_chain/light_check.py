"""The fine-tuned checkpoint (argument; default runs/hcp_e1.pt, a copy after epoch 1) against its
start (`hint_tb_checkpoint.pt` with the chain-plan hint and a prior of 8), both handed the light
hint they trained with (beam 8, one pass), paired on episodes 0-49 of seed 0:

    .venv/bin/python results/hint_chain/light_check.py runs/hcp_e1.pt
"""
import numpy as np, torch, sys
from policies import make_policy
from swarm.learn.evaluate import evaluate
from swarm.common.report import paired
from world.config import WorldConfig
torch.set_num_threads(1)
cfg = WorldConfig()
out = {}
for name, ck, ch in (("start", "results/hint_tb/hint_tb_checkpoint.pt", True), ("e1", sys.argv[1] if len(sys.argv) > 1 else "runs/hcp_e1.pt", False)):
    p = make_policy("commattn", cfg, checkpoint=ck)
    if ch: p.set_model(hint_planner="chain-plan", hint_prior=8.0)
    p.set_model(hint_beam=8, hint_passes=1)
    out[name] = evaluate(cfg, p, 0, 50).elratio
    print(name, out[name].mean(), flush=True)
print("e1 - start (light hint)", paired(out["e1"], out["start"]))
