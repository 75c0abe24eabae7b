"""The chain-plan-hint network with a prior of 16 (`chain_prior16_checkpoint.pt`, 0.9514 on the
1000 held-out episodes) under `swarm repro comm`'s bandwidth caps on 20 x 20 (the same
conditions and seed as `results/repro/comm.md`, its first 100 episodes, as
`results/planners/chain_plan_comm.py`), with `chain-plan`, `team-beam` and coordinated frontier
re-run on the same episodes for paired differences. Its hidden-state message carries the
decoder state and `chain-plan`'s plan (64 + 70 floats): what does a cap do to it, queued and
with `--overflow expire`?

    .venv/bin/python results/hint_chain/comm.py OUT.json I [I ...] [--episodes K]

I: indices into `swarm.studies.comm.CONDITIONS` (6: cap 60 B/s, queued; 11: the same cap with
`expire`); ~25 min a condition on one core. `comm.json` holds 11 (6 was stopped unfinished).
`--pair-only` runs the network and `chain-plan` alone (~12 min a condition; the other two are
in `results/planners/chain_plan_comm.json`, same episodes): `comm_pair_a.json` (range 5,
range 3), `comm_pair_b.json` (loss 30%, loss 50%), `_c` (the queued cap), `_d` (range 2),
`_e` (range 3 + loss 50%), `_f` (both 40 x 40 tasks, `--episodes 30`).
"""
import sys

from swarm.studies.comm import paired_script

EPISODES, SEED = 100, 0
CKPT = "results/hint_chain/chain_prior16_checkpoint.pt"
SPECS = {"chain-hint": ("commattn", CKPT), "chain-plan": ("chain-plan", None),
         "team-beam": ("team-beam", None), "coordinated-frontier": ("coordinated-frontier", None)}
argv = sys.argv[1:]
pair_only = "--pair-only" in argv
if pair_only:  # (the JSON's `command` then lacks the flag; `pair_only` records it)
    argv.remove("--pair-only")
    SPECS = {k: SPECS[k] for k in ("chain-hint", "chain-plan")}
paired_script(argv, "results/hint_chain/comm.py", SPECS, SEED, EPISODES, checkpoint=CKPT,
              pair_only=pair_only)
