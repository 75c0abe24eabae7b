"""`python -m swarm.cli ...`: what the supervisor spawns its children with."""

import sys

from swarm.cli import main

sys.exit(main())
