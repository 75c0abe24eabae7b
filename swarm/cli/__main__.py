"""`python -m swarm.cli ...`: what the supervisor spawns its children with; and, as `python -m
swarm.cli --fork-server FD RUN_ID PAD`, the run's fork server, which forks the world and the
robots (`swarm.common.forkserver`): each child returns from `serve` and runs its CLI here."""

import sys

from swarm.cli import preload_child, run_as_child
from swarm.common.forkserver import SERVE, serve

if len(sys.argv) > 3 and sys.argv[1] == SERVE and sys.argv[2].isdigit():  # (else: refused)
    argv = serve(int(sys.argv[2]), sys.argv[3], preload_child)
    if argv is None:  # (the server's end)
        sys.exit(0)
    sys.argv = [sys.argv[0], *argv]  # (its signal dispositions are the server's: a spawned
    sys.exit(run_as_child(argv))  # child's, SIGHUP ignored under nohup included)
sys.exit(run_as_child())
