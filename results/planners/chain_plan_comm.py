"""`chain-plan` under `swarm repro comm`'s scarce-communication conditions on 20 x 20 (the same
conditions and seed as `results/repro/comm.md`, its first 100 episodes), with `team-beam`,
CommAttn and coordinated frontier re-run on the same episodes for paired differences. A plan
rides in the hidden-state message (280 bytes a robot a tick here, packed; CommAttn's state
128): how much of its lead survives loss, short range and bandwidth caps?

`chain_plan_comm.json` holds every condition; its two bandwidth-cap rows were re-run after the
plan was packed (it was 1,280 bytes, every cell a float; `rows_before_packing` keeps those
rows). Packing is lossless, so the other rows are what the packed plan gives too.

    .venv/bin/python results/planners/chain_plan_comm.py OUT.json I [I ...] [--episodes K]

I: indices into `swarm.studies.comm.CONDITIONS`; `--episodes K` for fewer (the 40 x 40 rows: 30).
"""
import sys

from swarm.studies.comm import paired_script

EPISODES, SEED = 100, 0
SPECS = {"chain-plan": ("chain-plan", None), "team-beam": ("team-beam", None),
         "commattn": ("commattn", None), "coordinated-frontier": ("coordinated-frontier", None)}
paired_script(sys.argv[1:], "results/planners/chain_plan_comm.py", SPECS, SEED, EPISODES)
