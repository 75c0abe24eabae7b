"""`chain-plan` under `swarm repro comm`'s scarce-communication conditions on 20 x 20 (the same
conditions and seed as `results/repro/comm.md`, its first 100 episodes), with `team-beam`,
CommAttn and coordinated frontier re-run on the same episodes for paired differences. A plan
rides in the hidden-state message (1,280 bytes a robot a tick here, CommAttn's state 128):
how much of its lead survives loss, short range and bandwidth caps?

    .venv/bin/python results/planners/chain_plan_comm.py OUT.json I [I ...]

I: indices into `swarm.studies.comm.CONDITIONS` (20 x 20 ones only).
"""
import sys

from swarm.studies.comm import paired_script

EPISODES, SEED = 100, 0
SPECS = {"chain-plan": ("chain-plan", None), "team-beam": ("team-beam", None),
         "commattn": ("commattn", None), "coordinated-frontier": ("coordinated-frontier", None)}
paired_script(sys.argv[1:], "results/planners/chain_plan_comm.py", SPECS, SEED, EPISODES)
