"""Command-line front ends of recordings: `swarm record` (the recorder process, spawned by
`swarm run --record FILE` or started by hand), `swarm replay FILE [--verify]` and
`swarm trace FILE --out DIR`. Thin wrappers around `swarm.procs.recorder`, `swarm.studies.replay`,
`swarm.studies.verify` and `swarm.studies.trace`. A bad file is one line, exit status 2; a
recording that does not verify is its first divergence, exit status 1.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

from swarm.cli.common import _command, _consoles, named_dir, output_dir, output_file
from swarm.common.flags import check_wait
from swarm.common.report import counted
from swarm.common.spawn import supervised
from swarm.net import zconfig
from world.config import ConfigError

if TYPE_CHECKING:
    from swarm.studies.replay import Recording


def attention_focus(text: str) -> int | None:
    """`--attention` value: `all` (-1), `off` (None) or a robot id."""
    if text == "all":
        return -1
    if text == "off":
        return None
    if text.isdigit():
        return int(text)
    raise argparse.ArgumentTypeError(f"expected all, off or a robot id, got {text!r}")


ATTN_UNSET = -2  # `swarm replay` without --attention (-1 is `all`, its default)
MAX_SPEED = 1e6  # `swarm replay --speed`: times the recorded pace


def add_attention_flag(p: argparse.ArgumentParser) -> None:
    p.add_argument("--attention", type=attention_focus, default=-1, metavar="all|off|ID",
                   help="on the map, draw whom each robot (all), robot ID, or nobody (off) "
                        "attends to most (CommAttn robots report it; default all)")


def _output_json(path: str | None, obj: dict[str, Any]) -> None:
    if path:
        from swarm.common.atomic import write_json

        write_json(path, obj)


def run_endpoint(args: argparse.Namespace, zopts: zconfig.ZenohOptions,
                 wait: float = 0.0) -> zconfig.ZenohOptions:
    """Without --connect (or --zenoh-config), the hub of the run of that id started on this
    machine (its run file, as `swarm fault` finds it; waited for up to `wait` seconds); a
    secure run needs --secure."""
    if not zopts.connect and not zopts.config_file:
        from swarm.common.spawn import lookup_run
        from swarm.net.keys import Keys

        zopts.connect = [lookup_run(Keys(args.run_id).run, wait)]
        if not args.secure and zopts.connect[0].startswith("tls/"):  # (a --zenoh-config, as
            raise ConfigError(f"run {args.run_id} is secure: give --secure DIR (the "  # a
                              "recorder's certificate)")  # secure run's own recorder has, is TLS)
    return zopts


def cmd_record(args: argparse.Namespace) -> int:
    """`swarm record`: exit 0 at the run's end; stopped before it, the file is finished all the
    same (footer; the summary line by hand) and the exit is an interrupt's (130)."""
    import logging

    from swarm.net.record.recording import need_mcap
    from swarm.procs.recorder import main as record_main

    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING,
                        stream=sys.stderr, format="%(asctime)s %(name)s %(levelname)s %(message)s")
    need_mcap()
    output_file(args.out, "--out")
    if not 0.01 <= args.flush <= 60:
        raise ConfigError(f"--flush must lie in [0.01, 60] seconds, got {args.flush}")
    check_wait(args.wait)
    deadline = time.monotonic() + args.wait  # for the run to start, then for its world
    zopts = run_endpoint(args, zconfig.from_args(args), args.wait)
    try:
        from swarm.cli.secure import secure_options

        zopts = secure_options(args, zopts, "recorder", args.run_id)
        wait = max(deadline - time.monotonic(), 0.1)
        stats = record_main(args.run_id, args.out, zopts, wait, args.flush, args.wait)
    except TimeoutError as exc:
        raise ConfigError(str(exc)) from None
    # not into a supervisor's log: an interrupted run keeps its logs when one says more than
    # `swarm: interrupted` (the counts are in the file's metadata, the run's result names it)
    if not supervised():
        print(json.dumps({"recording": args.out, **stats}), file=sys.stderr)
    if stats["ended"] == "interrupted":  # the file is whole (footer written), the run was not
        raise KeyboardInterrupt  # (exit 130, as every command stopped by Ctrl-C)
    return 0


def cmd_replay(args: argparse.Namespace) -> int:
    from swarm.studies.replay import load, replay

    if args.verify:  # it re-steps the run: nothing is played, so these would do nothing
        given = [flag for flag, v in (("--speed", args.speed), ("--from", args.from_tick),
                                      ("--until", args.until)) if v is not None]
        given += ["--attention"] if args.attention != ATTN_UNSET else []
        if given:
            raise ConfigError(f"{given[0]} does nothing with --verify (it re-steps the run "
                              "without playing it); drop it or drop --verify")
    args.speed = 1.0 if args.speed is None else args.speed
    args.from_tick = 0 if args.from_tick is None else args.from_tick
    args.attention = -1 if args.attention == ATTN_UNSET else args.attention
    if not 0 <= args.speed <= MAX_SPEED:  # also NaN
        raise ConfigError(f"--speed must lie in [0, {MAX_SPEED:.0f}] times the recorded pace "
                          f"(0: as fast as it goes), got {args.speed:g}")
    if args.from_tick < 0:
        raise ConfigError(f"--from must be a run tick >= 0, got {args.from_tick}")
    if args.until is not None and args.until < args.from_tick:
        raise ConfigError(f"--until {args.until} is before --from {args.from_tick}")
    output_file(args.json)
    rec = load(args.file, partial=args.partial)
    n = rec.record.world.n_robots
    if args.attention is not None and args.attention >= n:  # as `swarm run` refuses it
        raise ConfigError(f"--attention {args.attention}: run {rec.record.run.run_id} has "
                          f"robots 0..{n - 1}")
    span = rec.raw.span()
    if span is None and not args.verify:  # (--verify may still check a result: it says below)
        return _no_tick(rec, "replay")
    first, last = span or (0, rec.last_tick)
    if args.verify and first > 0:
        ep, t = divmod(first, rec.record.world.horizon)
        raise ConfigError(f"{args.file} starts mid-run, at run tick {first} (episode "
                          f"{rec.record.run.first_episode + ep} tick {t}: the recorder joined "
                          "late); --verify re-steps a run from its start, so it needs a "
                          "recording from run tick 0 (swarm run --record FILE)")
    if not args.verify and args.from_tick > last:
        raise ConfigError(f"--from {args.from_tick} is past the end of {args.file} (run ticks "
                          f"{first}..{last})")
    if not args.verify and args.until is not None and args.until < first:
        raise ConfigError(f"--until {args.until} is before the start of {args.file} (run ticks "
                          f"{first}..{last})")
    out, err = _consoles()
    _say_cut(rec, err)
    if first > 0:
        err.print(f"[yellow]recording starts mid-run[/]: at run tick {first} (the recorder "
                  "joined late)", soft_wrap=True)
    if args.verify:
        from swarm.studies.verify import verify

        report = verify(rec)
        div = report.divergence
        checked = ", ".join(f"{v} {k}" for k, v in report.checked.items())
        empty = not report.ticks and not report.checked.get("results")  # (cut at its start)
        summary = {"file": args.file, "run_id": rec.record.run.run_id,
                   "clock": rec.record.run.clock, "ticks": report.ticks, "checked": report.checked,
                   "unreadable": report.unreadable, "notes": report.notes,
                   "damaged": rec.raw.damaged,  # (ok as the exit status: no hole, no void)
                   "ok": div is None and not empty and not rec.raw.damaged,
                   "divergence": None if div is None else vars(div) | {"line": div.line()}}
        _output_json(args.json, summary)
        for note in report.notes:
            err.print(f"note: {note}", soft_wrap=True)
        if div is not None:
            print(f"swarm: verify: {args.file}: {div.line()}", file=sys.stderr)
            return 1
        if empty:
            print(f"swarm: verify: {args.file}: nothing to verify (no complete tick and no "
                  "result in it)", file=sys.stderr)
            return 1
        if rec.raw.damaged:  # (an audit passes no file with a hole in it: cut is one thing)
            print(f"swarm: verify: {args.file}: damaged at {rec.raw.where_bad()}: the "
                  f"{report.ticks} ticks before it are as recorded, what "
                  "follows is unreadable and not verified", file=sys.stderr)
            return 1
        out.print(f"verified {args.file}: run {rec.record.run.run_id} "
                  f"({rec.record.run.policy}, {rec.record.run.clock} clock), {report.ticks} "
                  f"ticks recomputed; {checked}: every one as recorded" + (
                      f"; {report.unreadable} unreadable messages skipped, as the live processes "
                      "dropped them" if report.unreadable else ""), soft_wrap=True)  # (one line)
        return 0
    try:
        view, stats = replay(rec, out, speed=args.speed, from_tick=args.from_tick,
                             until_tick=args.until, attention=args.attention)
    except KeyboardInterrupt:
        return 130
    stats.first_tick = max(stats.first_tick, first)  # the ticks present, not asked for
    res = rec.result or {}
    shown = {k: v for k, v in vars(stats).items() if k != "order"}  # (the replay's own state)
    _output_json(args.json, {"file": args.file, **shown, "elratio": view.elratio,
                             "result": {k: res.get(k) for k in ("elratio_mean", "ticks",
                                                                "completed")}})
    out.print()
    out.print(f"replayed {stats.messages} messages of run {rec.record.run.run_id} (ticks "
              f"{stats.first_tick}..{stats.last_tick}; {counted(stats.bad, 'bad record')} dropped)")
    return 0


def _no_tick(rec: Recording, command: str) -> int:
    """A recording with no tick in it (a run stopped during its start-up): one line, exit
    status 1, nothing written."""
    print(f"swarm: {command}: {rec.path}: nothing to {command} (no tick in it"
          + ("" if rec.raw.complete else "; it is cut before its first") + ")", file=sys.stderr)
    return 1


def _new_dirs(path: str) -> Path | None:
    """The outermost directory of `path` that does not exist yet (None: it exists)."""
    target = Path(path).absolute()
    if target.exists():
        return None
    while not target.parent.exists():
        target = target.parent
    return target


def _say_cut(rec: Any, err: Any) -> None:
    """One line on stderr for a damaged or partial recording (what `--partial` let through)."""
    if rec.raw.damaged:  # (the recorder may well have finished it: say only what is known)
        err.print(f"[yellow]damaged recording[/]: unreadable at {rec.raw.where_bad()}; using "
                  f"the {len(rec.messages)} messages before it (up to run "
                  f"tick {rec.last_tick})", soft_wrap=True)
    elif not rec.raw.complete:
        err.print(f"[yellow]partial recording[/]: the recorder stopped at run tick "
                  f"{rec.last_tick}; using the {len(rec.messages)} messages before the cut",
                  soft_wrap=True)


def cmd_trace(args: argparse.Namespace) -> int:
    import shutil

    from swarm.cli.checks import distinct_paths
    from swarm.studies.replay import load
    from swarm.studies.trace import WRITES, trace

    named_dir(args.out, "--out")  # (before the file is read; Path("") is the working directory)
    if Path(args.out).exists() and not Path(args.out).is_dir():
        raise ConfigError(f"--out {args.out} exists and is not a directory")
    distinct_paths({"the input file": args.file},  # (DIR/links.csv as FILE or --json)
                   {"--json": args.json, **{f"--out's {f}": str(Path(args.out) / f)
                                            for f in WRITES}})
    output_file(args.json)
    rec = load(args.file, partial=args.partial)  # a bad file fails before --out is made
    if rec.raw.span() is None:
        return _no_tick(rec, "trace")
    made = _new_dirs(args.out)
    try:
        output_dir(args.out, "--out")
        res = trace(rec, args.out, _command())
    except BaseException:
        if made is not None:  # a failed trace leaves no folder behind
            shutil.rmtree(made, ignore_errors=True)
        raise
    _output_json(args.json, res)
    out, err = _consoles()
    _say_cut(rec, err)  # (said by replay, not by trace: the README said both)
    for f in res["files"]:
        out.print(f"wrote {f}")
    for note in res["notes"]:
        err.print(f"note: {note}")
    return 0


def add_parsers(sub: Any) -> None:
    """Register `record`, `replay` and `trace` on the `swarm` subparsers."""
    p = sub.add_parser("record", help="record a running swarm's traffic into an MCAP file",
                       description="Join run RUN_ID and write every message of it (raw msgpack "
                                   "and JSON) into FILE until the run ends (Ctrl-C stops it "
                                   "early, the file finished); `swarm run --record "
                                   "FILE` starts this for you. A run started on this machine is "
                                   "found by its id; elsewhere give --connect ENDPOINT.")
    p.add_argument("--run-id", required=True,
                   help="the run to record (without --connect: the `swarm run` of that id on "
                        "this machine)")
    p.add_argument("--out", required=True, metavar="FILE", help="the MCAP file to write")
    p.add_argument("--wait", type=float, default=30.0, metavar="S",
                   help="seconds to wait for a run of this machine to start (it may start "
                        "after the recorder) and for the world (default 30)")
    p.add_argument("--flush", type=float, default=0.5, metavar="S",
                   help="seconds between chunk flushes: what a killed recorder leaves (default "
                        "0.5)")
    p.add_argument("-v", "--verbose", action="store_true", help="log at INFO")
    zconfig.add_arguments(p)
    from swarm.cli.secure import add_secure_flag

    add_secure_flag(p)
    p.set_defaults(func=cmd_record)

    p = sub.add_parser("replay", help="replay a recording on the live dashboard, or --verify it",
                       description="Play FILE (from `swarm run --record`) through the live "
                                   "dashboard, no network needed; --verify re-steps the world "
                                   "(and, in virtual time, the radio) and checks every record.")
    p.add_argument("file", metavar="FILE", help="an MCAP recording")
    p.add_argument("--speed", type=float, default=None, metavar="X",
                   help="x times the recorded pace, in [0, 1e6] (0: as fast as it goes; "
                        "default 1)")
    p.add_argument("--from", dest="from_tick", type=int, default=None, metavar="TICK",
                   help="fast-forward to run tick TICK, then play at --speed")
    p.add_argument("--until", type=int, metavar="TICK", help="stop (the frame stays) after TICK")
    p.add_argument("--verify", action="store_true",
                   help="recompute every status, observation, delivery and the result; print "
                        "the first divergence and exit 1 on one")
    p.add_argument("--partial", action="store_true",
                   help="use a recording cut short (a killed recorder) up to its last chunk")
    p.add_argument("--json", metavar="FILE", help="write what was replayed or verified")
    add_attention_flag(p)
    p.set_defaults(func=cmd_replay, attention=ATTN_UNSET)  # (refused with --verify if given)

    p = sub.add_parser("trace", help="per-link, per-robot and per-kind figures of a recording",
                       description="CSV and PNG of a recording: link delivery matrix, latency "
                                   "and compute-time distributions, bytes per kind, elratio "
                                   "over ticks, mean attention per (receiver, sender distance).")
    p.add_argument("file", metavar="FILE", help="an MCAP recording")
    p.add_argument("--out", required=True, metavar="DIR", help="output directory")
    p.add_argument("--partial", action="store_true",
                   help="use a recording cut short (a killed recorder) up to its last chunk")
    p.add_argument("--json", metavar="FILE", help="write the list of files and counts")
    p.set_defaults(func=cmd_trace)
