"""What `swarm run --train`'s supervisor does with its learner process once the world has its
result: let it take in the run's last episodes, stop it first (`drain`), account for every
episode played in the run's result (`learner_result`) and say where its weights went
(`trained_line`)."""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

LEARNER_COUNTERS = ("trained", "pending", "stale_dropped", "incomplete", "rejected", "lost")


def drain(proc: subprocess.Popen[bytes], status: Callable[[], dict[str, Any] | None],
          pump: Callable[[float], None], done: int, batch: int, grace: float = 30.0) -> None:
    """After the last episode: let the learner `proc` take in every one of the `done` episodes
    of the run (`status`: its last status; `pump` takes in the supervisor's records for some
    seconds), then stop it first (its final status still routes through the world) and keep
    that status; a partial batch is never trained on (its episodes stay pending, counted)."""
    deadline = time.monotonic() + grace
    while time.monotonic() < deadline and proc.poll() is None:
        st = status() or {}
        acc = st.get("accounting") or {}
        joining = acc.get("pending", 0) - st.get("ready", 0)
        if acc.get("received", 0) >= done and joining == 0 and st.get("ready", 0) < batch:
            break
        pump(0.1)
    if proc.poll() is None:
        proc.send_signal(signal.SIGINT)
        deadline = time.monotonic() + 5.0
        while proc.poll() is None and time.monotonic() < deadline:
            pump(0.1)
    pump(0.3)  # its final status


def learner_result(status: dict[str, Any] | None, played: int, out: str | None,
                   warn: bool = False) -> dict[str, Any]:
    """The result's `learner`: its last status, with every episode `played` ending in exactly
    one of its counters (`unaccounted`: 0 when it heard every episode), and its folder. `warn`:
    episodes it never heard (say, stopped past its lease) are also a warning line."""
    st = status or {}
    acc = dict(st.get("accounting") or {})
    acc["played"] = played
    acc["unaccounted"] = played - sum(acc.get(k, 0) for k in LEARNER_COUNTERS)
    if warn and acc["unaccounted"] > 0:
        print(f"swarm: warning: {acc['unaccounted']} of the {played} episodes played reached no "
              "learner counter (unaccounted: the learner never heard them, or its last status "
              "did not come)", file=sys.stderr, flush=True)
    return {**st, "accounting": acc, "out": out}


def learner_left(out: str | None) -> dict[str, Any] | None:
    """What a learner that did not end with its run left: its last checkpoint (the weights of
    its last update, written atomically at every update), read from the file, as the line
    that says so and the result's `checkpoint`; None when it left none."""
    from policies.checkpoint import load_checkpoint

    ckpt = Path(str(out)) / "checkpoint.pt"
    if out is None or not ckpt.is_file():
        return None
    try:
        state = load_checkpoint(ckpt).get("learner") or {}
        version, trained = int(state["version"]), int(state["counters"]["trained"])
    except Exception as exc:  # (a file it did not finish is never renamed into place)
        return {"line": f"the learner's checkpoint {ckpt} cannot be read: {exc}",
                "checkpoint": {"path": str(ckpt)}}
    return {"line": f"the learner's last checkpoint: {ckpt} (version {version}, {trained} "
                    "episodes trained)",
            "checkpoint": {"path": str(ckpt), "version": version, "trained": trained}}


def trained_line(learner: dict[str, Any], batch: int) -> str:
    """The one line `swarm run --train` ends with: where the trained checkpoint is (without
    --learner-out, in the run's kept temp folder), or that no update made one."""
    out = Path(str(learner.get("out")))
    if (out / "checkpoint.pt").is_file():
        return f"swarm: trained weights (version {learner.get('version', 0)}): " \
            f"{out / 'checkpoint.pt'}"
    acc = learner.get("accounting") or {}
    fates = ", ".join(f"{acc[k]} {k.replace('_', ' ')}" for k in LEARNER_COUNTERS
                      if k != "trained" and acc.get(k))
    return f"swarm: the learner made no update (a batch is {batch} usable episodes; it " \
        f"received {acc.get('received', 0)}{': ' + fates if fates else ''}): no checkpoint " \
        f"in {out}"
