"""The robot processes of a `swarm run`, as its supervisor keeps them: spawned, faulted on purpose
(crash = SIGKILL, hang = SIGSTOP, restart = SIGCONT a hung robot or respawn a dead one), and
watched for deaths nobody planned. Every death is counted once (`crashes`), and one that was not
planned is also said (`errors`: the last error line of its log, or how it ended). And the end of
the run's recorder, as the supervisor waits for it (`finish_recorder`, `recording_result`)."""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from swarm.common.procstat import stopped
from swarm.common.spawn import EXIT_INCOMPLETE, last_error
from swarm.net.faults import ProcessFault
from swarm.net.faults.control import MAX_PENDING
from swarm.procs.dashboard import SwarmView

Proc = subprocess.Popen[bytes]


def how_it_ended(code: int) -> str:
    """'killed by SIGKILL' for -9, 'exit code 3' for 3."""
    if code < 0:
        try:
            return f"killed by {signal.Signals(-code).name}"
        except ValueError:
            return f"killed by signal {-code}"
    return f"exit code {code}"


def finish_recorder(proc: Proc | None, timeout: float = 60.0) -> None:
    """A supervised recorder ends by itself at the world's `end` record; give it the time to
    write the result and the footer (stopping it would SIGINT it: it still writes the footer)."""
    if proc is None:
        return
    try:
        proc.wait(timeout=timeout)
    except subprocess.TimeoutExpired:
        print(f"swarm: warning: the recorder did not finish within {timeout:g} s; stopping it",
              file=sys.stderr, flush=True)


def recording_result(path: str | None, code: int, log_dir: Path) -> dict[str, Any]:
    """A run's `recording`; a recorder that failed (killed, an error) left its file cut at its
    last flushed chunk: `partial`, and a warning line (`swarm run` exits 1)."""
    if code == 130:  # stopped (SIGINT: it did not finish in time): its footer is written
        print(f"swarm: warning: the recorder was stopped before the run's end: {path} is "
              "partial, whole up to where it stopped (`swarm replay` reads it; logs in "
              f"{log_dir})", file=sys.stderr, flush=True)
    elif code != 0:
        why = last_error(log_dir / "recorder.log") or how_it_ended(code)
        print(f"swarm: warning: the recorder failed ({why}): {path} is partial, cut at its last "
              "flushed chunk (`swarm replay --partial` reads it; logs in "
              f"{log_dir})", file=sys.stderr, flush=True)
    return {"path": path, "exit": code, "partial": code != 0}


class Fleet:
    """Robot id -> its running process, with the counts the run's result reports."""

    def __init__(self, spawn: Callable[[int], Proc], log_dir: Path, restart_crashed: bool) -> None:
        self.spawn, self.log_dir, self.restart_crashed = spawn, log_dir, restart_crashed
        self.procs: dict[int, Proc] = {}
        self.crashes, self.restarts = 0, 0
        self.hung: set[int] = set()
        self.held: set[int] = set()  # hung by a fault and not resumed by a restart (to the end)
        self.hangs: set[int] = set()  # robots hung on purpose at some point
        self.killed: set[Proc] = set()  # processes a planned crash killed (counted there)
        self.crashed: set[int] = set()  # robots a crash fault killed (planned, or a live one's)
        self.seen: set[Proc] = set()  # processes whose end was accounted for (not pids: reused)
        self.log_from: dict[int, int] = {}  # robot -> where its current process's log begins
        self.errors: dict[str, str] = {}  # "robot i" -> why it died (not planned)
        self.left: set[int] = set()  # robots that left, their world gone (EXIT_INCOMPLETE)
        self._deserted: float | None = None  # since when no robot is left (`deserted`)
        self.log: list[str] = []  # the process faults done, or found nothing to act on
        self.stopped_at_end: set[int] = set()  # robots found stopped by nobody's plan (`halt`)

    def start(self, i: int) -> None:
        log = self.log_dir / f"robot{i}.log"
        self.log_from[i] = log.stat().st_size if log.exists() else 0  # (it appends there)
        self.procs[i] = self.spawn(i)

    def up(self, i: int) -> bool:
        p = self.procs.get(i)
        return p is not None and p.poll() is None

    def fault(self, f: ProcessFault, run_tick: int) -> str:
        """Do `f` and log it (at the plan's tick, or a live one's: `run_tick`); the log line."""
        self._reaped(f.robot)  # (a death nobody planned, before a restart replaces it unseen)
        p, up = self.procs.get(f.robot), self.up(f.robot)
        note = ""  # a fault with nothing to act on is logged as such, never as done
        if f.kind == "crash" and p is not None and up:
            p.kill()
            p.wait()  # (a SIGKILL is quick; a hang or restart of the same tick sees it down)
            self.hung.discard(f.robot)
            self.held.discard(f.robot)  # (down now as a crash's)
            self.crashes += 1  # (here: a restart of the same tick replaces it before a check)
            self.killed.add(p)
            self.crashed.add(f.robot)
        elif f.kind == "hang" and p is not None and up and f.robot not in self.hung:
            p.send_signal(signal.SIGSTOP)
            self.hung.add(f.robot)
            self.hangs.add(f.robot)
            self.held.add(f.robot)
        elif f.kind == "restart" and p is not None and up and f.robot in self.hung:
            p.send_signal(signal.SIGCONT)
            self.hung.discard(f.robot)
            self.held.discard(f.robot)
            self.restarts += 1  # resumed: it rejoins the run (counted by the robot too)
        elif f.kind == "restart" and not up:
            self.restarts += 1
            self.start(f.robot)
        else:
            note = " (not down: nothing done)" if f.kind == "restart" else \
                f" ({'hung' if up and f.robot in self.hung else 'down'} already: nothing done)"
        self.log.append(f"{f.kind} {f.robot}@{f.tick if f.tick >= 0 else run_tick}{note}")
        return self.log[-1]

    def halted(self) -> list[Proc]:
        """The run is over: robots stopped (SIGSTOP) that no planned hang stopped are noted
        (`stopped_at_end`: the stall detection of a robot that rejoins never ran in them); the
        processes to resume, planned hangs too, so that they take the stop."""
        found = {i for i, p in self.procs.items() if p.poll() is None and stopped(p.pid)}
        self.stopped_at_end |= found - self.hung
        return [self.procs[i] for i in sorted(found | self.hung) if self.up(i)]

    def check(self) -> None:
        """Robots that died: a death nobody planned is counted and its reason kept; each dead
        robot is respawned with --restart-crashed, else forgotten."""
        for i in list(self.procs):
            if self._reaped(i):
                if self.restart_crashed:
                    self.restarts += 1
                    self.start(i)
                else:
                    del self.procs[i]

    def deserted(self, playing: bool, grace: float = 5.0) -> str | None:
        """Every robot has left by itself (the world's token was gone for it: the world stopped
        past its lease, say) while the world plays on (`playing`): episodes nobody plays would
        be averaged into the result. The line that ends the run, once that has lasted `grace`
        s (a world's own end can reach us after its robots', on a loaded machine); at the
        run's end (grace 0) the same line fails a run whose world finished first."""
        if self.procs or not self.left or not playing:
            self._deserted = None
            return None
        self._deserted = self._deserted or time.monotonic()
        if time.monotonic() - self._deserted < grace:
            return None
        return (f"every robot left the run before its end (robots {sorted(self.left)}: the "
                "world's token was gone for them; was the world stopped past its Zenoh lease?): "
                "no robot played the rest of its episodes")

    def _reaped(self, i: int) -> bool:
        """Whether robot i's process has ended; the first time it is seen ended, a death
        nobody planned (a non-zero exit) is counted and said (`errors`). It stays in `procs`
        (the caller replaces or forgets it)."""
        p = self.procs.get(i)
        if p is None or p.poll() is None:
            return False
        self.hung.discard(i)
        if p in self.seen:
            return True
        self.seen.add(p)
        if p in self.killed:
            self.killed.discard(p)
        elif p.returncode == EXIT_INCOMPLETE:  # it left on its own: its world was gone (the
            self.left.add(i)  # world's `robots_lost` says which); 0: the run's end, after it
        elif p.returncode != 0:
            self.crashes += 1
            self.errors[f"robot {i}"] = last_error(
                self.log_dir / f"robot{i}.log", since=self.log_from.get(i, 0)) or \
                how_it_ended(p.returncode)
        return True

    def account(self, res: dict[str, Any], view: SwarmView, planned: list[ProcessFault],
                start_timeout: float) -> None:
        """The robots' part of a run's result (`res`), and a warning line on stderr for each
        thing that went wrong with them that nobody planned (the run went on: said, not only
        in the JSON)."""
        errors = self.errors
        res["robot_crashes"], res["robot_restarts"] = self.crashes, self.restarts
        res.update({"child_errors": dict(errors)} if errors else {})
        said = [*(f"{w} failed: {why}" for w, why in errors.items()), *view.undecided(),
                *view.stalled(self.hangs)]
        said += [f"robot {i} was stopped (SIGSTOP) and not resumed by the run's end: out of the "
                 "run from then on (counted in robot_stalls)" for i in sorted(self.stopped_at_end)]
        res["robot_status"] = {str(i): r.counters() for i, r in view.robots.items()}
        res["robot_stalls"] = sum(r.stalls for r in view.robots.values()) + \
            len(self.stopped_at_end)  # (its own count never saw that stall: it never resumed)
        res["robots_stopped_at_end"] = sorted(self.stopped_at_end)
        absent = {f.robot for f in planned if f.kind in ("crash", "hang") and f.tick == 0}
        res["absent_at_start"] = [i for i in view.absent_at_start if i not in absent]
        down = {f.robot for f in planned if f.kind == "crash"} | self.crashed | self.held | {
            int(w.split()[1]) for w in errors}  # (said above; a hang's robot did not leave)
        left = [i for i, r in sorted(view.robots.items()) if r.state == "lost" and i not in down
                and i not in self.stopped_at_end]  # (said above)
        if left:  # (a world stalled past its lease: the robots' sessions dropped, and on the
            # virtual clock an absence nobody planned is for good)
            said.append(f"robots {left} left the run before its end; the world played on "
                        "without them")
        unsaid = int(res.get("robots_lost") or 0) - len(left) - len(down | self.stopped_at_end)
        if unsaid > 0:  # (they said they were done: a run-end record that was not the world's)
            said.append(f"{unsaid} robot(s) left the run before its end, each saying the run "
                        "had ended (robots_lost in the result); the world played on without them")
        if res["absent_at_start"]:  # (the world waited `start_timeout` for them, then began)
            said.append(f"robots {res['absent_at_start']} were not up within the start timeout "
                        f"({start_timeout:g} s; --start-timeout S): the run began without them")
        said += changes_said(res)
        for line in said:
            print(f"swarm: warning: {line}", file=sys.stderr, flush=True)


def changes_said(res: dict[str, Any]) -> list[str]:
    """Live link-fault changes (`swarm fault`) the run did not apply as asked: the world logged
    each, in a log a clean run removes, so the run says them once more (the supervisor says the
    process-fault changes it drops itself)."""
    fc = res.get("fault_changes")
    fc = fc if isinstance(fc, dict) else {}
    why = {"dropped": f"dropped (more than {MAX_PENDING} were waiting)",
           "late": "applied late (their tick had been played)",
           "unfit": "dropped (they did not fit the faults then in force)"}
    return [f"{fc[k]} live link-fault change(s) {w}" for k, w in why.items() if fc.get(k)]
