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

from swarm.common.forkserver import MODULE, prctl, set_cmdline
from swarm.common.spawn import PARENT_ENV, PR_SET_PDEATHSIG, cli_args

_MAX_REQUEST = 1 << 20


def _preload() -> None:
    """What the world and a robot import (not torch: a robot runs its network in numpy), and
    a supervised child's parser (a child built its own: ~480 flags, 0.05-0.3 CPU-s)."""
    import policies.belief  # noqa: F401
    import policies.grid_search  # noqa: F401
    import policies.infer.policy  # noqa: F401
    import swarm.cli
    import swarm.procs.robot  # noqa: F401
    import swarm.procs.robot_status  # noqa: F401
    import swarm.procs.world  # noqa: F401

    swarm.cli.prebuild_parser()


def _request(msg: bytes, fds: list[int]) -> tuple[list[str], dict[str, str]]:
    req = json.loads(msg)
    args = [str(a) for a in req["args"]]
    env = {str(k): str(v) for k, v in req["env"].items()}
    if len(fds) != 4:
        raise ValueError(f"four descriptors expected, got {len(fds)}")
    return args, env


def _fork(args: list[str], env: dict[str, str], fds: list[int], sock: socket.socket
          ) -> tuple[int, bool]:
    """(the child's pid or 0, False) here; (0, True) in the child, which runs once adopted and
    told to go. A middle process forks it and exits: the child is then the supervisor's (its
    subreaper's); the pid is sent once the middle is reaped, so adopted. The child waits on its
    go descriptor for the supervisor's byte, sent once it holds the pid: a child the supervisor
    gave up on (a reply that came too late) reads EOF and exits, never a second robot."""
    r, w = os.pipe()
    middle = os.fork()
    if middle == 0:  # (never back into the server's loop: a second server)
        try:
            child = os.fork()
        except BaseException:
            os._exit(1)
        if child:
            with contextlib.suppress(OSError):
                os.write(w, str(child).encode())
            os._exit(0)
        try:
            os.close(r)
            os.close(w)
            sock.close()
            if os.read(fds[3], 1) != b"g":
                os._exit(0)
            for i, f in enumerate(fds):
                if i < 3:
                    os.dup2(f, i)
                os.close(f)
            os.environ.clear()
            os.environ.update(env)
            set_cmdline(cli_args(*args))
        except BaseException:
            os._exit(1)
        return 0, True
    os.close(w)
    try:
        pid = os.read(r, 32)
    finally:
        os.close(r)
        os.waitpid(middle, 0)
    return int(pid) if pid.isdigit() else 0, False


def serve(fd: int, run_id: str) -> list[str] | None:
    """The server's loop; returns a forked child's argv (in that child), None at the end. A
    request that is not one, or a fork that fails, is answered 0 (the supervisor then spawns
    its children) and said in the server's log."""
    parent = os.environ.get(PARENT_ENV, "")
    supervisor = int(parent) if parent.isdigit() else os.getppid()
    prctl(PR_SET_PDEATHSIG, signal.SIGKILL)
    if os.getppid() != supervisor:  # (it died before prctl took effect)
        return None
    set_cmdline([sys.executable, "-m", MODULE, str(fd), run_id])
    sock = socket.socket(fileno=fd)
    _preload()
    while True:
        try:
            msg, fds, _, _ = socket.recv_fds(sock, _MAX_REQUEST, 4)
        except OSError:
            return None
        if not msg:  # (the supervisor's end closed)
            return None
        pid = 0
        try:
            args, env = _request(msg, fds)
            pid, child = _fork(args, env, fds, sock)
            if child:
                return args
        except Exception as exc:  # (a bad request, a fork refused: EAGAIN)
            print(f"swarm fork server: request dropped: {exc!r}", file=sys.stderr, flush=True)
        for f in fds:
            with contextlib.suppress(OSError):
                os.close(f)
        try:
            sock.send(str(pid).encode())
        except OSError:
            return None


if __name__ == "__main__":
    argv = serve(int(sys.argv[1]), sys.argv[2])
    if argv is None:
        sys.exit(0)
    sys.argv = [sys.argv[0], *argv]  # (its signal dispositions are the server's: a spawned
    from swarm.cli import run_as_child  # child's, SIGHUP ignored under nohup included)

    sys.exit(run_as_child(argv))
