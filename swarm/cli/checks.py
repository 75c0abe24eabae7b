"""Checks of `swarm run`, `world`, `robot` and `fault` flags that need more than one flag or the
run's record: a setting that would be silently dropped, or a fault the run can never reach, is
one line and exit 2 before anything is spawned or sent; and, for every command, an output flag
naming one of its inputs or another of its outputs (`check_paths`)."""

from __future__ import annotations

import argparse
import dataclasses
import os
import re
import sys
from pathlib import Path
from typing import Any

from swarm.cli.common import _checkpoint_pairs, file_tables, output_dir, output_file
from swarm.common.atomic import in_place
from swarm.common.policy_spec import build_inference
from swarm.common.spawn import EXIT_INCOMPLETE  # noqa: F401 (the CLI's, from here)
from swarm.procs.runconfig import RunConfig, check_fault_ticks, check_real_clock  # noqa: F401
from world.config import ConfigError, WorldConfig

INPUT_FLAGS = {"file": "the input file", "config": "--config", "spec": "--spec",
               "checkpoint": "--checkpoint", "curve": "--curve", "init": "--init",
               "zenoh_config": "--zenoh-config"}
"""Flags (by argparse dest) of every command that name a file it reads."""
OUTPUT_FLAGS = {"json": "--json", "episodes_csv": "--episodes-csv", "record": "--record",
                "out": "--out", "log_dir": "--log-dir", "learner_out": "--learner-out"}
"""Flags (by argparse dest) of every command that name a file or folder it writes."""
NONEMPTY_FLAGS = {"checkpoint": "--checkpoint", "curve": "--curve", "secure": "--secure"}
"""Flags whose empty value is refused, not read as not given (`learner --checkpoint ''` started
from fresh weights, `bench swarm --secure ''` benchmarked the plain mode alone); the other file
flags say it in their own checks. `train --init ''`, `--model ''`, `--hint-planner ''` and
`--imitate ''` keep their documented meaning: the default, overriding a config file's value."""
TRAIN_FLAGS = ("train_batch", "train_algo", "train_ppo_epochs", "learner_out", "rollout_loss",
               "train_sync")


def distinct_paths(inputs: dict[str, Any], outputs: dict[str, Any]) -> None:
    """An output path that is one of the command's inputs, or another of its outputs, is refused
    in one line before anything runs (`swarm replay run.mcap --json run.mcap` replaced the
    recording with its own summary). Each dict maps a flag to a path, None (not given) or a list
    of paths. Paths compare resolved, and as one file where both exist (a hard link); a device
    or FIFO (/dev/null, /dev/stdout) is written in place, never replaced, so outputs may share
    it."""
    def given(named: dict[str, Any]) -> list[tuple[str, str]]:
        return [(flag, str(p)) for flag, v in named.items()
                for p in (v if isinstance(v, list) else [v]) if p is not None and str(p).strip()]

    def same(a: str, b: str) -> bool:
        try:
            return os.path.samefile(a, b)
        except OSError:  # (one is missing: its name decides)
            return os.path.realpath(a) == os.path.realpath(b)

    seen: list[tuple[str, str]] = []
    for flag, path in given(outputs):
        if in_place(path):
            continue
        for other, was in seen:
            if same(path, was):
                raise ConfigError(f"{other} and {flag} are the same file ({path}): one would "
                                  "overwrite the other; give each its own")
        for other, was in given(inputs):
            if same(path, was):
                raise ConfigError(f"{flag} {path} is also {other}, which this command reads: "
                                  "it would be overwritten; give another file")
        seen.append((flag, path))


FILE_KEYS = {"eval": {"eval": {"checkpoint": "checkpoint", "checkpoints": "checkpoint",
                                "json": "json", "episodes_csv": "episodes_csv"}},
             "repro": {"repro": {"checkpoints": "checkpoint", "json": "json", "out": "out"}},
             "train": {"train": {"init": "init"}},
             "run": {"learner": {"out": "learner_out"}},
             "learner": {"learner": {"checkpoint": "checkpoint", "out": "out"}},
             "bench": {"bench": {"json": "json", "out": "out", "checkpoint": "checkpoint",
                                 "checkpoints": "checkpoint"}}}
"""Per command, the config file's keys (per table) that name a file, and the flag (dest) each
stands for: a key the flag overrides is not read."""


def check_paths(args: argparse.Namespace) -> None:
    """Every command's file flags (INPUT_FLAGS, OUTPUT_FLAGS) and the files its config file
    names (FILE_KEYS) through `distinct_paths`, before the command runs; of a repeatable
    `NAME=FILE` flag, the FILE."""
    def paths(flags: dict[str, str]) -> dict[str, Any]:
        return {flag: [p if Path(p).exists() or "=" not in p else p.partition("=")[2]
                       for p in v] if isinstance(v, list) else v
                for dest, flag in flags.items() if (v := getattr(args, dest, None)) is not None}

    for dest, flag in NONEMPTY_FLAGS.items():
        v = getattr(args, dest, None)
        if any(isinstance(x, str) and not x.strip() for x in (v if isinstance(v, list) else [v])):
            raise ConfigError(f"{flag} is empty: give a value, or leave the flag out")
    inputs, outputs = paths(INPUT_FLAGS), paths(OUTPUT_FLAGS)
    for label, dest, value in _file_keys(args):
        (outputs if dest in OUTPUT_FLAGS else inputs)[label] = value
    distinct_paths(inputs, outputs)


def _file_keys(args: argparse.Namespace) -> list[tuple[str, str, Any]]:
    """(`[table] key`, flag dest, path or paths) of the files the command's config file names
    that no flag overrides; a file that fails to load is left to the command's own error."""
    keys, found = FILE_KEYS.get(getattr(args, "command", None) or "", {}), []
    if not keys or not getattr(args, "config", None):
        return []
    try:
        tables = file_tables(args.config)
    except ConfigError:
        return []
    for name, fields in keys.items():
        table = tables.get(name, {})
        if name == "bench":
            table, name = table.get(getattr(args, "what", ""), {}), f"bench.{args.what}"
        for key, dest in fields.items():
            value = table.get(key) if isinstance(table, dict) else None
            if isinstance(value, dict):  # (NAME = FILE pairs)
                value = [v for v in value.values() if isinstance(v, str)]
            if isinstance(value, (str, list)) and getattr(args, dest, None) is None:
                found.append((f"[{name}] {key}", dest, value))
    return found


def check_clock(args: argparse.Namespace, tables: dict[str, Any], run: RunConfig,
                faults: dict[str, Any]) -> None:
    """A setting of one clock given with the other is refused, never silently dropped: --netns
    runs on the real clock; --watchdog and compute times model the virtual one."""
    netns, file_run = bool(getattr(args, "netns", False)), tables.get("run", {})
    if netns and (getattr(args, "clock", None) or file_run.get("clock")) == "virtual":
        raise ConfigError("--netns runs on the real clock (the kernel decides when a packet "
                          "arrives): drop --clock virtual")
    if netns or run.clock == "real":
        check_real_clock("--netns (the real clock)" if netns else "--clock real",
                         getattr(args, "watchdog", None) is not None or "watchdog" in file_run,
                         faults, run.seed)


def check_by_hand(faults: dict[str, Any]) -> None:
    """`swarm world` by hand runs no robot processes, so it cannot signal them: process faults
    in its `[faults]` are refused (the flags are not even offered)."""
    kinds = [k for k in ("crash", "hang", "restart") if faults.get(k)]
    if kinds:
        raise ConfigError(f"[faults] {', '.join(kinds)}: a world started by hand does not run "
                          "robot processes, so it cannot signal them (swarm run's supervisor "
                          "does; by hand, kill or stop the robot yourself)")


def check_not_played(at_tick: int | None, timed: list[int], now: int, run_id: str) -> None:
    """`swarm fault`: a tick run `run_id` has played (`now`, -1 unknown) is refused, nothing
    sent: `--at-tick` of a link change, or a process fault's ROBOT@TICK (it struck later)."""
    for what, tick in (("--at-tick", at_tick), ("ROBOT@TICK", min(timed, default=None))):
        if tick is not None and tick <= now:
            raise ConfigError(f"{what} {tick}: run {run_id} is at tick {now} already; give a "
                              "later tick (or none: the next); nothing was sent")


def check_training(args: argparse.Namespace, tables: dict[str, Any],
                   run: RunConfig) -> dict[str, Any] | None:
    """`swarm run`'s learner: its `[learner]` and `[train]` tables, every value checked, for a
    run that trains (None for one that does not). Training flags need --train (checked before
    any folder is made); a learner folder that holds a learner already, or `resume`, is refused
    before any spawn (the learner would refuse it: swarm run starts a fresh one)."""
    from policies import check_learned
    from swarm.learn.config import learner_configs

    given = [f"--{k.replace('_', '-')}" for k in TRAIN_FLAGS if getattr(args, k, None)
             is not None]
    if not run.train:
        if given or run.rollout_loss:
            raise ConfigError(f"{(given or ['[run] rollout_loss'])[0]} is a training setting: "
                              "it needs --train")
        return None
    check_learned(run.policy, "--train")
    tables = {**tables, "train": {"batch": 10, **tables.get("train", {})}}
    lc, tc = learner_configs(argparse.Namespace(
        train_batch=args.train_batch, train_algo=args.train_algo,
        train_ppo_epochs=args.train_ppo_epochs), tables)
    hint = "`swarm learner --resume` continues one in a run started by hand"
    if lc.resume:
        raise ConfigError(f"[learner] resume: swarm run starts a fresh learner ({hint})")
    out = args.learner_out or lc.out or (args.log_dir and str(Path(args.log_dir, "learner")))
    if out and (Path(out) / "checkpoint.pt").exists() and not lc.gather_only:
        raise ConfigError(f"learner folder {out} already holds a learner (checkpoint.pt): give "
                          f"a new --learner-out (swarm run starts a fresh learner; {hint})")
    return {"learner": {**dataclasses.asdict(lc), "out": args.learner_out or lc.out},
            "train": dataclasses.asdict(tc)}


def check_policy(run: RunConfig, world: WorldConfig) -> None:
    """The run's policy and its checkpoint (readable, the right policy and shapes), before
    anything starts; `--train` alone starts from fresh weights."""
    if not (run.train and run.checkpoint is None):
        build_inference(run.policy, world, run.checkpoint)


def status_tick(payload: bytes) -> int:
    """The run tick of a world status record (-1 when it is not one)."""
    from swarm.net.messages import K_STATUS, BadMessage, unpack_record

    try:
        tick = unpack_record(payload, K_STATUS).get("run_tick")
    except BadMessage:
        return -1
    return tick if type(tick) is int and 0 <= tick < 2**40 else -1


def stray_checkpoints(checkpoints: dict[str, str], names: list[str], flag: str) -> None:
    """A one-line ConfigError if `--checkpoint NAME=FILE` names a policy not among `names` (those
    `flag` gives), or no policy at all."""
    from policies import LEARNED, REGISTRY

    stray = sorted(set(checkpoints) - set(names))
    if stray:
        what = f"not among {flag} {','.join(names) or '(none)'}" if stray[0] in REGISTRY else \
            f"not a policy (learned ones: {', '.join(sorted(LEARNED))})"
        raise ConfigError(f"--checkpoint {stray[0]}=...: {stray[0]!r} is {what}")


def eval_checkpoints(given: list[str] | None) -> tuple[str | None, dict[str, str] | None]:
    """`--checkpoint FILE` (one policy) or `--checkpoint NAME=FILE` (repeatable): a value whose
    part before `=` is a name (no path) is a pair, unless it is an existing file; anything else
    a file. (A NAME that is no policy is then refused as such, not as a missing file.)"""
    if not given:
        return None, None
    pairs = [g for g in given if re.fullmatch(r"[A-Za-z][\w-]*", g.partition("=")[0])
             and "=" in g and not Path(g).is_file()]
    files = [g for g in given if g not in pairs]
    if len(files) > 1 or (files and pairs):
        raise ConfigError("give one --checkpoint FILE (one policy) or --checkpoint NAME=FILE "
                          "per learned policy")
    return (files[0] if files else None), _checkpoint_pairs(pairs)


_WORLD_ITEMS = ("table1", "table2", "fig4", "fig5", "fig9", "fig10", "fig11", "comm")
REPRO_FLAGS = {  # `swarm repro` flag (its dest) -> the items that use it
    "episodes": ("fig4", "fig5"), "table2_episodes": ("table2",), "robots": ("fig4",),
    "add_every": ("fig5",), "decisions": ("table1",), "curve": ("fig8",),
    "comm_episodes": ("comm",), "comm_policies": ("comm",), "resume": ("comm",),
    "policies": ("table1", "table2", "fig4", "fig5", "fig8", "fig9"),
    "sense": _WORLD_ITEMS, "vision": tuple(i for i in _WORLD_ITEMS if i != "fig9"),
    **dict.fromkeys(("size", "static_blocks", "horizon"), tuple(i for i in _WORLD_ITEMS
                                                                 if i != "comm")),
    "comm_range": tuple(i for i in _WORLD_ITEMS if i not in ("fig9", "comm"))}
_WHY = {"fig8": "it draws training curves", "fig9": "it sweeps vision and comm range itself",
        "fig10": "it studies commattn", "fig11": "it studies commattn",
        "comm": "its conditions set the map size, blocks, horizon and comm range; it takes "
                "--comm-policies"}


def check_repro_flags(items: list[str], args: argparse.Namespace, cfg: Any) -> None:
    """A `swarm repro` flag none of the items uses is one line, not silently ignored (`repro
    fig9 --comm-range 3` made the same figure and recorded the flag in its "Made by" line); so
    is a checkpoint of `cfg` (a `ReproConfig`) for a policy none of them runs."""
    repro_checkpoints(items, cfg)
    for dest, users in REPRO_FLAGS.items():
        if getattr(args, dest, None) is None or set(items) & set(users):
            continue
        why = "; ".join(f"{i}: {_WHY[i]}" for i in items if i in _WHY)
        raise ConfigError(f"--{dest.replace('_', '-')} is not used by {', '.join(items)}"
                          + (f" ({why})" if why else "") + f"; it is for {', '.join(users)}: "
                          "leave it out")


def buildable(names: tuple[str, ...], world: WorldConfig, checkpoints: dict[str, str],
              asked_for: bool) -> tuple[str, ...]:
    """`names` each built once before anything is timed: one that cannot be built is a one-line
    ConfigError, but when the command takes every policy by default (not `asked_for`), a
    plugin that cannot be built is skipped with a warning, as one that does not import."""
    from policies import PLUGINS
    from swarm.common.policy_spec import build_policy

    kept = []
    for name in names:
        try:
            build_policy(name, world, checkpoints.get(name))
        except ConfigError as exc:
            if asked_for or name not in PLUGINS:
                raise
            print(f"swarm: warning: {exc}; skipped", file=sys.stderr)
            continue
        kept.append(name)
    return tuple(kept)


def repro_checkpoints(items: list[str], cfg: Any) -> None:
    """`repro --checkpoint NAME=FILE` (or `[repro] checkpoints`) for a policy none of `items`
    runs is refused, as `eval` refuses one (its Made by line named a checkpoint that played no
    part): fig9 draws CommNet and CommAttn of --policies, fig10 and fig11 study CommAttn, comm
    runs --comm-policies, fig8 draws training curves and runs none."""
    from swarm.studies.fig9 import drawn

    runs = {"fig8": ((), "the policies fig8 runs"), "fig9": (drawn(cfg.policies), "--policies"),
            "fig10": (("commattn",), "fig10's policy"), "fig11": (("commattn",), "fig11's policy"),
            "comm": (cfg.comm_policies, "--comm-policies")}
    names, flags = [], []
    for item in items:
        ran, flag = runs.get(item, (cfg.policies, "--policies"))
        names += [n for n in ran if n not in names]
        flags += [flag] if flag not in flags else []
    stray_checkpoints(cfg.checkpoints, names, flags[0] if len(flags) == 1 else
                      f"the policies {', '.join(items)} run")


RUN_FILES = ("spec.json", "world_result.json", "initial.pt", "zenoh", "learner")
"""What a run writes into its log folder beside each process's `NAME.log`
(`swarm.procs.supervisor`): an output of the run named so was overwritten by it."""


def check_run_outputs(args: argparse.Namespace) -> None:
    """`swarm run`'s outputs, the last of its checks (the folders are made here: a run refused
    by a later check left them behind), the folders first (`--json`/`--record` may go in
    `--log-dir`), and none named as a file the run writes in its log folder (`--json
    D/world.log` was replaced by the world's log)."""
    for flag, path in (("--json", args.json), ("--record", args.record)):
        if args.log_dir and path and Path(path).resolve().parent == Path(args.log_dir).resolve() \
                and (path.endswith(".log") or Path(path).name in RUN_FILES):
            raise ConfigError(f"{flag} {path} is a file the run writes in --log-dir "
                              f"{args.log_dir}: name another")
    folders = {"--log-dir": args.log_dir, "--learner-out": getattr(args, "learner_out", None)}
    for flag, path in folders.items():  # (all probed before any is made)
        output_dir(path, flag, make=False)
    if args.record is not None:  # the package
        from swarm.net.record.recording import need_mcap

        need_mcap()
    made = [Path(p).resolve() for p in folders.values() if p]
    for flag, path in (("--json", args.json), ("--record", args.record)):
        if path and Path(path).resolve().parent not in made:  # (else: once its folder is)
            output_file(path, flag)
    for flag, path in folders.items():
        output_dir(path, flag)
    output_file(args.json)
    output_file(args.record, "--record")


def check_out_and_json(out: str, json_path: str | None) -> None:
    """A folder of outputs (made here) and a JSON summary that may go inside it: the folder is
    made only once a `--json` outside it is known good (a refused one left it made)."""
    output_dir(out, "--out", make=False)
    if json_path and Path(json_path).resolve().parent != Path(out).resolve():
        output_file(json_path)  # (in --out itself: checked once --out is made)
    output_dir(out, "--out")
    output_file(json_path)
