"""A run's fork server: one interpreter that loads a robot's modules once and forks every robot
of the run from itself, so a robot starts in milliseconds instead of ~0.4 CPU-s of interpreter
start and imports (numpy, zenoh, the CLI) each: 40 CPU-s for a team of 100, most of a short
run's CPU (docs/DECISIONS.md, "Robots forked from a fork server").

A forked robot is what a spawned one is, to everyone who looks: a child of the supervisor (the
server forks twice and the supervisor is the children's subreaper, so it waits for them, sees
their exit codes and signals them as before, through an ordinary `subprocess.Popen`), with its
own environment, standard streams and signal state, and its command line in /proc (written over
the server's argv, which the supervisor pads for it). The server never opens a Zenoh session nor
starts a thread (a fork copies only the calling thread); it ends when its socket closes, or with
its supervisor. Where it cannot serve (it died, a command line too long for its pad) the robot
is spawned as its own interpreter, as without it.
"""

from __future__ import annotations

import ctypes
import json
import os
import socket
import subprocess
import sys
import threading
from pathlib import Path
from typing import Any, BinaryIO

from swarm.common.spawn import cli_args, start_child

PAD = 8192
"""Bytes of argv the server starts with: the room for its children's command lines."""
_PR_SET_CHILD_SUBREAPER = 36
MODULE = "swarm.cli.forkserver"
"""The server itself (it runs the CLI: it belongs to `swarm.cli`)."""
FORKED = ("world", "robot")
"""The commands it forks (what it loads); the others, the learner's torch say, are spawned."""
ENV = "SWARM_FORKSERVER"
"""`SWARM_FORKSERVER=0` in the supervisor's environment: every robot its own interpreter."""


def wanted() -> bool:
    return os.environ.get(ENV, "1") != "0" and sys.platform == "linux"


def prctl(option: int, value: int) -> bool:
    try:
        return ctypes.CDLL(None, use_errno=True).prctl(option, value, 0, 0, 0) == 0
    except (OSError, AttributeError):
        return False


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
        with log.open("ab") as err:  # (one BLAS thread whatever the user's: a fork copies one)
            self.proc: subprocess.Popen[bytes] = start_child(
                [sys.executable, "-m", MODULE, str(theirs.fileno()), run_id, "-" * PAD],
                env={**env, **one}, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=err,
                pass_fds=[theirs.fileno()])
        theirs.close()
        self.sock: socket.socket | None = ours
        self.log = log

    def spawn(self, args: list[str], env: dict[str, str], stderr: int,
              timeout: float = 10.0) -> subprocess.Popen[bytes] | None:
        """The `swarm.cli` child of `args` (`swarm world` or `swarm robot`), forked; None
        for another command, or if the server cannot (then never again: it is killed, and a
        child it forks too late is never told to go): the caller spawns it."""
        if self.sock is None or args[0] not in FORKED or not fits(args):
            return None
        null = os.open(os.devnull, os.O_RDWR)
        go, said = os.pipe()  # (the child runs once we hold its pid: `said` gets a byte)
        try:
            req = json.dumps({"args": args, "env": env}).encode()
            self.sock.settimeout(timeout)
            socket.send_fds(self.sock, [req], [null, null, stderr, go])
            reply = self.sock.recv(64)
            pid = int(reply) if reply.isdigit() else 0
            if pid > 0:
                os.write(said, b"g")
        except (OSError, ValueError):
            pid = 0
        finally:
            for f in (null, go, said):
                os.close(f)
        if pid <= 0:
            self.close()
            self.proc.kill()  # (reaped with the run's other children)
            return None
        return Forked(pid, cli_args(*args))

    def close(self) -> None:
        """The server ends (its socket's end); the children it forked run on, adopted (and the
        process that asked is no one's subreaper from here: it may run more runs)."""
        if self.sock is not None:
            self.sock.close()
            self.sock = None
            prctl(_PR_SET_CHILD_SUBREAPER, 0)


def child(forks: ForkServer | None, prefix: list[str], args: list[str], env: dict[str, str],
          stderr: BinaryIO) -> subprocess.Popen[bytes]:
    """The `swarm.cli` child of `args`: forked by `forks` where it can, else spawned (after
    `prefix`: `ip netns exec NS`), stdin and stdout /dev/null, stderr to `stderr`."""
    forked = forks.spawn(args, env, stderr.fileno()) if forks is not None else None
    return forked or start_child([*prefix, *cli_args(*args)], env=env, stderr=stderr,
                                 stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL)


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
