"""The best learned policy (`hint_tb_full_checkpoint.pt`: CommAttn reading `team-beam`'s full
search as its hint) under `swarm repro comm`'s scarce-communication conditions on 20 x 20 (the
same conditions, seed and 200 episodes as `results/repro/comm.md` and
`results/planners/team_beam_comm.py`), with `team-beam`, the shipped CommAttn and coordinated
frontier re-run on the same episodes for paired differences. Where does the learned part pay,
and where does it inherit its planner's losses?

    .venv/bin/python results/hint_tb/comm.py OUT.json I [I ...]

I: indices into `swarm.studies.comm.CONDITIONS` (0-8 are the 20 x 20 ones; ~315 s a condition
on one core, the network and `team-beam` most of it). The README's table is `comm_a.json`
(0-4) and `comm_b.json` (5-8).
"""
import sys

from swarm.studies.comm import paired_script

EPISODES, SEED = 200, 0
CKPT = "results/hint_tb/hint_tb_full_checkpoint.pt"
SPECS = {"hint": ("commattn", CKPT), "team-beam": ("team-beam", None),
         "commattn": ("commattn", None), "coordinated-frontier": ("coordinated-frontier", None)}
paired_script(sys.argv[1:], "results/hint_tb/comm.py", SPECS, SEED, EPISODES, checkpoint=CKPT)
