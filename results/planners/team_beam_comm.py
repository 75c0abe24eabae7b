"""`team-beam` under `swarm repro comm`'s scarce-communication conditions on 20 x 20 (the same
conditions, seed and episodes as `results/repro/comm.md`), with CommAttn and coordinated
frontier re-run on the same episodes for paired differences. How much a planner that depends on
what it hears loses as communication gets scarce, next to the learned policy:

    .venv/bin/python results/planners/team_beam_comm.py OUT.json I [I ...]

I: indices into `swarm.studies.comm.CONDITIONS` (the 40 x 40 ones are too slow for team-beam
here: every robot plans every robot it hears). 200 episodes of seed 0 per condition.
"""
import sys

from swarm.studies.comm import paired_script

EPISODES, SEED = 200, 0
SPECS = {"team-beam": ("team-beam", None), "commattn": ("commattn", None),
         "coordinated-frontier": ("coordinated-frontier", None)}
paired_script(sys.argv[1:], "results/planners/team_beam_comm.py", SPECS, SEED, EPISODES)
