"""A run's fork server: one interpreter that loads what the world and a robot import once and
forks the world and every robot of the run from itself, so each starts in milliseconds instead
of ~0.4 CPU-s of interpreter start and imports (numpy, zenoh, the CLI and its parser): 80 CPU-s
for a team of 200, most of a short run's CPU (docs/DECISIONS.md, "Robots forked from a fork
server"). The supervisor's end (`ForkServer`, `child`) and the server's loop (`serve`, run by
`python -m swarm.cli --fork-server`, which preloads the CLI's modules: `swarm.cli.preload_child`).

A forked child is what a spawned one is, to everyone who looks: a child of the supervisor (the
server forks twice and the supervisor is the children's subreaper, so it waits for them, sees
their exit codes and signals them as before, through an ordinary `subprocess.Popen`), with its
own environment, standard streams and the signal state a spawned child has, and its command
line in /proc (written over the server's argv, which the supervisor pads for it). The server
never opens a Zenoh session nor starts a thread (a fork copies only the calling thread); it ends
when its socket closes, or with its supervisor. Where it cannot serve (another command, a
namespace, a command line too long for its pad, a server that failed) the child is spawned as
its own interpreter, as without it.
"""

from __future__ import annotations

import contextlib
import ctypes
import gc
import json
import os
import signal
import socket
import subprocess
import sys
import threading
from collections.abc import Callable
from pathlib import Path
from typing import Any, BinaryIO

from swarm.common.spawn import (
    PARENT_ENV,
    PR_SET_PDEATHSIG,
    cli_args,
    prctl,
    start_child,
    stops_held,
)

PAD = 8192
"""Bytes of argv the server starts with: the room for its children's command lines."""
_PR_SET_CHILD_SUBREAPER = 36
_MAX_REQUEST = 1 << 20
SERVE = "--fork-server"
"""`python -m swarm.cli --fork-server FD RUN_ID PAD`: the server (`swarm/cli/__main__.py`)."""
FORKED = ("world", "robot")
"""The commands it forks (what it loads); the others, the learner's torch say, are spawned."""
ENV = "SWARM_FORKSERVER"
"""`SWARM_FORKSERVER=0` in the supervisor's environment: every robot its own interpreter."""


def wanted() -> bool:
    return os.environ.get(ENV, "1") != "0" and sys.platform == "linux"


def _argv_area() -> tuple[int, int]:
    """This process's argv strings in memory (/proc/self/stat's arg_start, arg_end)."""
    fields = Path("/proc/self/stat").read_text().rsplit(")", 1)[1].split()
    return int(fields[45]), int(fields[46])  # (fields 48, 49; the rest starts at field 3)


def set_cmdline(argv: list[str]) -> bool:
    """Write `argv` over this process's argv area, NUL-padded (so /proc/PID/cmdline, ps and
    pgrep show it as a command line; the last byte stays NUL: the kernel then reads the whole
    area as argv). False if it does not fit (nothing written)."""
    start, end = _argv_area()
    data = b"\0".join(a.encode() for a in argv) + b"\0"
    if len(data) > end - start:
        return False
    ctypes.memmove(start, data.ljust(end - start, b"\0"), end - start)
    return True


def fits(args: list[str]) -> bool:
    return len(b"\0".join(a.encode() for a in cli_args(*args))) + 1 <= PAD


class Forked(subprocess.Popen):  # type: ignore[type-arg]
    """A `Popen` of a process the fork server made (the supervisor's child by adoption): poll,
    wait, send_signal and kill as for any child; no pipes."""

    def __init__(self, pid: int, args: list[str]) -> None:  # (no super().__init__: no fork)
        self.args, self.pid, self.returncode = args, pid, None
        self.stdin = self.stdout = self.stderr = None
        self.text_mode = self.universal_newlines = False
        self.encoding = self.errors = None
        self.pipesize, self._input, self._communication_started = -1, None, False
        self._waitpid_lock = threading.Lock()
        self._sigint_wait_secs = 0.25
        self._closed_child_pipe_fds = True
        self._child_created = True
        self._fileobj2output: dict[Any, Any] = {}


class ForkServer:
    """The supervisor's end: started before the world, so its imports overlap the world's."""

    def __init__(self, env: dict[str, str], log: Path, run_id: str) -> None:
        """Started as any child (`start_child`: its stop signals blocked; the server keeps them
        so, and its children start so, as spawned ones do, till their CLI takes them)."""
        if not prctl(_PR_SET_CHILD_SUBREAPER, 1):
            raise OSError("cannot become a child subreaper")
        ours, theirs = socket.socketpair(socket.AF_UNIX, socket.SOCK_SEQPACKET)
        one = {k: "1" for k in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")}
        try:
            with log.open("ab") as err:  # (one BLAS thread whatever the user's: a fork copies one)
                self.proc: subprocess.Popen[bytes] = start_child(
                    cli_args(SERVE, str(theirs.fileno()), run_id, "-" * PAD),
                    env={**env, **one}, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                    stderr=err, pass_fds=[theirs.fileno()])
        except BaseException:
            ours.close()
            prctl(_PR_SET_CHILD_SUBREAPER, 0)
            raise
        finally:
            theirs.close()
        self.sock: socket.socket | None = ours
        self.log = log

    def spawn(self, args: list[str], env: dict[str, str], stderr: int,
              children: list[subprocess.Popen[bytes]], timeout: float = 30.0) -> bool:
        """Whether the `swarm.cli` child of `args` (`swarm world` or `swarm robot`) was forked
        and appended to `children`; False for another command, or if the server cannot (then
        never again: it is killed): the caller spawns it. A stop while the server answers (its
        first answer waits for its imports) is raised at once: a child forked meanwhile is never
        told to go (it exits), and from the pid on to its place in `children` stops are held."""
        if self.sock is None or args[0] not in FORKED or not fits(args):
            return False
        null = os.open(os.devnull, os.O_RDWR)
        go, said = os.pipe()  # (the child runs once we hold its pid: `said` gets a byte)
        pid = 0
        try:
            req = json.dumps({"args": args, "env": env}).encode()
            self.sock.settimeout(timeout)
            socket.send_fds(self.sock, [req], [null, null, stderr, go])
            reply = self.sock.recv(64)
            with stops_held():
                if reply.isdigit() and int(reply) > 0:
                    os.write(said, b"g")
                    pid = int(reply)
                    children.append(Forked(pid, cli_args(*args)))
        except (OSError, ValueError):
            pass
        finally:  # (no pid, or a stop before it came: the socket is out of step, never again)
            for f in (null, go, said):
                os.close(f)
            if pid <= 0:
                self.close()
                self.proc.kill()  # (reaped with the run's other children)
        return pid > 0

    def close(self) -> None:
        """The server ends (its socket's end); the children it forked run on, adopted (and the
        process that asked is no one's subreaper from here: it may run more runs)."""
        if self.sock is not None:
            self.sock.close()
            self.sock = None
            prctl(_PR_SET_CHILD_SUBREAPER, 0)


def child(forks: ForkServer | None, prefix: list[str], args: list[str], env: dict[str, str],
          stderr: BinaryIO, children: list[subprocess.Popen[bytes]]) -> subprocess.Popen[bytes]:
    """The `swarm.cli` child of `args`, appended to `children` (every child ever started is
    there, so stopped at the end: stops are held from its fork to there): forked by `forks`
    where it can, else spawned (after `prefix`: `ip netns exec NS`); stdin and stdout
    /dev/null, stderr to `stderr`."""
    if forks is None or not forks.spawn(args, env, stderr.fileno(), children):
        with stops_held():
            children.append(start_child([*prefix, *cli_args(*args)], env=env, stderr=stderr,
                                        stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL))
    return children[-1]


def start(env: dict[str, str], log_dir: Path, run_id: str,
          children: list[subprocess.Popen[bytes]]) -> ForkServer | None:
    """A run's fork server (log: `forkserver.log`), its process appended to `children` (the
    caller's, stopped at its end), or None where there is none (not Linux, `SWARM_FORKSERVER=0`,
    no subreaper)."""
    if not wanted():
        return None
    try:
        server = ForkServer(env, log_dir / "forkserver.log", run_id)
        children.append(server.proc)
        return server
    except OSError as exc:
        print(f"swarm: warning: no fork server ({exc}); every robot its own interpreter",
              file=sys.stderr, flush=True)
        return None


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


def serve(fd: int, run_id: str, preload: Callable[[], None]) -> list[str] | None:
    """The server's loop, once `preload` has loaded what its children import; returns a forked
    child's argv (in that child), None at the end. A request that is not one, or a fork that
    fails, is answered 0 (the supervisor then spawns its children) and said in the server's
    log."""
    parent = os.environ.get(PARENT_ENV, "")
    supervisor = int(parent) if parent.isdigit() else os.getppid()
    prctl(PR_SET_PDEATHSIG, signal.SIGKILL)
    if os.getppid() != supervisor:  # (it died before prctl took effect)
        return None
    set_cmdline(cli_args(SERVE, str(fd), run_id))
    try:
        sock = socket.socket(fileno=fd)
    except OSError as exc:  # (started by hand with a descriptor that is not its socket)
        print(f"swarm: error: --fork-server {fd}: not a socket ({exc.strerror})", file=sys.stderr)
        raise SystemExit(2) from None
    preload()
    gc.collect()
    gc.freeze()  # (what it loaded: never traversed by a child's collections, nor copied by them)
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
