"""`python -m swarm.cli.forkserver FD RUN_ID PAD`: a run's fork server (its supervisor's end,
and why: `swarm.common.forkserver`). It loads what the world and a robot import, then forks a
`swarm.cli` child per request on socket FD until the socket closes; the child returns from
`serve` to run the CLI as `python -m swarm.cli` would, with its own environment, standard
streams, signal handlers and command line."""

from __future__ import annotations

import contextlib
import json
import os
import signal
import socket
import sys
import time

from swarm.common.forkserver import MODULE, prctl, set_cmdline
from swarm.common.spawn import PR_SET_PDEATHSIG, cli_args

_MAX_REQUEST = 1 << 20


def _preload() -> None:
    """What the world and a robot import (not torch: a robot runs its network in numpy)."""
    import swarm.cli.run  # noqa: F401
    import swarm.procs.robot  # noqa: F401
    import swarm.procs.robot_status  # noqa: F401
    import swarm.procs.world  # noqa: F401


def _await_adoption(middle: int) -> None:
    """In a child: until the middle process that forked it is gone, so that it is the
    supervisor's child (by adoption) when its CLI checks whom it dies with."""
    while os.getppid() == middle:
        time.sleep(0.0002)


def _request(msg: bytes, fds: list[int]) -> tuple[list[str], dict[str, str]]:
    req = json.loads(msg)
    args = [str(a) for a in req["args"]]
    env = {str(k): str(v) for k, v in req["env"].items()}
    if len(fds) != 3:
        raise ValueError(f"three descriptors expected, got {len(fds)}")
    return args, env


def serve(fd: int, run_id: str) -> list[str] | None:
    """The server's loop; returns a forked child's argv (in that child), None at the end."""
    supervisor = os.getppid()
    prctl(PR_SET_PDEATHSIG, signal.SIGKILL)
    if os.getppid() != supervisor:  # (it died before prctl took effect)
        return None
    set_cmdline([sys.executable, "-m", MODULE, str(fd), run_id])
    sock = socket.socket(fileno=fd)
    _preload()
    while True:
        try:
            msg, fds, _, _ = socket.recv_fds(sock, _MAX_REQUEST, 3)
        except OSError:
            return None
        if not msg:  # (the supervisor's end closed)
            return None
        try:
            args, env = _request(msg, fds)
        except (ValueError, KeyError, TypeError, AttributeError) as exc:
            print(f"swarm fork server: bad request dropped: {exc}", file=sys.stderr, flush=True)
            for f in fds:
                os.close(f)
            sock.send(b"0")
            continue
        r, w = os.pipe()
        middle = os.fork()
        if middle == 0:  # forks the child, says its pid, goes: the child is then adopted
            child, me = -1, os.getpid()
            with contextlib.suppress(OSError):
                child = os.fork()
            if child == 0:
                os.close(r)
                os.close(w)
                sock.close()
                _await_adoption(me)
                for i, f in enumerate(fds):
                    os.dup2(f, i)
                    os.close(f)
                os.environ.clear()
                os.environ.update(env)
                set_cmdline(cli_args(*args))
                return args
            with contextlib.suppress(OSError):
                os.write(w, str(child).encode())
            os._exit(0)
        os.close(w)
        for f in fds:
            os.close(f)
        pid = b""
        with contextlib.suppress(OSError):
            pid = os.read(r, 32)
        os.close(r)
        os.waitpid(middle, 0)
        sock.send(pid if pid.isdigit() else b"0")


def _child_signals() -> None:
    """A fresh interpreter's signal handlers (the CLI takes them from there)."""
    signal.signal(signal.SIGINT, signal.default_int_handler)
    for sig in (signal.SIGTERM, signal.SIGHUP):
        signal.signal(sig, signal.SIG_DFL)


if __name__ == "__main__":
    argv = serve(int(sys.argv[1]), sys.argv[2])
    if argv is None:
        sys.exit(0)
    sys.argv = [sys.argv[0], *argv]
    _child_signals()
    from swarm.cli import run_as_child

    sys.exit(run_as_child(argv))
