"""How the supervisor starts its children and how they die with it.

Children are fresh interpreters (`python -m swarm.cli ...`: never fork, a forked Zenoh session
hangs). Each one gets the supervisor's pid in `SWARM_SUPERVISOR`; `die_with_parent()` (called by
the CLI before anything else) asks the kernel to send it SIGTERM when that process dies
(`prctl(PR_SET_PDEATHSIG)`), SIGKILL included, and turns SIGTERM into a KeyboardInterrupt so the
child closes its session and writes what it owes on the way out. A supervisor's registry entry
(`swarm fault --run ID` finds the run through it) is ignored and removed once its pid is gone;
a run id is taken atomically, for the run's life, by an exclusive lock beside it (`claim_run`).
"""

from __future__ import annotations

import atexit
import contextlib
import ctypes
import fcntl
import json
import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Iterable, Iterator
from pathlib import Path
from types import FrameType
from typing import Any

from world.config import ConfigError

PARENT_ENV = "SWARM_SUPERVISOR"
# `swarm run` and `swarm world`: fewer episodes completed than asked (a stop on the control key);
# `swarm robot`: it gave up on a world gone before the run's end (a supervisor's fleet does not
# count that as a crash: the world's `robots_lost` says which)
EXIT_INCOMPLETE = 3
PR_SET_PDEATHSIG = 1


def alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def child_env(**extra: str) -> dict[str, str]:
    """The environment of a child of this process: one BLAS thread, and this pid to die with."""
    return dict(os.environ, OMP_NUM_THREADS="1", MKL_NUM_THREADS="1",
                **{PARENT_ENV: str(os.getpid())}, **extra)


SHUTDOWN_GRACE_S = 8.0
"""How long a supervised child may take to unwind once told to go (SIGTERM, or its supervisor's
death): then SIGALRM's default action ends it, so a cleanup stuck on a dead peer (a blocking
put, a session close) never leaves a process of the run behind. What it wrote before is safe:
result files and checkpoints are written atomically."""


def _interrupt(signum: int, frame: FrameType | None) -> None:
    raise KeyboardInterrupt


def _interrupt_within_grace(signum: int, frame: FrameType | None) -> None:
    if signal.getitimer(signal.ITIMER_REAL)[0] == 0:  # the first SIGTERM starts the clock
        signal.signal(signal.SIGALRM, signal.SIG_DFL)
        signal.setitimer(signal.ITIMER_REAL, SHUTDOWN_GRACE_S)
    raise KeyboardInterrupt


def stop_signals() -> tuple[int, ...]:
    """The signals that stop a command as Ctrl-C does: SIGINT, SIGTERM, and SIGHUP (its
    terminal closed, its ssh dropped) unless SIGHUP came in ignored (`nohup`: left so)."""
    hup = () if signal.getsignal(signal.SIGHUP) is signal.SIG_IGN else (signal.SIGHUP,)
    return (signal.SIGINT, signal.SIGTERM, *hup)


def terminate_as_interrupt(grace: bool = False) -> None:
    """SIGTERM and SIGHUP unwind like Ctrl-C (sessions closed, final records written, network
    namespaces removed), not a hard stop: a closed terminal left a `--netns`/`--hosts` run's
    namespaces behind. With `grace`, the unwinding has SHUTDOWN_GRACE_S seconds."""
    try:
        for sig in stop_signals()[1:]:
            signal.signal(sig, _interrupt_within_grace if grace else _interrupt)
    except ValueError:  # not the main thread (main() called from a test's thread)
        pass


def supervised() -> bool:
    """Whether a supervisor (`swarm run`) started this process."""
    return os.environ.get(PARENT_ENV, "").isdigit()


def prctl(option: int, value: int) -> bool:
    """Linux's prctl(option, value); False where it failed or there is none."""
    try:
        return ctypes.CDLL(None, use_errno=True).prctl(option, value, 0, 0, 0) == 0
    except (OSError, AttributeError):
        return False


def die_with_parent() -> bool:
    """In a child started by a supervisor: SIGTERM when the supervisor dies, however it dies,
    and SHUTDOWN_GRACE_S to unwind. False (nothing done) in a process no supervisor started."""
    if not supervised():
        return False
    parent = os.environ[PARENT_ENV]
    terminate_as_interrupt(grace=True)
    if not prctl(PR_SET_PDEATHSIG, signal.SIGTERM):  # not Linux: the parent's cleanup still runs
        return True
    if os.getppid() != int(parent):  # it died before prctl took effect
        os.kill(os.getpid(), signal.SIGTERM)
    return True


def registry(run_id: str) -> Path:
    """Where a running supervisor notes its hub endpoint, for `swarm fault --run ID`."""
    return Path(tempfile.gettempdir()) / "swarm-runs" / f"{run_id}.json"


def lookup_run(run_id: str, wait: float = 0.0) -> str:
    """The hub endpoint of a run started on this machine by `swarm run`; an entry whose
    supervisor is gone (SIGKILLed: no chance to remove it) is stale, removed and ignored. With
    `wait` (seconds) a run not registered yet is waited for (`swarm record` started first)."""
    deadline = time.monotonic() + wait
    while True:
        try:
            return _registered(run_id)
        except ConfigError as exc:
            if time.monotonic() >= deadline:
                waited = f" (waited {wait:g} s)" if wait > 0 else ""
                raise ConfigError(f"{exc}{waited}") from None
        time.sleep(0.1)


def _registered(run_id: str) -> str:
    """`lookup_run` once: the hub in the registry entry, or a one-line ConfigError."""
    path = registry(run_id)
    try:
        rec = json.loads(path.read_text())
        hub, pid = str(rec["hub"]), int(rec["pid"])
    except (OSError, ValueError, KeyError, TypeError):
        raise ConfigError(f"no running swarm {run_id!r} on this machine; "
                          f"give --connect ENDPOINT") from None
    if not alive(pid):  # its entry and lock go, unless a new run of the id holds the lock
        with contextlib.suppress(ConfigError, OSError):  # (that run writes its own entry)
            check_run_free(run_id)
        raise ConfigError(f"swarm {run_id!r} is no longer running (its supervisor, pid {pid}, "
                          "is gone)")
    return hub


_CLAIMS: dict[str, int] = {}  # run id -> the fd of its lock: the ids this process holds


def claim_run(run_id: str) -> None:
    """Take `run_id` for this process (the supervisor, for its run's life), or a one-line
    ConfigError if a live process on this machine holds it, this one included: two runs of one
    id would each take `swarm fault --run ID` for the other's. Atomic (an exclusive flock on
    `swarm-runs/ID.lock`, beside the registry), so of two runs started in the same instant one
    is refused, where both passed a check of the registry the supervisor wrote later; the
    kernel drops the lock when its holder dies, SIGKILL included, so a dead holder's lock is
    never in the way, and its registry entry (written only by a holder) is removed here.
    `release_run` gives the id back, its lock file removed."""
    if run_id in _CLAIMS:
        raise _taken(run_id)
    path = _lock_file(run_id)
    path.parent.mkdir(parents=True, exist_ok=True)
    while True:
        fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(fd)
            raise _taken(run_id) from None
        try:  # the file we locked is still the one at `path` (its last holder unlinks it)
            same = os.stat(path).st_ino == os.fstat(fd).st_ino
        except FileNotFoundError:
            same = False
        if same:
            break
        os.close(fd)
    registry(run_id).unlink(missing_ok=True)
    os.ftruncate(fd, 0)
    os.write(fd, f"{os.getpid()}\n".encode())
    _CLAIMS[run_id] = fd
    if len(_CLAIMS) == 1:
        atexit.register(_release_all)


def _taken(run_id: str) -> ConfigError:
    return ConfigError(f"run id {run_id!r} is taken by a swarm running on this machine; give "
                       "another --run-id")


def release_run(run_id: str) -> None:
    """Give back a `claim_run` of this process (the lock file removed, then unlocked)."""
    fd = _CLAIMS.pop(run_id, None)
    if fd is not None:
        _lock_file(run_id).unlink(missing_ok=True)
        os.close(fd)


def _lock_file(run_id: str) -> Path:
    return registry(run_id).with_suffix(".lock")


def _release_all() -> None:
    for run_id in list(_CLAIMS):
        release_run(run_id)


def check_run_free(run_id: str) -> None:
    """`claim_run`'s refusal early, before a command's other checks (its supervisor then takes
    the id for good, and refuses it still if another run took it meanwhile); a free id's
    leftovers of a dead run (registry entry, lock file) are removed on the way."""
    claim_run(run_id)
    release_run(run_id)


def cli_args(*args: str) -> list[str]:
    return [sys.executable, "-m", "swarm.cli", *args]


def wait_port(host: str, port: int, proc: subprocess.Popen[bytes], timeout: float,
               name: str = "world") -> None:
    """Wait until `proc` (the hub: world or learner) accepts connections on host:port."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            raise RuntimeError(f"{name} process exited with code {proc.returncode} before "
                               "listening")
        with socket.socket() as s:
            s.settimeout(0.2)
            if s.connect_ex((host, port)) == 0:
                return
        time.sleep(0.05)
    raise TimeoutError(f"{name} did not listen on {host}:{port} within {timeout:g} s")


def last_error(log: Path, tail: int = 4096, since: int = 0) -> str:
    """The last exception line (`SomeError: message`) or one-line CLI error (`swarm: error:
    message`, given as the message) of a child's log after byte `since` (where this child
    began writing: a log is appended to by every process of that name), or "" if none."""
    try:
        with log.open("rb") as fh:
            fh.seek(max(fh.seek(0, os.SEEK_END) - tail, since, 0))
            lines = fh.read().decode("utf-8", "replace").splitlines()
    except OSError:
        return ""
    for line in reversed(lines):
        if line.startswith("swarm: error: "):  # swarm.cli.main's one line (a bad config, a path)
            return line[len("swarm: error: "):].strip()
        head = line.split(":", 1)[0]
        if line and not line[0].isspace() and head.endswith(("Error", "Exception")):
            return line.strip()
    return ""


def child_result(path: Path, run_id: str) -> dict | None:
    """The result a child wrote to `path` (its `--json`, written atomically before it exits)
    if it is a result of run `run_id`, else None: the fallback when its result message was lost
    on the way (a session closed under heavy packet loss)."""
    try:
        rec = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    return rec if isinstance(rec, dict) and rec.get("run_id") == run_id else None


TROUBLE = ("child_errors", "robot_crashes", "robots_lost", "timeouts", "robot_restarts",
           "result_message_lost")
"""Result keys whose non-zero value means a run's logs are worth keeping."""


def tidy_logs(folder: Path, res: dict[str, Any], keep: bool = False) -> None:
    """Remove a run's temp folder (its children's logs, its spec, a secure run's session configs:
    nothing reads them once its processes are gone) after a clean run; it stays, named in the
    result (`logs`), when anything went wrong (`TROUBLE`) or with `keep` (a learner writes into
    it, the recorder failed: its log says why)."""
    if keep or any(res.get(k) for k in TROUBLE):
        res["logs"] = str(folder)
        return
    shutil.rmtree(folder, ignore_errors=True)


_TRACEBACK_HEAD = ("Traceback (most recent call last):", "Fatal Python error: init_",
                   "Python runtime state: ", "Could not import runpy module",
                   "Could not access runpy._run_module_as_main", "Exception ignored in: ")
"""What heads a traceback in a child's log (the others: the interpreter stopped while it
still started, in `site`, its standard streams or `-m`'s runpy, before any line of ours, or
an exception it could only print, in `threading`'s shutdown say)."""

_DUMP = re.compile(r"object (address|refcount|type|type name|repr) *: (.*)|lost sys\.stderr")
"""CPython's dump of an exception it could not print (its stderr gone while it stopped); its
first line may be glued to the traceback's last."""


_CHAINED = ("During handling of the above exception, another exception occurred:",
            "The above exception was the direct cause of the following exception:")


def says_more_than_interrupted(lines: Iterable[str]) -> bool:
    """Whether a child's log says more than that it was interrupted: its one line `swarm:
    interrupted`, or the traceback of a KeyboardInterrupt (a child stopped while it still
    loaded its modules, before its CLI could take the signal; in a chain, the last exception
    is the one that ended it) are not more; anything else is, another exception included."""
    block, last = False, None  # in a traceback's frames; the exception line that ended one
    for line in (x.rstrip() for x in lines):
        if (dump := _DUMP.search(line)) is not None:  # (ends a traceback cut short by it)
            block, last = False, dump[2] if dump[1] == "type name" else last
            continue
        line = "KeyboardInterrupt" if line == "KeyboardInterrupt:" else line  # (no message)
        if line.startswith(_TRACEBACK_HEAD) or block and (not line or line[0].isspace()):
            block = True
        elif block:
            block, last = False, line
        elif line in _CHAINED and last is not None:  # (the next traceback's is the last one)
            last = None
        elif line:
            if last not in (None, "KeyboardInterrupt") or \
                    line not in ("swarm: interrupted", "KeyboardInterrupt"):
                return True
            last = None
    return block or last not in (None, "KeyboardInterrupt")  # (cut short: read as more)


def tidy_interrupted(folder: Path, keep: bool = False) -> None:
    """An interrupted run's temp folder: removed when no log in it says more than that it was
    interrupted, else kept and named on stderr (no result names it)."""
    def says(log: Path) -> bool:
        with log.open(errors="replace") as fh:
            return says_more_than_interrupted(fh)

    if folder.is_dir() and (keep or any(says(p) for p in folder.rglob("*.log") if p.is_file())):
        print(f"swarm: the run's logs are in {folder}", file=sys.stderr)
    else:
        shutil.rmtree(folder, ignore_errors=True)


@contextlib.contextmanager
def stops_held() -> Iterator[None]:
    """The stop signals held while the block runs, then raised as KeyboardInterrupt: a stop
    that lands between a child's fork and its Popen's return loses that child (never told to
    stop, it ran on and failed to join a run that was gone). A no-op off the main thread."""
    held: list[int] = []
    stops = stop_signals()
    if threading.current_thread() is not threading.main_thread() or \
            any(signal.getsignal(s) is None for s in stops):  # (not ours to put back)
        yield
        return
    before = {s: signal.signal(s, lambda n, f: held.append(n)) for s in stops}
    try:
        yield
    finally:
        for s, h in before.items():
            signal.signal(s, h)
    if held:
        raise KeyboardInterrupt


def start_child(args: list[str], **popen: Any) -> subprocess.Popen[bytes]:
    """`subprocess.Popen(args, **popen)` for a `swarm.cli` child, started with the stop signals
    blocked (a signal mask is inherited across fork and exec); its CLI unblocks them once its
    handlers are in place (`unblock_stops`), and one sent meanwhile is delivered then. A child
    stopped while its interpreter still loaded its modules wrote a traceback of wherever the
    KeyboardInterrupt landed (in `site`, in a `.pth` file, once chained into a RuntimeError),
    which read as a failure and kept the run's logs."""
    stops = [signal.SIGINT, signal.SIGTERM, signal.SIGHUP]
    before = signal.pthread_sigmask(signal.SIG_BLOCK, stops)
    try:
        return subprocess.Popen(args, **popen)
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, before)


def unblock_stops() -> None:
    """The stop signals let through (a child of `start_child` starts with them blocked); one
    that came meanwhile is delivered now."""
    signal.pthread_sigmask(signal.SIG_UNBLOCK, [signal.SIGINT, signal.SIGTERM, signal.SIGHUP])


def _reap(p: subprocess.Popen[Any], block: bool) -> bool:
    """Whether child `p` has exited, reaping it with os.waitpid (not Popen's own wait/poll:
    a KeyboardInterrupt landing inside Popen.poll between its lock's acquire and `try` leaves
    that lock held, and every later Popen.wait then blocks forever; seen in a test run)."""
    if p.returncode is not None:
        return True
    try:
        pid, status = os.waitpid(p.pid, 0 if block else os.WNOHANG)
    except ChildProcessError:  # reaped elsewhere: its status is gone (Popen says 0 here too)
        p.returncode = 0
        return True
    if pid != p.pid:
        return False
    p.returncode = os.waitstatus_to_exitcode(status)
    return True


def stop_children(procs: list[subprocess.Popen[Any]], grace: float = 2.0) -> None:
    """SIGINT every child still running, give them `grace` seconds together, then SIGKILL the
    rest; every one reaped on return. A Ctrl-C meanwhile is held and raised as
    KeyboardInterrupt once they are all down (so no child outlives an interrupted stop)."""
    held: list[int] = []
    before = signal.getsignal(signal.SIGINT)
    hold = threading.current_thread() is threading.main_thread() and before is not None
    if hold:
        signal.signal(signal.SIGINT, lambda s, f: held.append(s))
    try:
        for p in procs:
            if not _reap(p, block=False):
                try:
                    p.send_signal(signal.SIGINT)
                except ProcessLookupError:
                    pass
        deadline = time.monotonic() + grace
        waiting = [p for p in procs if not _reap(p, block=False)]
        while waiting and time.monotonic() < deadline:
            time.sleep(0.01)
            waiting = [p for p in waiting if not _reap(p, block=False)]
        for p in waiting:
            try:
                p.kill()
            except ProcessLookupError:
                pass
            _reap(p, block=True)
    finally:
        if hold:
            signal.signal(signal.SIGINT, before)
    if held:
        raise KeyboardInterrupt
