"""Shared test setup: the repository root, the `swarm` CLI as a subprocess, the `procs` marker
(tests that spawn processes or open Zenoh sessions: `pytest -m "not procs"` is the fast inner
loop), one torch thread in-process."""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def swarm(*args: str, timeout: float = 180,
          env: dict[str, str] | None = None) -> subprocess.CompletedProcess[str]:
    """Run `python -m swarm.cli ARGS` from the repository root; output captured as text (`env`:
    variables added to this process's environment)."""
    return subprocess.run([sys.executable, "-m", "swarm.cli", *args], check=False, cwd=ROOT,
                          text=True, capture_output=True, timeout=timeout,
                          env={**os.environ, **env} if env else None)


def swarm_here(*args: str, capsys: pytest.CaptureFixture[str]
               ) -> subprocess.CompletedProcess[str]:
    """`swarm ARGS` in this process, from the repository root as `swarm` runs it, returned as
    `swarm` returns it: for commands that spawn nothing or only their own workers, and for
    refusals (no interpreter or torch start; the signal handlers and working directory are put
    back). The console entry itself is run as a subprocess by every `swarm` test."""
    import signal

    from swarm.cli import main

    capsys.readouterr()
    sigs = (signal.SIGTERM, signal.SIGINT, signal.SIGHUP)
    handlers, cwd = [signal.getsignal(s) for s in sigs], os.getcwd()
    os.chdir(ROOT)
    try:
        code = main(list(args))
    except SystemExit as exc:  # (argparse's usage errors)
        code = exc.code if isinstance(exc.code, int) else 1
    finally:
        os.chdir(cwd)
        for sig, handler in zip(sigs, handlers, strict=True):
            signal.signal(sig, handler)
    out, err = capsys.readouterr()
    return subprocess.CompletedProcess(["swarm", *args], code, out, err)


def swarm_started(*args: str) -> subprocess.Popen[str]:
    """Start `python -m swarm.cli ARGS` (a headless run) and return once its first tick's status
    line is out, the run on; the caller waits for it (or kills it)."""
    proc = subprocess.Popen([sys.executable, "-m", "swarm.cli", *args], cwd=ROOT,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    assert proc.stdout is not None
    for line in proc.stdout:
        if line.startswith('{"status"'):
            break
    return proc


def _compile_sources() -> None:
    """Byte-compile the packages once, before any test starts a process: where the environment
    sets PYTHONDONTWRITEBYTECODE (this machine's and CI's do), Python never writes a .pyc, so
    each of the ~1,150 processes the suite starts compiled our modules from source again, ~0.2
    CPU-s apiece (docs/DECISIONS.md, "The suite's time"). The .pyc files go where Python puts
    them itself (`__pycache__/`, git-ignored); an edited module is compiled afresh."""
    import compileall

    for pkg in ("swarm", "world", "policies"):
        compileall.compile_dir(ROOT / pkg, quiet=2)


def pytest_configure(config: pytest.Config) -> None:
    config.addinivalue_line("markers", "procs: spawns processes or opens Zenoh sessions (slow)")
    worker = os.environ.get("PYTEST_XDIST_WORKER")
    if not worker:  # (the controller, before its workers start; or the only process)
        _compile_sources()
    if worker:  # (pytest -n 2: each worker's runs note their hubs in a folder of their own)
        tmp = Path(tempfile.gettempdir()) / f"swarm-tests-{os.getpid()}-{worker}"
        tmp.mkdir(exist_ok=True)
        os.environ["TMPDIR"] = str(tmp)
        tempfile.tempdir = None


@pytest.fixture(autouse=True)
def _one_torch_thread():
    """In-process torch work uses one thread (the suite also runs many processes on 2 cores);
    a test module that never imports torch is left alone."""
    torch = sys.modules.get("torch")
    if torch is None:
        yield
        return
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


CYCLIC_PLUGIN = '''
import numpy as np

from policies.base import Policy, receiver_index
from policies.chain_plan import ChainPlan


class Cyclic(Policy):
    """A hand-written policy of another package: robot i takes action (tick + i) mod 9."""

    name = "cyclic"

    def act(self, view, greedy=True):
        g, i = receiver_index(view)
        out = np.zeros(view.receivers.shape, dtype=np.int64)
        out[g, i] = (view.tick + i) % 9
        return out
'''
"""The source of a third-party policy package's module (the README's "Building on it"
example): the tests that install a plugin add their buggy variants to it."""
