"""`python -m swarm.cli ...`: what the supervisor spawns its children with."""

import signal
import sys

from swarm.cli import main

# Done: a stop signal arriving while the interpreter shuts down (the supervisor stopping every
# child at once) must not print a KeyboardInterrupt traceback from threading's shutdown. The
# signals are ignored inside the same `try` as main() returns in: one that lands between the
# two (it did, in a clean secure run's robot log) is the stop this child was about to obey.
code = 130
try:
    code = main()
    for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
        signal.signal(sig, signal.SIG_IGN)
except KeyboardInterrupt:
    for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
        signal.signal(sig, signal.SIG_IGN)
sys.exit(code)
