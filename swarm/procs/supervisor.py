"""`swarm run`: spawn the world and N robot processes, supervise them, show the live dashboard.

The world and the robots are forked by the run's fork server (`swarm.common.forkserver`: it
never opens a Zenoh session, so a fork is safe), the other children are fresh interpreters; all
are the supervisor's own children. The world listens on a free loopback port; robots and the
supervisor's own session connect to it. Ctrl-C (or any exit) SIGINTs every child, then SIGKILLs
what is left after 2 s: no process of the run outlives it. With `--netns` each process has a
network namespace of its own, joined by veth pairs, and the kernel applies the link faults."""

from __future__ import annotations

import contextlib
import dataclasses
import logging
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import zenoh
from rich.console import Console
from rich.live import Live

from swarm.common import forkserver
from swarm.common.atomic import write_json
from swarm.common.policy_spec import effective_checkpoint, shown
from swarm.common.procstat import ProcSampler, process_age
from swarm.common.report import json_line, provenance
from swarm.common.spawn import (
    child_env,
    child_result,
    claim_run,
    last_error,
    registry,
    release_run,
    stop_children,
    stops_held,
    tidy_interrupted,
    tidy_logs,
    wait_port,
)
from swarm.learn.weights import fresh_checkpoint
from swarm.net.faults import ProcessFault, control, plan_from_table
from swarm.net.inbox import Inbox, put_once, tally
from swarm.net.kernel.hosts import topology
from swarm.net.keys import Keys
from swarm.net.learning import check_learner_status
from swarm.net.messages import (
    K_CONTROL,
    K_LSTATUS,
    K_RESULT,
    K_RSTATUS,
    K_STATUS,
    pack_record,
    unpack_record,
)
from swarm.net.records import check_robot_status, check_world_result, check_world_status
from swarm.net.security.tls import identity_of, run_configs, topology_configs, topology_secure
from swarm.net.zconfig import ZenohOptions, free_port
from swarm.procs.dashboard import SwarmView, render
from swarm.procs.fleet import Fleet, finish_recorder, how_it_ended, recording_result
from swarm.procs.learning.supervised import drain, learner_left, learner_result
from swarm.procs.runconfig import RunConfig, RunRecord, SuperviseOptions, leave_grace
from swarm.procs.status_order import StatusOrder
from world.config import ConfigError, WorldConfig, to_dict

log = logging.getLogger("swarm.supervisor")


class Supervisor:
    def __init__(self, cfg: WorldConfig, run: RunConfig, opts: SuperviseOptions,
                 console: Console | None = None, faults: dict[str, Any] | None = None,
                 learning: dict[str, Any] | None = None) -> None:
        self.cfg, self.run_cfg, self.opts = cfg, run, opts
        self.learning = learning  # {"learner": LearnerConfig fields, "train": ...} or None
        self.learner: subprocess.Popen[bytes] | None = None
        self.learner_status: dict[str, Any] | None = None
        self.learner_out: str | None = None  # the learner's output folder (--train)
        self.faults = dict(faults or {})
        plan = plan_from_table(self.faults, run.seed)
        self.process_faults = sorted(plan.process, key=lambda p: p.tick)
        self.planned = list(self.process_faults)  # (the plan's, kept: the queue is used up)
        self.process_faults_dropped = 0  # live changes the full queue had no room for
        self.run_tick = 0  # the world's run tick, from its last status
        self.order = StatusOrder()  # statuses in order, one that skips ahead held
        self.console = console or Console()
        self.keys = Keys(run.run_id)
        self.port = free_port()
        self.hub = f"tcp/127.0.0.1:{self.port}"
        self.topo = topology(run.run_id, cfg.n_robots, opts.netns, opts.hosts)
        self.routers: list[subprocess.Popen[bytes]] = []  # --hosts: one per host but the world's
        self.zcfg = [] if opts.netns is None else opts.netns.zenoh_cfg()  # --cfg of every session
        # the run's files (children's logs, the spec they read, the world's result file): in
        # --log-dir, kept; else in a temp folder, removed after a clean run (`tidy_logs`)
        self.tmp = Path(opts.log_dir) if opts.log_dir else \
            Path(tempfile.mkdtemp(prefix=f"swarm-{run.run_id}-"))
        self.log_dir = self.tmp
        self.log_dir.mkdir(parents=True, exist_ok=True)
        self.zfiles: dict[str, Path] = {}  # --secure: identity -> its session's config file
        extra = (learning is not None, bool(opts.record))  # (a learner's, a recorder's files)
        self.topo_sec = topology_secure(opts.secure, run.run_id, cfg.n_robots, opts.hosts,
                                        *extra) if opts.secure and self.topo else None
        if opts.secure and self.topo is None:  # (namespaces: configs once they are up)
            self.hub, self.zfiles = run_configs(opts.secure, run.run_id, cfg.n_robots, self.port,
                                                self.log_dir / "zenoh", *extra)
        self.world: subprocess.Popen[bytes] | None = None
        self.children: list[subprocess.Popen[bytes]] = []  # every one spawned (`_spawn`)
        self.forks: forkserver.ForkServer | None = None  # forks the world and robots
        self.fleet = Fleet(self._spawn_robot, self.log_dir, run.restart_crashed)
        self.robots = self.fleet.procs  # robot id -> its running process
        self.inbox: Inbox | None = None
        self.bad, self.bad_by_key = 0, {}  # records that did not decode or fit, dropped
        self.view = SwarmView(run.run_id, run.policy, cfg.height, cfg.width, cfg.n_robots,
                              cfg.comm_range, run.episodes, attention_focus=opts.attention)
        self.recorder: subprocess.Popen[bytes] | None = None
        self.recorder_alive = False
        self.result: dict[str, Any] | None = None
        self.procstat = ProcSampler()  # peak memory and CPU per tick of the children
        self.first_tick_age: float | None = None

    def _spawn(self, args: list[str], name: str, zopts: ZenohOptions,
               ns: str | None = None) -> subprocess.Popen[bytes]:
        err = open(self.log_dir / f"{name}.log", "ab")
        env = child_env()
        prefix = self.topo.exec_prefix(ns) if self.topo is not None and ns else []
        zfile = str(self.zfiles[identity_of(name)]) if self.zfiles else None  # --secure's TLS
        zopts = dataclasses.replace(zopts, cfg=[*zopts.cfg, *self.zcfg], config_file=zfile)
        try:  # (appended to `children`, so stopped at the end)
            return forkserver.child(None if ns else self.forks, prefix, [*args, *zopts.to_args()],
                                    env, err, self.children)
        finally:
            err.close()

    def _spawn_robot(self, i: int) -> subprocess.Popen[bytes]:
        hub, ns = self.hub, None
        if self.topo is not None:  # its own namespace, through its link to the world
            hub, ns = self.topo.robot_endpoint(i, self.port), self.topo.robot_ns[i]
        # a robot waits for the world's record as long as the world waits for the robots
        wait = max(30.0, self.run_cfg.start_timeout)
        return self._spawn(["robot", "--id", str(i), "--run-id", self.run_cfg.run_id,
                            "--wait", f"{wait:g}"], f"robot{i}", ZenohOptions("client", [hub]),
                           ns)

    def start(self) -> float:
        """Write the spec and start the world; robots follow once the supervisor listens."""
        spec = self.tmp / "spec.json"
        fresh = self.learning is not None and not self.run_cfg.checkpoint  # one fresh version 0
        if fresh:  # (written while the world starts: the world never reads it)
            self.run_cfg = dataclasses.replace(self.run_cfg,
                                               checkpoint=str(self.tmp / "initial.pt"))
        learning = self.learning or {}
        RunRecord(self.cfg, self.run_cfg, self.faults, learner=learning.get("learner"),
                  train=learning.get("train"), supervised=True).write(spec)
        listen, host, ns = [self.hub], "127.0.0.1", None
        if self.topo is not None:  # the world listens on each of its veths, in its namespace
            self.topo.up()
            host, ns = self.topo.hub_addr, self.topo.world_ns
            self.hub = f"tcp/{host}:{self.port}"
            if self.topo_sec is not None:  # TLS; the relays' certificates name the addresses
                self.hub, self.zfiles = topology_configs(self.topo_sec, self.topo, self.port,
                                                         self.log_dir / "zenoh")
            listen = self.topo.world_listen(self.port)
        write_json(registry(self.run_cfg.run_id), {"hub": self.hub, "pid": os.getpid()})
        t0 = time.monotonic()
        with stops_held():  # (none into a namespace: `ip netns exec` starts a process)
            self.forks = None if self.topo else forkserver.start(
                child_env(), self.log_dir, self.run_cfg.run_id, self.children)
        self.world = self._spawn(["world", "--spec", str(spec), "--run-id", self.run_cfg.run_id,
                                  "--json", str(self.tmp / "world_result.json")], "world",
                                 ZenohOptions("router", listen=listen), ns)
        if fresh:  # (one that fails: `supervise` stops the world)
            fresh_checkpoint(self.run_cfg.policy, self.cfg, self.run_cfg.seed,
                             Path(str(self.run_cfg.checkpoint)))
        wait_port(host, self.port, self.world, 30.0)
        for name, args, zopts, rns, addr in self.topo.routers(self.port) if self.topo else []:
            self.routers.append(self._spawn(args, name, zopts, rns))
            wait_port(addr, self.port, self.routers[-1], 30.0, name)
        if self.opts.record:  # in the root namespace, like the supervisor's own session
            self.recorder = self._spawn(["record", "--run-id", self.run_cfg.run_id, "--out",
                                         self.opts.record], "recorder",
                                        ZenohOptions("client", [self.hub]))
        if self.learning is not None:
            out = self.learning["learner"].get("out") or str(self.log_dir / "learner")
            self.learner_out = out
            self.learner = self._spawn(["learner", "--spec", str(spec), "--run-id",
                                        self.run_cfg.run_id, "--policy", self.run_cfg.policy,
                                        "--checkpoint", str(self.run_cfg.checkpoint), "--out",
                                        out, "--made-by", self.opts.command or "swarm run"],
                                       "learner", ZenohOptions("client", [self.hub]))
        return t0

    def stop_all(self, grace: float = 2.0) -> None:
        if self.forks is not None:  # (it ends; what it forked is in `children`)
            self.forks.close()
        for p in self.fleet.halted():  # a stopped process cannot take SIGINT
            p.send_signal(signal.SIGCONT)
        with contextlib.suppress(OSError):
            registry(self.run_cfg.run_id).unlink()
        stop_children(list(self.children), grace)  # (every one ever started)

    def _handle(self, kind: str, key: str, payload: bytes | None) -> None:
        v = self.view
        try:
            if kind == "status":
                rec = check_world_status(unpack_record(payload or b"", K_STATUS), self.cfg,
                                         self.run_cfg.first_episode, self.run_cfg.episodes)
                apply, dropped = self.order.offer(rec)
                if dropped is not None:
                    self._bad_record("status", dropped)
                if not apply:  # (held: applied if the next one goes on from it)
                    return
                v.apply_status(rec)
                self.run_tick = rec["run_tick"]
                while self.process_faults and self.process_faults[0].tick <= self.run_tick:
                    self._process_fault(self.process_faults.pop(0))
                if self.opts.headless and self.opts.status_lines:
                    json_line({"status": rec})
            elif kind == "rstatus":
                v.apply_robot(check_robot_status(unpack_record(payload or b"", K_RSTATUS),
                                                 self.cfg.n_robots, self.cfg.horizon))
            elif kind == "result":
                self.result = check_world_result(
                    unpack_record(payload or b"", K_RESULT), self.run_cfg.policy,
                    self.run_cfg.episodes, self.run_cfg.run_id, self.cfg.horizon)
                v.apply_result(self.result)
            elif kind == "lstatus":
                self.learner_status = check_learner_status(unpack_record(payload or b"", K_LSTATUS))
                v.learner = self.learner_status
            elif kind == "control":
                faults = control.check_control(unpack_record(payload or b"", K_CONTROL),
                                               self.run_cfg.seed, self.cfg.n_robots).process
                if len(self.process_faults) + len(faults) > control.MAX_PENDING:  # (not bad)
                    self.process_faults_dropped += 1
                    if self.process_faults_dropped & (self.process_faults_dropped - 1) == 0:
                        log.warning("dropped a process-fault change (%d so far): %d wait "
                                    "already", self.process_faults_dropped, control.MAX_PENDING)
                    return
                for f in faults:  # ROBOT@TICK waits for run tick TICK, ROBOT alone is now
                    if f.tick < 0:
                        self._process_fault(f)
                    else:
                        self.process_faults = sorted([*self.process_faults, f],
                                                     key=lambda p: p.tick)
            elif kind in ("alive:live", "alive:dead"):
                live, parts = kind == "alive:live", key.split("/")
                if parts[-2] == "robot" and parts[-1].isdigit():
                    if not int(parts[-1]) < self.cfg.n_robots:  # (a token of no robot here)
                        raise ValueError(f"liveliness token of robot {parts[-1]}, not in the team")
                    v.set_alive(int(parts[-1]), live)
                elif parts[-1] == "recorder":
                    self.recorder_alive = live
                elif parts[-1] == "world":
                    v.world_alive = live
        except Exception as exc:  # a record of the right kind with wrong contents: dropped
            self._bad_record(kind, str(exc), key)

    def _bad_record(self, kind: str, why: str, key: str | None = None) -> None:
        key = key or str(getattr(self.keys, kind))
        self.bad += 1
        self.view.bad_records = self.bad
        if tally(self.bad_by_key, key):  # (the first few of a key, then powers of two)
            log.warning("supervisor dropped a %s record on %s: %s", kind, key, why)

    def _process_fault(self, f: ProcessFault) -> None:
        """Do `f` (`Fleet.fault`) and show it among the dashboard's events (not once the run
        has its result: there is nothing left to fault)."""
        if self.result is not None:
            return
        self.view.events = self.view.events[-5:] + [self.fleet.fault(f, self.run_tick)]

    def supervise(self) -> dict[str, Any]:
        try:  # the id is this run's until it ends, or refused (nothing started yet)
            claim_run(self.run_cfg.run_id)
        except ConfigError:
            if self.opts.log_dir is None:
                tidy_interrupted(self.tmp)
            raise
        stopped, failed = False, None
        try:  # whatever happens, no process and no namespace of the run is left behind
            return self._supervise()
        except (KeyboardInterrupt, ConfigError) as exc:  # (ConfigError: refused by --netns)
            stopped, failed = True, "interrupted" if isinstance(exc, KeyboardInterrupt) else None
            raise
        except Exception as exc:  # (RuntimeError, TimeoutError, OSError, a Zenoh error: said)
            failed = str(exc) or type(exc).__name__
            raise
        finally:
            try:  # (a Ctrl-C held during the stop is raised after it: the namespaces go anyway)
                self.stop_all()
            finally:
                if self.topo is not None:
                    self.topo.down()
                if stopped and self.opts.log_dir is None:  # no result names the temp folder
                    tidy_interrupted(self.tmp, self.learner_out is not None)
                release_run(self.run_cfg.run_id)
                if failed:
                    self._ended_early(failed)

    def _ended_early(self, failed: str) -> None:
        """A run that failed or was interrupted, once every process is stopped: where the
        learner's weights are (its last checkpoint, read from the file), and its --json with
        `error`, what was done and the learner's accounting (not an older run's file)."""
        try:  # (in a `finally`: nothing here may hide the run's own error)
            left = None if self.learner is None else learner_left(self.learner_out)
            if left is not None:
                print(f"swarm: {left['line']}", file=sys.stderr, flush=True)
            if self.opts.json_path:
                v, lr = self.view, {} if self.learning is None else {"learner": {**learner_result(
                    self.learner_status, self.view.episodes_done, self.learner_out), **(
                        {"checkpoint": left["checkpoint"]} if left else {})}}
                write_json(self.opts.json_path, {
                    "error": failed, "ticks_done": v.ticks_done,
                    "completed": v.episodes_done, **lr, **self._made_by()})
        except Exception as exc:
            log.warning("what the run left could not be said in full: %s", exc)

    def _supervise(self) -> dict[str, Any]:
        t_start = self.start()
        mine = str(self.zfiles["supervisor"]) if self.zfiles else None  # --secure
        conf = ZenohOptions(mode="client", connect=[self.hub], cfg=self.zcfg,
                            config_file=mine).to_config()
        first_tick: float | None = None
        with zenoh.open(conf) as session:
            k = self.keys
            self.inbox = inbox = (
                Inbox(session).subscribe(k.status, "status")
                .subscribe(k.robot_status("*"), "rstatus").subscribe(k.result, "result")
                .subscribe(k.control, "control").subscribe(k.learner_status, "lstatus")
                .liveliness(k.alive_all, "alive"))
            # (the learner starts beside the robots: the world's first tick waits for it)
            if self.recorder is not None:  # its subscription first: every tick is recorded
                self._wait_recorder(inbox)
            # Robots only after our subscriptions reached the world: the first tick is not missed.
            for i in range(self.cfg.n_robots):
                self.fleet.start(i)
            fit = self.console.is_terminal  # (a terminal crops what is taller than itself)
            live = None if self.opts.headless else Live(
                get_renderable=lambda: render(self.view, fit), console=self.console,
                refresh_per_second=4, screen=False, transient=False)
            try:
                if live:
                    live.start()
                while self.result is None:
                    ev = inbox.next(0.1)
                    if ev is not None:
                        self._handle(*ev)
                        if ev.kind == "status" and first_tick is None:
                            first_tick = time.monotonic()
                            self.first_tick_age = process_age()
                    self._check_children()
                    self._sample_rss()
                    if self.world is not None and self.world.poll() is not None and \
                            inbox.q.empty():
                        break
                self._sample_rss(every=0.0)  # (robots whole: a short run's may all be early)
                held, dropped = self.order.end((self.result or {}).get("ticks"))
                if held is not None:  # (the last status, after a skip: `StatusOrder.end`)
                    self.view.apply_status(held)
                elif dropped is not None:
                    self._bad_record("status", dropped)
                # a training world stays up after its result until the learner is drained and
                # stopped; robots send their final counts only once the world has ended
                self._drain_learner()
                if self.learner is not None:
                    put_once(session, k.control, pack_record(K_CONTROL, {"stop": True}))
                self._late_status()
                finish_recorder(self.recorder)
            except KeyboardInterrupt:
                put_once(session, k.control, pack_record(K_CONTROL, {"stop": True,
                                                                     "why": "interrupt"}))
                raise
            finally:
                if live:
                    live.stop()
                inbox.close()
                self.stop_all()
        lost = self.result is None and self.world is not None and self.world.returncode == 0
        if lost:  # its result message was lost on the way: the copy it wrote before exiting
            self.result = child_result(self.tmp / "world_result.json", self.run_cfg.run_id)
            if self.result is not None:
                log.warning("the world's result message was lost; read its result file instead")
        if self.result is None:
            code = self.world.returncode if self.world else "?"
            why = last_error(self.log_dir / "world.log")
            raise RuntimeError(f"world ended without a result (exit code {code}"
                               f"{': ' + why if why else ''}); logs in {self.log_dir}")
        res = dict(self.result)
        res["startup_s"] = (first_tick - t_start) if first_tick else None
        res["first_tick_s"] = self.first_tick_age  # from the command (this process's start)
        self.fleet.account(res, self.view, self.planned, self.run_cfg.start_timeout)
        if why := self.fleet.deserted(True, grace=0.0):  # (the world's end came before the 5 s)
            raise RuntimeError(f"{why} (logs in {self.log_dir})")
        res["supervisor_bad"] = self.bad  # records it dropped (status, result, control, ...)
        if self.inbox is not None:  # and what its inbox dropped unread
            res["supervisor_dropped"] = self.inbox.dropped
        res["result_message_lost"] = lost
        if self.recorder is not None:  # one that failed cut the file: data lost, said
            res["recording"] = recording_result(self.opts.record, self.recorder.returncode,
                                                self.log_dir)
        res["process_faults"] = self.fleet.log
        if res.get("stopped"):  # a stop on the control key ended the run early: said, not hidden
            print(f"swarm: run {self.run_cfg.run_id} was stopped by a control message after "
                  f"{res.get('completed', 0)} of {self.run_cfg.episodes} episodes",
                  file=sys.stderr, flush=True)
        # scheduled for a tick the run never reached: named, not silently dropped
        res["process_faults_pending"] = [f"{f.kind} {f.robot}@{f.tick}"
                                         for f in self.process_faults]
        res["process_faults_dropped"] = self.process_faults_dropped
        res.update(self.procstat.summary())
        if self.learning is not None:
            res["learner"] = learner_result(self.learner_status, int(res.get("completed", 0)),
                                            self.learner_out, warn=True)
        res.update(self._made_by())
        if self.topo is not None:  # a robot whose session never opened is in no other count
            res["netns"] = {**self.topo.describe(), "never_joined": sum(
                r.state == "starting" for r in self.view.robots.values())}
        if self.opts.log_dir is None:  # a temp folder: removed after a clean run
            tidy_logs(self.tmp, res, keep=self.learner_out is not None and
                      Path(self.learner_out).resolve().is_relative_to(self.tmp.resolve())
                      or res.get("recording", {}).get("partial", False))
        if self.zfiles:  # its session configs are named while the run's folder stands
            res["secure"] = {"certs": self.opts.secure, "hub": self.hub, **(
                {"configs": str(self.log_dir / "zenoh")} if self.log_dir.is_dir() else {})}
        if self.opts.json_path:
            write_json(self.opts.json_path, res)
        return res

    def _made_by(self) -> dict[str, Any]:
        rc = self.run_cfg  # what made the result (--train without a checkpoint: None, fresh
        ckpt = None if rc.checkpoint == str(self.tmp / "initial.pt") else rc.checkpoint \
            if rc.train else effective_checkpoint(rc.policy, rc.checkpoint)  # weights of --seed)
        return dict(command=self.opts.command, checkpoint=shown(ckpt), world=to_dict(self.cfg),
                    run={**to_dict(rc), "checkpoint": shown(ckpt)}, provenance=provenance())

    def _drain_learner(self) -> None:
        if self.learner is not None and self.result is not None:
            drain(self.learner, lambda: self.learner_status, self._pump_inbox,
                  int(self.result.get("completed", 0)), int(self.learning["train"]["batch"]))

    def _wait_recorder(self, inbox: Inbox, timeout: float = 60.0) -> None:
        """Until the recorder's token is up (it listens and its file is open)."""
        assert self.recorder is not None
        deadline = time.monotonic() + timeout
        while not self.recorder_alive:
            if (ev := inbox.next(0.1)) is not None:
                self._handle(*ev)
            if self.recorder.poll() is not None or time.monotonic() > deadline:
                code = self.recorder.poll()  # (None: it did not come up in time)
                why = last_error(self.log_dir / "recorder.log") or (
                    f"not up within {timeout:g} s" if code is None else how_it_ended(code))
                raise RuntimeError(f"the recorder did not start: {why} (logs in {self.log_dir})")

    def _late_status(self) -> None:
        """Wait (`leave_grace`) for the last tick's status and running robots' final counts."""
        want = int((self.result or {}).get("ticks", 0))
        deadline = time.monotonic() + leave_grace(self.cfg.n_robots)
        while time.monotonic() < deadline and (self.view.ticks_done < want or not self.view.final(
                i for i, p in self.robots.items() if p.poll() is None or p.returncode == 0)):
            self._pump_inbox(0.05)

    def _pump_inbox(self, seconds: float) -> None:
        end = time.monotonic() + seconds
        while self.inbox is not None and (ev := self.inbox.next(end - time.monotonic())):
            self._handle(*ev)

    def _sample_rss(self, every: float = 0.5) -> None:
        procs = {"world": self.world, **{f"robot{i}": p for i, p in self.robots.items()}}
        self.procstat.sample(procs, self.view.ticks_done, every=every)

    def _check_children(self) -> None:
        """Robots that died are counted, said and restarted with --restart-crashed
        (`Fleet.check`); a child that died of an error ends the run with that error as one
        line, naming the process, when the run cannot go on without it (the learner; the last
        robot, which would leave the world playing episodes nobody plays; a robot
        before the first tick, unless --restart-crashed brings it back: the world would wait
        for it until `start_timeout`, then play without it; not with --netns/--hosts, where a
        robot may never join through a faulty link, `never_joined`)."""
        if self.result is None:
            self.fleet.check()
        early = self.view.ticks_done == 0 and not (self.run_cfg.restart_crashed or self.topo)
        if why := self.fleet.deserted(self.result is None and self.world is not None and
                                      self.world.poll() is None):
            raise RuntimeError(f"{why} (logs in {self.log_dir})")
        if self.fleet.errors and (early or not self.robots):  # (--netns: may never join)
            who, why = next(iter(self.fleet.errors.items()))
            raise RuntimeError(f"{who} failed: {why}{'' if self.robots else '; no robot is left'}"
                               f" (logs in {self.log_dir})")
        if self.learner is not None and self.learner.poll() is not None and self.result is None:
            why = last_error(self.log_dir / "learner.log") or how_it_ended(self.learner.returncode)
            raise RuntimeError(f"the learner failed: {why} (logs in {self.log_dir})")


def main(cfg: WorldConfig, run: RunConfig, opts: SuperviseOptions,
         console: Console | None = None, faults: dict[str, Any] | None = None,
         learning: dict[str, Any] | None = None) -> dict[str, Any]:
    return Supervisor(cfg, run, opts, console, faults, learning).supervise()
