"""`python -m swarm.cli ...`: what the supervisor spawns its children with."""

import signal
import sys

from swarm.cli import main

code = main()
# Done: a stop signal arriving while the interpreter shuts down (the supervisor stopping every
# child at once) must not print a KeyboardInterrupt traceback from threading's shutdown.
signal.signal(signal.SIGINT, signal.SIG_IGN)
signal.signal(signal.SIGTERM, signal.SIG_IGN)
sys.exit(code)
