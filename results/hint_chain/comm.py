"""The chain-plan-hint network with a prior of 16 (`chain_prior16_checkpoint.pt`, 0.9514 on the
1000 held-out episodes) under `swarm repro comm`'s bandwidth caps on 20 x 20 (the same
conditions and seed as `results/repro/comm.md`, its first 100 episodes, as
`results/planners/chain_plan_comm.py`), with `chain-plan`, `team-beam` and coordinated frontier
re-run on the same episodes for paired differences. Its hidden-state message carries the
decoder state and `chain-plan`'s plan (64 + 70 floats): what does a cap do to it, queued and
with `--overflow expire`?

    .venv/bin/python results/hint_chain/comm.py OUT.json I [I ...] [--episodes K]

I: indices into `swarm.studies.comm.CONDITIONS` (6: cap 60 B/s, queued; 11: the same cap with
`expire`); ~8 min a condition on one core. `comm.json` holds 6 and 11.
"""
import sys

from swarm.studies.comm import paired_script

EPISODES, SEED = 100, 0
CKPT = "results/hint_chain/chain_prior16_checkpoint.pt"
SPECS = {"chain-hint": ("commattn", CKPT), "chain-plan": ("chain-plan", None),
         "team-beam": ("team-beam", None), "coordinated-frontier": ("coordinated-frontier", None)}
paired_script(sys.argv[1:], "results/hint_chain/comm.py", SPECS, SEED, EPISODES, checkpoint=CKPT)
