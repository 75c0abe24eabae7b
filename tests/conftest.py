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


def pytest_configure(config: pytest.Config) -> None:
    config.addinivalue_line("markers", "procs: spawns processes or opens Zenoh sessions (slow)")
    worker = os.environ.get("PYTEST_XDIST_WORKER")
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
