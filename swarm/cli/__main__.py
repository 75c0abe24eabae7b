"""`python -m swarm.cli ...`: what the supervisor spawns its children with."""

import sys

from swarm.cli import run_as_child

sys.exit(run_as_child())
