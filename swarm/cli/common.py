"""What every `swarm` command shares: the one-line-error parser, the experiment file's tables,
world flags, consoles and progress bars.

Settings come, in increasing precedence, from the dataclass defaults, the TOML experiment file
(`--config FILE`: `[world]` plus one table per subcommand) and the command-line flags. Any bad
value is one line on stderr (`swarm: error: ...`) and exit status 2, never a traceback.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import re
import shlex
import sys
import tempfile
from pathlib import Path
from typing import Any, NoReturn, Self

from swarm.common.atomic import in_place
from swarm.common.report import OutputClosed, printable
from world.config import (
    ConfigError,
    WorldConfig,
    from_dict,
    load_toml,
    parse_size,
    toml_bools,
    with_scaled_blocks,
)

# Top-level tables an experiment file may hold; other subcommands add theirs here.
SECTIONS = ("world", "eval", "bench", "repro", "run", "faults", "train", "learner")
BENCH_TABLES = ("env", "policy", "swarm", "train", "rollout", "record")


class _Parser(argparse.ArgumentParser):
    """ArgumentParser whose usage errors are one line: `swarm: error: ...`, exit 2."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        # a negative value with a unit (`--latency -5ms`) is a value, so it reaches the value's
        # own check (argparse would otherwise take it for an option: "expected one argument")
        self._negative_number_matcher = re.compile(r"^-\d+(\.\d*)?[a-zA-Z/]*$|^-\.\d+$")

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"swarm: error: {message} (see {self.prog} --help)\n")


# ---------------------------------------------------------------------------- configuration


def _range(text: str) -> float:
    """`--comm-range` value: a non-negative number or `inf`."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number or 'inf', got {text!r}") from None
    if math.isnan(value) or value < 0:
        raise argparse.ArgumentTypeError(f"must be >= 0 or 'inf', got {text!r}")
    return value


def file_tables(path: str | None) -> dict[str, Any]:
    """The experiment file's tables (empty without a file); unknown tables are errors."""
    if path is None:
        return {}
    data = load_toml(path)
    for key, value in data.items():
        if key not in SECTIONS:
            hint = " (an experiment file: run it with `swarm experiment FILE`)" \
                if key == "experiment" else ""
            raise ConfigError(f"config file {path}: unknown table [{key}]{hint}; known: "
                              f"{', '.join(SECTIONS)}")
        if not isinstance(value, dict):
            raise ConfigError(f"config file {path}: '{key}' must be a table ([{key}])")
    bench = data.get("bench", {})
    for key, value in bench.items():
        if key not in BENCH_TABLES or not isinstance(value, dict):
            raise ConfigError(f"config file {path}: unknown key bench.{key}; the [bench] table "
                              f"holds only {', '.join(f'[bench.{t}]' for t in BENCH_TABLES)}")
    return data


def merged(cls: type, table: dict[str, Any], flags: dict[str, Any], where: str) -> Any:
    """Dataclass `cls` from the file's `table` overridden by the flags that were given."""
    toml_bools(cls, table, where)  # (the flags' text may say "true"; the file must say true)
    given = {k: v for k, v in flags.items() if v is not None}
    return from_dict(cls, {**table, **given}, where=where)


def _size(text: str) -> tuple[int, int]:
    """`--size` value: HxW."""
    try:
        return parse_size(text)
    except ConfigError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def _world_flags(args: argparse.Namespace) -> dict[str, Any]:
    """WorldConfig fields of this subcommand's world flags (None: not given)."""
    flags = {
        "n_robots": getattr(args, "world_robots", None), "dynamic": getattr(args, "dynamic", None),
        "n_static": getattr(args, "static_blocks", None),
        "n_dynamic": getattr(args, "dynamic_blocks", None),
        "add_every": getattr(args, "world_add_every", None),
        "vision": getattr(args, "vision", None),
        "comm_range": getattr(args, "comm_range", None), "horizon": getattr(args, "horizon", None),
        "explore_mode": "sense" if getattr(args, "sense", None) else None,
    }
    size = getattr(args, "size", None)
    if size is not None:
        flags["height"], flags["width"] = size
    return flags


def world_given(args: argparse.Namespace, tables: dict[str, Any]) -> set[str]:
    """The WorldConfig fields a world flag or the `[world]` table set."""
    return {*tables.get("world", {}), *(k for k, v in _world_flags(args).items() if v is not None)}


def world_config(args: argparse.Namespace, tables: dict[str, Any]) -> WorldConfig:
    """`[world]` of the file overridden by the world flags of this subcommand."""
    flags = _world_flags(args)
    table = dict(tables.get("world", {}))
    size = {k: v for k in ("height", "width")
            if (v := flags.get(k) if flags.get(k) is not None else table.get(k)) is not None}
    for key, n in with_scaled_blocks(size).items():  # another map size: the paper's density
        if key.startswith("n_") and key not in table and flags.get(key) is None:
            flags[key] = n
    world = merged(WorldConfig, table, flags, "[world]")
    if not world.dynamic:  # a flag that would do nothing is a mistake, not a no-op
        for key, flag in (("add_every", "--add-every"), ("n_dynamic", "--dynamic-blocks")):
            if _world_flags(args).get(key) is not None:
                raise ConfigError(f"{flag} has no effect on a static map (--static or "
                                  "[world] dynamic = false); drop it or use --dynamic")
    return world


def add_common(p: argparse.ArgumentParser, results: bool = True) -> None:
    p.add_argument("--seed", type=int, help="seed of maps, spawns, schedules and noise "
                   "(default 0)")
    p.add_argument("--config", metavar="FILE",
                   help="TOML experiment file ([world] + this command's table)")
    if results:
        p.add_argument("--json", metavar="FILE", help="write the results as one JSON object")


def add_world(p: argparse.ArgumentParser, robots: bool = True, schedule: bool = True) -> None:
    g = p.add_argument_group("world (override [world] of --config)")
    if robots:
        g.add_argument("--robots", dest="world_robots", type=int, metavar="N",
                       help="robots N (default 10)")
    if schedule:
        m = g.add_mutually_exclusive_group()
        m.add_argument("--static", dest="dynamic", action="store_false", default=None,
                       help="no dynamic blocks")
        m.add_argument("--dynamic", dest="dynamic", action="store_true", default=None,
                       help="dynamic blocks appear (default)")
        g.add_argument("--add-every", dest="world_add_every", type=int, metavar="M",
                       help="steps between dynamic-block batches (default 3)")
    g.add_argument("--size", type=_size, metavar="HxW",
                   help="map size (default 20x20); block counts scale with the area unless "
                        "given")
    g.add_argument("--static-blocks", type=int, metavar="N",
                   help="static blocks (default 81 on 20x20, scaled by area)")
    if schedule:
        g.add_argument("--dynamic-blocks", type=int, metavar="N",
                       help="dynamic blocks (default 70 on 20x20, scaled by area)")
    g.add_argument("--vision", type=int, metavar="V",
                   help="side of the v x v view (odd, default 5)")
    g.add_argument("--comm-range", type=_range, metavar="R|inf",
                   help="communication range in cells (default 10)")
    g.add_argument("--horizon", type=int, metavar="T", help="mission steps (default 30)")
    g.add_argument("--sense", action="store_true", default=None,
                   help="sense mode: every cell seen is explored (default: visit)")


# ---------------------------------------------------------------------------- progress


class RichProgress:
    """A `ProgressSink` drawing rich progress bars on a (stderr) console."""

    def __init__(self, console: Any) -> None:
        from rich.progress import (
            BarColumn,
            MofNCompleteColumn,
            Progress,
            TextColumn,
            TimeElapsedColumn,
            TimeRemainingColumn,
        )

        self.bar = Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(),
                            TimeElapsedColumn(), TimeRemainingColumn(), console=console)
        self.task: Any = None

    def __enter__(self) -> Self:
        self.bar.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.bar.stop()

    def start(self, label: str, total: int) -> None:
        self.task = self.bar.add_task(label, total=total)

    def advance(self, n: int = 1) -> None:
        self.bar.advance(self.task, n)


def _consoles() -> tuple[Any, Any]:
    """Stdout console for results (120 columns when piped, so tables do not wrap) and stderr
    console for progress."""
    from rich.console import Console  # here: robot processes never draw

    out = Console()
    if not out.is_terminal:
        out = Console(width=max(out.width, 120))
    out.on_broken_pipe = _output_closed  # (rich's own: a silent exit 1, read as a failure)
    return out, Console(stderr=True)


def _output_closed() -> None:
    raise OutputClosed  # (swarm.cli.main: one line, exit 141)


def _command() -> str:
    """The command line as text that writes as UTF-8 (a byte that is none, in a path given as
    an argument, is shown escaped: it crashed the tables' and the curve's "Made by" line)."""
    return printable(shlex.join(["swarm", *sys.argv[1:]]))


def _ints(text: str | None, flag: str) -> tuple[int, ...] | None:
    """'10,25' -> (10, 25); an empty entry or a repeat is a typo (one line naming `flag`), not
    a row to drop or run twice."""
    if text is None:
        return None
    try:
        out = tuple(int(x) for x in text.split(","))
    except ValueError:
        raise ConfigError(f"{flag} expects comma-separated integers, got {text!r}") from None
    if len(set(out)) != len(out):
        raise ConfigError(f"{flag} expects distinct integers, got {text!r}")
    return out


def _names(text: str | None, flag: str) -> tuple[str, ...] | None:
    """'a,b' -> ('a', 'b'); an empty entry or a repeat is refused, as `_ints` does."""
    if text is None:
        return None
    out = tuple(x.strip() for x in text.split(","))
    if not all(out) or len(set(out)) != len(out):
        raise ConfigError(f"{flag} expects distinct comma-separated names, got {text!r}")
    return out



def _checkpoint_pairs(pairs: list[str] | None, flag: str = "--checkpoint") -> dict[str, str] | None:
    if not pairs:
        return None
    out = {}
    for pair in pairs:
        name, sep, path = pair.partition("=")
        if not sep or not name or not path:
            raise ConfigError(f"{flag} wants NAME=FILE, got {pair!r}")
        if name in out:  # (the last was kept without a word)
            times = sum(p.partition("=")[0] == name for p in pairs)
            raise ConfigError(f"{flag} {name}=... given {times} times: give one file per policy")
        out[name] = path
    return out




NAME_MAX = 255  # bytes in one file name (Linux and macOS file systems)
PATH_MAX = 4096  # bytes in a whole path (Linux)


def path_name(path: str | Path, flag: str) -> None:
    """A path the file system can name: one over NAME_MAX bytes in a part or PATH_MAX in all is
    refused in one line, before anything is made (the OS's "File name too long" came mid-run,
    as a traceback during parsing, or once `mkdir -p` had made the parents)."""
    for part in Path(path).parts:
        if len(os.fsencode(part)) > NAME_MAX:
            raise ConfigError(f"{flag} {_short(path)}: the name {_short(part)} is longer than "
                              f"{NAME_MAX} bytes")
    if len(os.fsencode(os.path.abspath(path))) >= PATH_MAX:
        raise ConfigError(f"{flag} {_short(path)}: the path is longer than {PATH_MAX} bytes")


def _short(text: str | Path) -> str:
    """`text` cut to fit an error line."""
    text = str(text)
    return text if len(text) <= 40 else f"{text[:37]}..."


def output_file(path: str | None, flag: str = "--json") -> None:
    """A result file must be writable before the work that produces it starts."""
    if path is None:
        return
    if not str(path).strip():  # (a Path too: `swarm train --out` is one)
        raise ConfigError(f"{flag} wants a file name, got an empty one")
    path_name(path, flag)
    target = Path(path)
    try:
        if target.is_dir():
            raise ConfigError(f"{flag} {path} is a directory, not a file")
        if in_place(target):  # a device, FIFO or /dev/stdout: opened and written, never replaced
            if not os.access(target, os.W_OK):
                raise ConfigError(f"{flag} {path} is not writable")
            return
        parent = target.parent if str(target.parent) else Path(".")
        if not parent.is_dir():
            raise ConfigError(f"{flag} {path}: {parent} " + (
                "is a file, not a directory" if parent.exists() else "does not exist"))
        if target.exists() and not os.access(target, os.W_OK):
            raise ConfigError(f"{flag} {path} is not writable")
        with tempfile.TemporaryFile(dir=parent):  # written beside it, then renamed (atomic.py)
            pass
    except OSError as exc:
        raise ConfigError(f"{flag} {path} is not writable ({exc.strerror or exc})") from None


def named_dir(path: str | Path | None, flag: str) -> None:
    """An empty directory name is refused (Path("") is the working directory): first thing, so
    `--out ''` is never read as "not given" by an `args.out or DEFAULT` further on."""
    if path is not None and not str(path).strip():  # (a Path too: `swarm train --out` is one)
        raise ConfigError(f"{flag} wants a directory, got an empty name")


def output_dir(path: str | None, flag: str, make: bool = True) -> None:
    """A directory a run will write into, made now and probed with a file (permission bits do
    not say it for root or for a special file system such as /proc). `make=False` leaves a
    missing one to the run (made once it is known to start) and probes the nearest folder that
    exists: a path under a file, or where nothing can be made, is refused all the same."""
    if path is None:
        return
    named_dir(path, flag)
    path_name(path, flag)
    target = Path(path)
    try:
        if target.exists() and not target.is_dir():
            raise ConfigError(f"{flag} {path} exists and is not a directory")
        probe = target
        if not make:
            while not probe.exists() and probe != probe.parent:
                probe = probe.parent
            if not probe.is_dir():
                raise ConfigError(f"{flag} {path} is under {probe}, which is not a directory")
        probe.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=probe):
            pass
    except OSError as exc:
        raise ConfigError(f"{flag} {path} is not writable ({exc.strerror or exc})") from None


def add_fault_flags(p: argparse.ArgumentParser, process: bool = True, config: bool = True,
                    live: bool = False) -> None:
    """The fault flags of `swarm run`/`world`/`fault` (process faults too) and `swarm eval`;
    `config`: the command reads `--config` (whose `[faults]` the flags override); `live`:
    `swarm fault`, whose process faults also take a robot alone (at once)."""
    g = p.add_argument_group("faults (override [faults] of --config; see docs/DECISIONS.md)"
                             if config else "faults (see docs/DECISIONS.md)")
    g.add_argument("--latency", metavar="DUR", help="one-way radio latency, e.g. 50ms, 0.2s or "
                   "\"50 ms\" (us, ms, s; a number alone is ms: 50 is 50ms)")
    g.add_argument("--jitter", metavar="DUR", help="extra uniform delay in [0, DUR), e.g. 10ms "
                   "(a number alone is ms)")
    g.add_argument("--loss", metavar="P", help="message loss probability, e.g. 0.1")
    g.add_argument("--bandwidth", metavar="RATE", help="per-robot radio cap, e.g. 2kB/s")
    g.add_argument("--overflow", choices=["queue", "drop", "expire"],
                   help="what the bandwidth cap does with excess messages: queue them "
                        "(default), drop them, or expire them (queue, but never send one "
                        "that would leave the queue after its deadline)")
    g.add_argument("--partition", metavar="GROUPS", help="groups that cannot hear each other, "
                   "e.g. 0-4/5-9; the robots left out form one more group (0 on 4 robots is "
                   "0/1-3)")
    g.add_argument("--compute-ms", type=float, metavar="MS",
                   help="virtual clock: every robot's modelled compute time before it sends "
                        "(per robot: [faults.robot.K] compute)")
    if process:
        for kind, what in (("crash", "SIGKILL"), ("hang", "SIGSTOP"),
                           ("restart", "restart/SIGCONT")):
            g.add_argument(f"--{kind}", action="append",
                           metavar="ROBOT[@TICK]" if live else "ROBOT@TICK",
                           help=f"{what} robot ROBOT at run tick TICK" + (
                               ", or at once with ROBOT alone" if live else "") + " (repeatable)")
    g.add_argument("--fault-seed", type=int, metavar="S",
                   help="seed of the fault draws (default: " + (
                       "the run's --seed)" if live else "the episode seed, --seed)"))


def fault_table(args: argparse.Namespace, tables: dict[str, Any],
                n_robots: int | None = None, whole: bool = True) -> dict[str, Any]:
    """The `[faults]` table of the file overridden by the fault flags given, checked (`whole`:
    the run's faults, not a live change merged onto the ones in force)."""
    from swarm.net.faults import cap_keys, plan_from_table

    table = dict(tables.get("faults", {}))
    if whole:  # (a live change's empty partition lifts the one in force)
        for where, value in (("[faults] partition", table.get("partition")),
                             ("--partition", getattr(args, "partition", None))):
            if value is not None and not str(value).strip():
                raise ConfigError(f"{where} is empty: give the groups (e.g. 0-4/5-9), or leave "
                                  "it out for no partition")
    for key in ("latency", "jitter", "loss", "bandwidth", "overflow", "partition"):
        value = getattr(args, key, None)
        if value is not None:
            table[key] = value
    if getattr(args, "compute_ms", None) is not None:
        ms = args.compute_ms
        if not 0 <= ms < float("inf"):  # (NaN too; said as given, not as 'nanms')
            raise ConfigError(f"--compute-ms must be a number of milliseconds >= 0, got {ms}")
        table["compute"] = f"{ms:.12f}".rstrip("0").rstrip(".") + "ms"  # (1e-05 is no duration)
    for kind in ("crash", "hang", "restart"):
        if getattr(args, kind, None):
            table[kind] = list(getattr(args, kind))
    if getattr(args, "fault_seed", None) is not None:
        table["seed"] = args.fault_seed
    plan = plan_from_table(table, n_robots=n_robots, at_once=not whole)  # one line before any run
    given = ["--overflow"] * (getattr(args, "overflow", None) is not None) + \
        [f"[faults] {k}" for k in cap_keys(table)]
    if whole and given and not plan.capped:  # (accepted, and every run the same as without it)
        raise ConfigError(f"{given[0]} says what a bandwidth cap does; there is no cap (give "
                          "--bandwidth, or a bandwidth in [faults])")
    return table


def training_faults(args: argparse.Namespace, tables: dict[str, Any], given_json: str,
                    n_robots: int) -> dict[str, Any]:
    """`swarm train`'s faults, from the fault flags (or `[faults]`), or else from `--faults
    JSON` (or `[train] faults`; a JSON object, TrainConfig checks), either checked as the flags
    are (an overflow with no cap, an empty partition; process faults, which the batched
    trainer has not: said, then left out). Both given: one line."""
    faults = batched_faults(fault_table(args, tables, n_robots), "training")  # as eval
    if faults and given_json:
        raise ConfigError("faults given twice: --faults JSON (or [train] faults) and the fault "
                          "flags (or [faults]); give one")
    if given_json:
        faults = batched_faults(fault_table(argparse.Namespace(), {"faults": json.loads(
            given_json)}, n_robots), "training")
    return faults


def batched_faults(table: dict[str, Any], what: str) -> dict[str, Any]:
    """`table` without its process faults (crash, hang, restart: the swarm's supervisor kills
    and stops processes; a batched evaluation or training has none), with one warning line on
    stderr when it had any (a config file shared with `swarm run` is a normal use)."""
    from swarm.net.faults import PROCESS_KINDS
    from swarm.net.faults.control import link_table

    given = [k for k in PROCESS_KINDS if table.get(k)]
    if given:
        print(f"swarm: warning: [faults] {', '.join(given)} are the swarm's process faults "
              f"(swarm run); the batched {what} plays without them", file=sys.stderr)
    return link_table(table)


def batched_fault_plan(args: argparse.Namespace, tables: dict[str, Any], world: WorldConfig,
                       seed: int) -> Any:
    """The radio's fault plan for the batched evaluator: `[faults]` and the fault flags, as
    `swarm run` reads them (the fault seed defaults to the episode seed there too), less the
    process faults (see `batched_faults`)."""
    from swarm.net.faults import plan_from_table

    table = batched_faults(fault_table(args, tables, world.n_robots), "evaluation")
    return plan_from_table(table, seed, world.n_robots) if table else None
