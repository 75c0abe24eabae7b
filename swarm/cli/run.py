"""Command-line front ends of the distributed swarm: `swarm run`, `world`, `robot` and
`experiment`, each a thin wrapper around an importable `main(...)` (in `swarm.procs`; the sweep's
in `swarm.studies.experiment`), and `fault`, the operator's client: it checks the change against
the running world's config and tick and puts one control record, on a session of its own."""

from __future__ import annotations

import argparse
import dataclasses
import json
import logging
import secrets
import sys
from typing import Any

from swarm.cli.checks import (
    EXIT_INCOMPLETE,
    check_by_hand,
    check_clock,
    check_fault_ticks,
    check_not_played,
    check_policy,
    check_run_outputs,
    check_training,
    status_tick,
)
from swarm.cli.common import (
    _command,
    _consoles,
    add_common,
    add_fault_flags,
    add_world,
    fault_table,
    file_tables,
    named_dir,
    output_dir,
    output_file,
    path_name,
    world_config,
)
from swarm.cli.hosts import add_hosts_flag, add_netns_flags, hosts_option, netns_faults
from swarm.cli.record import add_attention_flag
from swarm.cli.secure import add_secure_flag, check_run_secure, secure_options
from swarm.common.flags import check_wait, robot_id
from swarm.common.report import OutputClosed, json_line, provenance
from swarm.net import zconfig
from swarm.net.inbox import put_once
from swarm.net.zconfig import open_session
from swarm.procs.runconfig import RunConfig, RunRecord, check_new_run
from world.config import ConfigError, from_dict, to_dict, toml_bools


def _add_run_flags(p: argparse.ArgumentParser, pace: str) -> None:
    """The [run] flags `swarm run` and `swarm world` share; `pace`: the command's --pace default."""
    g = p.add_argument_group("run (override [run] of --config)")
    g.add_argument("--policy", help="policy every robot runs (default commattn, from the shipped "
                                    "checkpoint)")
    g.add_argument("--checkpoint", metavar="FILE", help="checkpoint of a learned policy")
    g.add_argument("--episodes", type=int, metavar="K", help="episodes to run (default 5)")
    g.add_argument("--first-episode", type=int, metavar="E", help="number of the first episode")
    g.add_argument("--run-id", metavar="ID", help="namespace of every key (default: random)")
    g.add_argument("--tick-timeout", type=float, metavar="S",
                   help="seconds the world waits for a tick's actions (default 2)")
    g.add_argument("--pace", type=float, metavar="HZ",
                   help=f"cap ticks/s so the run can be watched (default: {pace})")
    g.add_argument("--sample", action="store_true", default=None,
                   help="sample actions (counter-based noise) instead of greedy")
    g.add_argument("--clock", choices=["virtual", "real"],
                   help="message timing in virtual time (default: a run is a function of its "
                        "seed and faults) or on the wall clock (forced by --netns)")
    g.add_argument("--delivery", choices=["radio", "direct"],
                   help="robot-to-robot messages through the world's radio (default) or straight "
                        "between robots, each applying range and the seeded faults itself "
                        "(same decisions; on the real clock each robot times its copies on "
                        "its own clock; robots learn it from the world)")
    g.add_argument("--watchdog", type=float, metavar="S",
                   help="virtual clock: wall seconds before a hung robot is stepped without "
                        "(default 10)")
    g.add_argument("--start-timeout", type=float, metavar="S",
                   help="seconds the world waits for every robot before the first tick, then "
                        "starts without the missing ones (default 60; `swarm run`: 60 or 0.6 s "
                        "a robot, the longer)")


def _add_train_flags(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("learning in the field (override [learner] / [train] of --config)")
    g.add_argument("--train", action="store_true", default=None,
                   help="run a learner too: robots sample, record their episodes and adopt "
                        "its weights at episode boundaries")
    g.add_argument("--train-batch", type=int, metavar="B",
                   help="episodes per learner update (default 10 with --train)")
    g.add_argument("--train-algo", choices=["reinforce", "ppo"],
                   help="the learner's estimator (default reinforce, the paper's; ppo is ours)")
    g.add_argument("--train-ppo-epochs", type=int, metavar="K",
                   help="with --train-algo ppo: passes over each batch (default 4)")
    g.add_argument("--learner-out", metavar="DIR",
                   help="the learner's checkpoint and curve (default: LOG_DIR/learner)")
    g.add_argument("--rollout-loss", type=float, metavar="P",
                   help="drop each robot's episode record to the learner with probability P")
    g.add_argument("--train-sync", action="store_true", default=None,
                   help="lockstep: each episode waits for the learner to take the ones before it "
                        "and uses its newest weights, so the run is a function of its seed")


def run_config(args: argparse.Namespace, tables: dict[str, Any]) -> RunConfig:
    flags = {"policy": args.policy, "checkpoint": args.checkpoint, "episodes": args.episodes,
             "first_episode": args.first_episode, "run_id": args.run_id,
             "tick_timeout": args.tick_timeout, "seed": args.seed, "pace": args.pace,
             "clock": getattr(args, "clock", None), "watchdog": getattr(args, "watchdog", None),
             "delivery": getattr(args, "delivery", None),
             "greedy": False if args.sample else None,
             "train": getattr(args, "train", None),
             "rollout_loss": getattr(args, "rollout_loss", None),
             "train_sync": getattr(args, "train_sync", None),
             "restart_crashed": getattr(args, "restart_crashed", None) or None,
             "start_timeout": getattr(args, "start_timeout", None)}
    table = dict(tables.get("run", {}))
    toml_bools(RunConfig, table, "[run]")
    given = {k: v for k, v in flags.items() if v is not None}
    data = {**table, **given}
    if data.get("train"):  # a learner learns from sampled decisions: greedy ones never explore
        if table.get("greedy") is True:
            raise ConfigError("[run] greedy = true with train: a field learner needs sampled "
                              "actions (drop greedy)")
        data["greedy"] = False
    data.setdefault("run_id", f"r{secrets.token_hex(4)}")
    try:
        return check_new_run(from_dict(RunConfig, data, "[run]"))
    except ValueError as exc:
        raise ConfigError(str(exc)) from None


def _logging(verbose: bool) -> None:
    logging.basicConfig(level=logging.INFO if verbose else logging.WARNING, stream=sys.stderr,
                        format="%(asctime)s %(name)s %(levelname)s %(message)s")


START_S_PER_ROBOT = 0.6
"""`swarm run`'s default start timeout per robot it spawns (when over the 60 s default)."""

def cmd_run(args: argparse.Namespace) -> int:
    from swarm.common.spawn import check_run_free
    from swarm.procs.supervisor import SuperviseOptions
    from swarm.procs.supervisor import main as supervise

    tables = file_tables(args.config)
    world = world_config(args, tables)
    run = run_config(args, tables)
    faults = fault_table(args, tables, world.n_robots)
    # everything the run needs, checked before a process is spawned: one line, exit 2
    learning = check_training(args, tables, run)  # (None: the run does not train)
    check_clock(args, tables, run, faults)
    check_fault_ticks(faults, run, world, flags=[k for k in ("crash", "hang", "restart")
                                                 if getattr(args, k, None)])
    check_run_free(run.run_id)
    if args.start_timeout is None and "start_timeout" not in tables.get("run", {}):
        # (spawning N interpreters: ~0.3 s of CPU each, on a machine that may be busy)
        run = dataclasses.replace(run, start_timeout=min(3600.0, max(
            run.start_timeout, START_S_PER_ROBOT * world.n_robots)))
    check_run_secure(args, run.run_id, world.n_robots, run.train)
    check_policy(run, world)
    if args.attention is not None and args.attention >= world.n_robots:  # (None: off)
        raise ConfigError(f"--attention {args.attention}: the team has robots "
                          f"0..{world.n_robots - 1}")
    if args.hosts:
        from swarm.net.kernel.hosts import check_host_count

        check_host_count(args.hosts, world.n_robots)
    out, _ = _consoles()
    if args.pace is None and "pace" not in tables.get("run", {}) and not args.headless \
            and out.is_terminal:
        run = dataclasses.replace(run, pace=8.0)  # watchable by default on a terminal
    netns = netns_faults(args)
    if netns is not None:  # the kernel decides when a packet arrives: only the wall clock knows
        run = dataclasses.replace(run, clock="real")
    if args.secure and netns is not None and netns.transport != "tcp":
        raise ConfigError("--secure needs --netns-transport tcp (TLS runs over TCP)")
    check_run_outputs(args)  # (last: it makes the folders)
    opts = SuperviseOptions(headless=args.headless, json_path=args.json,
                            log_dir=args.log_dir,
                            netns=netns, secure=args.secure, record=args.record,
                            attention=args.attention, hosts=hosts_option(args),
                            command=_command())
    try:
        res = supervise(world, run, opts, console=out, faults=faults, learning=learning)
    except OutputClosed:
        print("swarm: stdout was closed (its reader went away); every process of the run was "
              "stopped", file=sys.stderr)
        return 141
    except KeyboardInterrupt:
        print("swarm: interrupted; every process of the run was stopped", file=sys.stderr)
        return 130
    if args.headless:
        json_line({"result": {k: v for k, v in res.items() if k != "actions"}})
    else:
        from swarm.cli.console import eval_table

        m = res.get("messages", {})  # copies to other robots, both kinds, in each figure
        to_others = m.get("traj_to_others")
        sent = "-" if to_others is None else to_others + (m.get("hidden_delivered") or 0)
        out.print()
        out.print(eval_table([res], title=f"swarm run {run.run_id}", width=out.width))
        out.print(f"ticks/s {res.get('ticks_per_s', 0):.1f}   "
                  f"startup {res.get('startup_s') or 0:.1f} s"
                  f"   copies delivered {sent} lost {m.get('lost')} "
                  f"late {m.get('late')} bad {m.get('bad')}   timeouts {res.get('timeouts')}   "
                  f"robots lost {res.get('robots_lost')}"
                  + (f"   logs kept in {res['logs']}" if res.get("logs") else ""))
        if args.json:
            out.print(f"wrote {args.json}")
    if learning is not None and "learner" in res:  # where the trained weights went
        from swarm.procs.learning.supervised import trained_line

        print(trained_line(res["learner"], learning["train"]["batch"]), file=sys.stderr)
    if res.get("recording", {}).get("partial"):  # the recording asked for is lost in part
        return 1
    return EXIT_INCOMPLETE if res.get("completed", 0) < run.episodes else 0


def cmd_world(args: argparse.Namespace) -> int:
    from swarm.common.atomic import write_json
    from swarm.procs.world import main as world_main
    _logging(args.verbose)
    if args.spec is not None and not args.spec.strip():
        raise ConfigError("--spec wants a file name, got an empty one")
    supervised = False  # (a spec's: `swarm run` owns the robots, their process faults too)
    if args.spec:
        rec = RunRecord.read(args.spec)
        world, run, faults, supervised = rec.world, rec.run, rec.faults, rec.supervised
    else:
        tables = file_tables(args.config)
        world, run = world_config(args, tables), run_config(args, tables)
        faults = fault_table(args, tables, world.n_robots)
        check_clock(args, tables, run, faults)
        check_by_hand(faults)
        check_policy(run, world)  # (a spec's: `swarm run` checked it)
    zopts = secure_options(args, zconfig.from_args(args), "world", run.run_id, world.n_robots)
    output_file(args.json)
    if not args.spec:
        print(f"swarm world: run id {run.run_id}", file=sys.stderr, flush=True)
    try:
        res = world_main(world, run, zopts, faults=faults, supervised=supervised)
    except KeyboardInterrupt:
        if not args.spec:  # (by hand: said, as `swarm run` says it; a supervisor's says it)
            print("swarm: interrupted", file=sys.stderr)
        return 130
    if args.json:
        write_json(args.json, {**res, "run": res.get("run") or to_dict(run),  # (as `run`'s)
                               "command": _command(), "provenance": provenance()})
    if res.get("stopped") and not args.spec:  # (spawned, the supervisor says it)
        print(f"swarm world: stopped by a control record after {res['completed']} of "
              f"{run.episodes} episodes", file=sys.stderr)
        return EXIT_INCOMPLETE
    return 0


def cmd_robot(args: argparse.Namespace) -> int:
    from swarm.common.spawn import supervised
    from swarm.net.keys import check_run_id
    from swarm.procs.robot import main as robot_main
    from swarm.procs.robot_status import CLAIM_SETTLE_S, WorldLeft

    check_run_id(args.run_id)
    check_wait(args.wait)
    _logging(args.verbose)
    try:
        zopts = secure_options(args, zconfig.from_args(args), f"robot-{args.id}", args.run_id)
        robot_main(args.id, args.run_id, zopts, wait_world=args.wait,  # (a supervisor starts
                   settle=0.0 if supervised() else CLAIM_SETTLE_S)  # each id once)
    except KeyboardInterrupt:  # (by hand: said, as every other command does; a supervised
        if not supervised():    # robot's stop is its supervisor's, which says why)
            print("swarm: interrupted", file=sys.stderr)
        return 130
    except WorldLeft as exc:
        print(f"swarm robot: {exc}", file=sys.stderr)
        return EXIT_INCOMPLETE
    except TimeoutError as exc:
        raise ConfigError(str(exc)) from None
    return 0


def cmd_fault(args: argparse.Namespace) -> int:
    """Change the faults of a running swarm: link faults go to the world (from the next tick, or
    --at-tick), process faults to the supervisor (at once, or at ROBOT@TICK)."""

    import time

    from swarm.common.spawn import lookup_run
    from swarm.net.keys import Keys, check_run_id
    from swarm.net.messages import K_CONTROL, BadMessage, pack_record
    from swarm.procs.robot_status import fetch_config

    check_run_id(args.run)  # before asking the network about it
    if args.at_tick is not None and not 0 <= args.at_tick < 2**40:
        raise ConfigError(f"--at-tick must be a run tick >= 0, got {args.at_tick}")
    check_wait(args.wait)
    table = fault_table(args, {}, whole=False)
    process = [f"{kind}:{text}" for kind in ("crash", "hang", "restart")
               for text in (getattr(args, kind) or [])]
    link = {k: v for k, v in table.items() if k not in ("crash", "hang", "restart")}
    if args.clear and link:
        raise ConfigError(f"--clear removes every link fault, so it takes none: use --replace "
                          f"to set {', '.join(sorted(link))} alone")
    if not link and not process and not args.clear:
        raise ConfigError("no fault given (see swarm fault --help)")
    if args.at_tick is not None and not (link or args.clear):
        raise ConfigError("--at-tick times link faults; a process fault takes ROBOT@TICK")
    opts = zconfig.from_args(args)
    if not opts.connect:
        opts.connect = [lookup_run(args.run)]
    if not args.secure and any(e.startswith("tls/") for e in opts.connect):
        raise ConfigError(f"run {args.run} is secure: give --secure DIR (the operator's "
                          "certificate)")
    opts = secure_options(args, opts, "operator", args.run)
    keys = Keys(args.run)
    rec: dict[str, Any] = {}
    if link or args.clear:
        rec["faults_table"] = link
        rec["replace"] = bool(args.clear or args.replace)
        if args.at_tick is not None:
            rec["at_tick"] = args.at_tick
    if process:
        rec["process"] = process
    with open_session(opts, args.wait) as session:
        # the run's tick, from its status (an operator of a --secure run may not read it)
        ticks: list[int] = []
        timed = [int(t.rpartition("@")[2]) for t in process if "@" in t]  # ROBOT@TICK
        sub = None if args.secure else session.declare_subscriber(
            keys.status, lambda s: ticks.append(status_tick(s.payload.to_bytes())))
        try:  # the run is there, and the faults fit it: else nothing is sent
            run = fetch_config(session, keys, args.wait)
        except (TimeoutError, BadMessage) as exc:
            where = ", ".join(opts.connect or []) or "this network"
            hint = (f"; with --secure, is {args.secure}/ca.pem the run's CA?" if args.secure
                    else "")  # (TLS refuses another CA's certificate without a word to us)
            raise ConfigError(f"run {args.run} did not answer at {where} ({exc}){hint}; "
                              "nothing was sent") from None
        if process and not run.supervised:  # (no supervisor: nobody to kill or stop a robot)
            raise ConfigError(f"run {args.run} has no supervisor (its world was started by hand): "
                              "process faults need `swarm run`; nothing was sent")
        fault_table(args, {}, run.world.n_robots, False)  # a partition or robot beyond it
        check_fault_ticks(table, run.run, run.world, args.at_tick)  # or a tick beyond its end
        if run.run.clock == "real" and "compute" in link:
            raise ConfigError(f"run {args.run} is on the real clock: --compute-ms models compute "
                              "time on the virtual clock; nothing was sent")
        time.sleep(0.3)  # the world's subscriptions reach this session too before the one put
        deadline = time.monotonic() + args.wait
        while sub is not None and (args.at_tick is not None or timed) and \
                max(ticks, default=-1) < 0 and time.monotonic() < deadline:  # (a tick to check)
            time.sleep(0.05)
        now = max(ticks, default=-1)
        check_not_played(args.at_tick, timed, now, args.run)
        if args.at_tick is not None and now < 0:
            print(f"swarm: warning: --at-tick {args.at_tick} not checked against run "
                  f"{args.run}'s tick (no status read); if it has passed, the change applies "
                  "at the next tick, counted late in the result's fault_changes",
                  file=sys.stderr, flush=True)
        sent_at, seen = time.time(), len(ticks)
        put_once(session, keys.control, pack_record(K_CONTROL, rec))
        time.sleep(0.1)
        pace = run.run.pace  # (two ticks' statuses at most: its tick time, or its pace's)
        wait = time.monotonic() + max(3.0, 2 * run.run.tick_timeout, 2 / pace if pace else 0)
        while sub is not None and 0 < seen == len(ticks) and time.monotonic() < wait:
            time.sleep(0.05)
        if sub is not None and 0 < seen == len(ticks):  # (after its last tick, nothing applies)
            print(f"swarm: warning: run {args.run} sent no status after the change: it may "
                  "have ended first (its result's fault_changes says what applied)",
                  file=sys.stderr, flush=True)
    print(json.dumps({"run": args.run, "sent_at": sent_at, "control": rec}))
    return 0


def cmd_experiment(args: argparse.Namespace) -> int:
    from swarm.studies import experiment

    named_dir(args.out, "--out")  # (`--out ''` fell back to the file's out: results/)
    path_name(args.file, "swarm experiment")
    seeds = None if args.seeds is None else experiment.parse_seeds(args.seeds)
    if (args.episodes is not None or seeds is not None) and not args.out:
        raise ConfigError("--episodes/--seeds need --out DIR: a shrunk sweep would overwrite "
                          "the file's own results")
    sweep = experiment.plan(args.file, args.episodes, seeds)  # every run checked: one line, exit 2
    if args.out:  # (the command its files record: rerun, it writes where this one did)
        sweep = dataclasses.replace(sweep, overrides=("--out", args.out, *sweep.overrides))
    out = args.out or sweep.exp.out
    output_dir(out, "--out" if args.out else f"{args.file}: [experiment] out")
    return experiment.main(sweep, out, args.resume, args.overwrite)


def add_parsers(sub: Any) -> None:
    """Register `experiment`, `run`, `world` and `fault` on the `swarm` subparsers."""
    p = sub.add_parser("experiment", help="sweep a fault parameter over policies on the swarm",
                       description="A swarm run per (policy, value, seed) of TOML FILE into "
                                   "CSV, Markdown, PNG; exit 1 if a recording is partial.")
    p.add_argument("file", metavar="FILE", help="TOML experiment file")
    p.add_argument("--out", metavar="DIR",
                   help="output directory, made if missing (default: [experiment] out, for the "
                        "shipped files the committed results/experiments)")
    p.add_argument("--episodes", type=int, metavar="K",
                   help="episodes per run (default: [run] episodes of FILE)")
    p.add_argument("--seeds", metavar="A,B,..",
                   help="seeds per point (default: [experiment] seeds of FILE)")
    p.add_argument("--resume", action="store_true",
                   help="skip runs already in the CSV; refused unless the sweep record beside "
                        "it (<name>.json) holds this sweep's world, [run], parameter, kernel, "
                        "faults and checkpoints (policies, values and seeds may be added)")
    p.add_argument("--overwrite", action="store_true", help="replace this sweep's results in "
                   "the output folder (a folder holding them is refused without it or --resume)")
    p.add_argument("--seed", type=int, help=argparse.SUPPRESS)
    p.set_defaults(func=cmd_experiment)

    p = sub.add_parser("run", help="spawn world + N robot processes over Zenoh, live dashboard",
                       description="The distributed swarm: one world process and N robot "
                                   "processes, each with its own Zenoh session, on loopback. "
                                   "Exit status: 0 every episode done, 1 a process of the run "
                                   "failed (its log named; a recorder too: the recording is "
                                   "partial), 2 bad input (nothing "
                                   f"run), {EXIT_INCOMPLETE} stopped before every episode "
                                   "completed (a stop on the run's control key; the result says "
                                   "stopped: control), 130 interrupted.")
    add_common(p)
    add_world(p)
    _add_run_flags(p, "8 when the live dashboard is on a terminal; unlimited with --headless "
                      "or when stdout is not a terminal")
    add_fault_flags(p)
    add_netns_flags(p)
    add_hosts_flag(p)
    _add_train_flags(p)
    p.add_argument("--headless", action="store_true", help="JSON lines on stdout, no dashboard")
    p.add_argument("--restart-crashed", action="store_true", help="restart robots that die")
    p.add_argument("--log-dir", metavar="DIR",
                   help="children's logs (default: a temp folder, removed after a clean run, "
                        "kept and named in the result otherwise)")
    p.add_argument("--record", metavar="FILE.mcap",
                   help="record every message of the run (raw msgpack and JSON, MCAP) into "
                        "FILE; see `swarm replay` and `swarm trace`")
    add_attention_flag(p)
    add_secure_flag(p)
    p.set_defaults(func=cmd_run)

    p = sub.add_parser("world", help="the world process (grid, clock, radio), by hand",
                       description="Run the world process; robots join with `swarm robot`. Exit "
                                   "status: 0 every episode played, 1 the run could not go on "
                                   "(no robot, or with [run] train no learner, came alive "
                                   "within --start-timeout), 2 bad input, "
                                   f"{EXIT_INCOMPLETE} stopped by a control record, 130 "
                                   "interrupted.")
    add_common(p)
    add_world(p)
    _add_run_flags(p, "unlimited")
    add_fault_flags(p, process=False)  # (crash, hang, restart: the supervisor's, swarm run)
    p.add_argument("--spec", metavar="FILE", help=argparse.SUPPRESS)
    p.add_argument("-v", "--verbose", action="store_true", help="log at INFO")
    zconfig.add_arguments(p)
    add_secure_flag(p)
    p.set_defaults(func=cmd_world)

    p = sub.add_parser("fault", help="change the faults of a running swarm",
                       description="Live fault injection into run RUN: link faults apply from "
                                   "the world's next tick (or --at-tick K); --crash/--hang/"
                                   "--restart ROBOT@TICK at run tick TICK, ROBOT alone at once "
                                   "(a `swarm run`'s robots only: its supervisor does them).")
    p.add_argument("--run", required=True, help="run id (see the dashboard)")
    p.add_argument("--replace", action="store_true",
                   help="replace the link faults in force instead of changing the given ones")
    p.add_argument("--clear", action="store_true", help="remove every link fault")
    p.add_argument("--at-tick", type=int, metavar="K",
                   help="link faults apply from run tick K (default: the next tick); with the "
                        "virtual clock the change is then reproducible. A tick the run has "
                        "passed or will never reach is refused (nothing sent); where the run's "
                        "status cannot be read (--secure: only the operator's control goes "
                        "out) it is sent with a warning, and a passed tick applies at the next, "
                        "counted late")
    p.add_argument("--wait", type=float, default=5.0, metavar="S",
                   help="seconds to wait for the run's world to answer (default 5)")
    add_fault_flags(p, config=False, live=True)
    zconfig.add_arguments(p)
    add_secure_flag(p)
    p.set_defaults(func=cmd_fault)


def add_robot_parser(sub: Any) -> None:
    """Register `robot` on the `swarm` subparsers."""
    p = sub.add_parser("robot", help="one robot process, by hand",
                       description="Join run RUN_ID as robot ID; the config comes from the "
                                   "world. Exit status: 0 the run ended, 2 bad input or no "
                                   f"world, {EXIT_INCOMPLETE} the world left before the run's "
                                   "end, 130 interrupted.")
    p.add_argument("--id", type=robot_id, required=True, help="robot id 0..N-1")
    p.add_argument("--run-id", required=True, help="the run to join (printed by `swarm world`)")
    p.add_argument("--wait", type=float, default=30.0, metavar="S",
                   help="seconds to wait for the world, in [0.1, 3600] (default 30); a client "
                        "waits as long for its router to listen")
    p.add_argument("-v", "--verbose", action="store_true", help="log at INFO")
    zconfig.add_arguments(p)
    add_secure_flag(p)
    p.set_defaults(func=cmd_robot)
