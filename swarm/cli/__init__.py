"""The `swarm` console script: one parser, one module per command family (all thin).

`swarm.cli.batch`: eval, bench, repro, train (in-process, but for `bench swarm|rollout|record`,
which time real processes); `swarm.cli.run`: run, world, robot, fault, experiment (the
distributed swarm); `swarm.cli.learn`: learner, rollout-worker;
`swarm.cli.secure`: certs, audit; `swarm.cli.record`: record, replay, trace; `swarm.cli.hosts`:
router.
"""

from __future__ import annotations

import signal
import threading

# SIGINT is Ctrl-C even where it came in ignored: a shell without job control starts `swarm run
# ... &` with SIGINT ignored, and Python then never raises KeyboardInterrupt; the supervisor and
# its children stop on SIGINT, so a run started so would otherwise be deaf to `kill -INT` and to
# its stop. Taken here, before the command modules load (~0.1 s, longer on a loaded machine): a
# SIGINT that lands while it is still ignored is lost for good (a run sent `kill -INT` right
# after its start went on to its end), so one that lands during the imports is kept for main().
# (Where SIGINT is not ignored, Python's own handler is in place: left alone.) What is left is
# the interpreter's own start, ~20-40 ms, before any line of ours runs.
_early_interrupt: list[int] = []
if threading.current_thread() is threading.main_thread() and \
        signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
    signal.signal(signal.SIGINT, lambda sig, frame: _early_interrupt.append(sig))

import argparse  # noqa: E402
import os  # noqa: E402
import sys  # noqa: E402
from collections.abc import Sequence  # noqa: E402

from swarm.cli import batch, hosts, learn, record, run, secure  # noqa: E402
from swarm.cli.checks import check_paths  # noqa: E402
from swarm.cli.common import _Parser  # noqa: E402
from swarm.common import flags  # noqa: E402
from swarm.common.report import OutputClosed  # noqa: E402
from swarm.common.spawn import (  # noqa: E402
    die_with_parent,
    terminate_as_interrupt,
    unblock_stops,
)
from world.config import ConfigError  # noqa: E402


def _version() -> str:
    """The installed package's version and the commit it was installed from (results name it
    too: `provenance`)."""
    from importlib.metadata import PackageNotFoundError, version

    from swarm.common.report import provenance

    try:
        v = version("commattn-swarm")
    except PackageNotFoundError:  # (run from a source tree, not installed)
        v = "(not installed)"
    git = provenance().get("git")
    return f"{v} ({git})" if git else v


class _Version(argparse.Action):
    """`--version`, computed only when asked (it runs git); with where the shipped data is (an
    installed package keeps checkpoints/ and deploy/ outside site-packages)."""

    def __call__(self, parser: argparse.ArgumentParser, *args: object) -> None:
        from swarm.common.shipped import DATA

        print(f"swarm {_version()}\ndata: {DATA} (checkpoints/, deploy/)")
        parser.exit()


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="swarm", description="CommAttn swarm emulator: evaluate, benchmark "
                     "and reproduce the paper's experiments.")
    parser.add_argument("--version", action=_Version, nargs=0,
                        help="print the version, the source tree's commit and where the "
                             "shipped checkpoints/ and deploy/ are, then exit")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    batch.add_parsers(sub)
    run.add_parsers(sub)
    learn.add_parsers(sub)
    run.add_robot_parser(sub)
    record.add_parsers(sub)
    secure.add_parsers(sub)
    hosts.add_parsers(sub)
    return parser


_prebuilt: list[argparse.ArgumentParser] = []
"""The parser of a supervised child, built once before it was forked (`preload_child`)."""


def preload_child() -> None:
    """In the fork server (`swarm.common.forkserver`), before it forks: what the world and a
    robot import (not torch: a robot runs its network in numpy), and the parser a supervised
    child takes (each built its own: ~480 flags, 0.05-0.3 CPU-s)."""
    import policies.belief  # noqa: F401
    import policies.grid_search  # noqa: F401
    import policies.infer.policy  # noqa: F401
    import swarm.procs.robot  # noqa: F401
    import swarm.procs.robot_status  # noqa: F401
    import swarm.procs.world  # noqa: F401

    flags.HELP = False
    _prebuilt.append(build_parser())


def run_as_child(argv: Sequence[str] | None = None) -> int:
    """main() as a child process runs it (`python -m swarm.cli`, or forked by the fork server);
    returns the exit status.

    A stop signal arriving while the interpreter shuts down (the supervisor stopping every
    child at once) must not print a KeyboardInterrupt traceback from threading's shutdown. The
    signals are ignored inside the same `try` as main() returns in: one that lands between the
    two (it did, in a clean secure run's robot log) is the stop this child was about to obey."""
    code = 130
    try:
        code = main(argv)
        for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
            signal.signal(sig, signal.SIG_IGN)
    except KeyboardInterrupt:
        for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
            signal.signal(sig, signal.SIG_IGN)
    return code


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the `swarm` console script; returns the exit status."""
    # a child of `swarm run` goes when its supervisor goes, SIGKILL included (with a deadline);
    # SIGTERM and SIGHUP clean up like Ctrl-C (children stopped, files closed, namespaces
    # removed); SIGINT: see the top
    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGINT, signal.default_int_handler)
    supervised = die_with_parent()
    if not supervised:
        terminate_as_interrupt()
    try:  # a child's stops come blocked (`start_child`): one sent while it loaded lands here
        unblock_stops()
    except KeyboardInterrupt:
        _early_interrupt.append(signal.SIGINT)
    if _early_interrupt:  # interrupted while the modules loaded: nothing started yet
        _early_interrupt.clear()
        print("swarm: interrupted", file=sys.stderr)
        return 130
    flags.HELP = not supervised  # (a child prints no help: its flags need none)
    if not supervised:
        from policies import SKIPPED  # (once a command: not again in each child's log)

        for line in SKIPPED:
            print(f"swarm: warning: {line}", file=sys.stderr)
    parser = _prebuilt.pop() if _prebuilt and supervised else build_parser()
    args, extra = parser.parse_known_args(argv)
    if extra:  # named after the subcommand whose --help lists what it takes
        prog = " ".join(["swarm", *(getattr(args, k, None) or "" for k in ("command", "what"))])
        parser.exit(2, f"swarm: error: unrecognized arguments: {' '.join(extra)} "
                       f"(see {prog.strip()} --help)\n")
    if getattr(args, "func", None) is None:
        parser.print_help(sys.stderr)
        return 2
    try:
        check_paths(args)  # (no output over an input or another output: before anything runs)
        return args.func(args)
    except ConfigError as exc:
        print(f"swarm: error: {' '.join(str(exc).split())}", file=sys.stderr)
        return 2
    except (BrokenPipeError, OutputClosed):  # (`swarm eval ... | head`: the reader went away)
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())  # (a quiet exit flush)
        print("swarm: stdout was closed (its reader went away)", file=sys.stderr)
        return 141
    except OSError as exc:
        print(f"swarm: error: {exc}", file=sys.stderr)
        return 1
    except (RuntimeError, TimeoutError) as exc:  # a run that failed: one line, the logs named
        print(f"swarm: error: {' '.join(str(exc).split())}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("swarm: interrupted", file=sys.stderr)
        return 130
