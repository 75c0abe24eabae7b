"""The `swarm` console script: argparse front end over the importable `main`-style functions.

Settings come, in increasing precedence, from the dataclass defaults, the TOML experiment file
(`--config FILE`: `[world]` plus one table per subcommand) and the command-line flags. Any bad
value is one line on stderr (`swarm: error: ...`) and exit status 2, never a traceback.
"""

from __future__ import annotations

import argparse
import math
import shlex
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, NoReturn, Self

from rich.console import Console
from rich.progress import (
    BarColumn,
    MofNCompleteColumn,
    Progress,
    TextColumn,
    TimeElapsedColumn,
    TimeRemainingColumn,
)

from swarm import atomic
from swarm.console import (
    curves_table,
    env_bench_table,
    kv_table,
    eval_table,
    files_table,
    policy_bench_table,
    rollout_bench_table,
    sweep_table,
    table1_table,
    table2_table,
)
from world.config import ConfigError, WorldConfig, from_dict, load_toml

# Top-level tables an experiment file may hold; other subcommands add theirs here.
SECTIONS = ("world", "eval", "bench", "repro", "run", "faults", "train", "learner")
BENCH_TABLES = ("env", "policy", "swarm", "train", "rollout")


class _Parser(argparse.ArgumentParser):
    """ArgumentParser whose usage errors are one line: `swarm: error: ...`, exit 2."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"swarm: error: {message} (see {self.prog} --help)\n")


@dataclass(frozen=True)
class EvalConfig:
    """Options of `swarm eval` (TOML table `[eval]`)."""

    policy: str = "nearest-frontier"
    """Registry name, a comma-separated list, or `all` (every baseline)."""
    checkpoint: str | None = None
    """Checkpoint of a learned policy."""
    episodes: int = 1000
    """Episodes per policy (episode numbers 0 .. episodes-1 of the seed)."""
    seed: int = 0
    """Seed of maps, spawns, block schedules and policy noise."""
    batch: int = 250
    """Episodes stepped at once."""
    greedy: bool = True
    """Greedy actions (false: sample where the policy is stochastic)."""
    json: str | None = None
    """Write the results to this JSON file."""

    def __post_init__(self) -> None:
        if self.episodes < 1:
            raise ConfigError(f"episodes must be >= 1, got {self.episodes}")
        if self.batch < 1:
            raise ConfigError(f"batch must be >= 1, got {self.batch}")


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
            raise ConfigError(f"config file {path}: unknown table [{key}]; known: "
                              f"{', '.join(SECTIONS)}")
        if not isinstance(value, dict):
            raise ConfigError(f"config file {path}: '{key}' must be a table ([{key}])")
    bench = data.get("bench", {})
    for key, value in bench.items():
        if key not in BENCH_TABLES or not isinstance(value, dict):
            raise ConfigError(f"config file {path}: unknown key bench.{key}; the [bench] table "
                              f"holds only [bench.env] and [bench.policy]")
    return data


def merged(cls: type, table: dict[str, Any], flags: dict[str, Any], where: str) -> Any:
    """Dataclass `cls` from the file's `table` overridden by the flags that were given."""
    given = {k: v for k, v in flags.items() if v is not None}
    return from_dict(cls, {**table, **given}, where=where)


def world_config(args: argparse.Namespace, tables: dict[str, Any]) -> WorldConfig:
    """`[world]` of the file overridden by the world flags of this subcommand."""
    dynamic = getattr(args, "dynamic", None)
    sense = getattr(args, "sense", None)
    flags = {
        "n_robots": getattr(args, "world_robots", None), "dynamic": dynamic,
        "add_every": getattr(args, "world_add_every", None), "vision": getattr(args, "vision", None),
        "comm_range": getattr(args, "comm_range", None), "horizon": getattr(args, "horizon", None),
        "explore_mode": "sense" if sense else None,
    }
    return merged(WorldConfig, tables.get("world", {}), flags, "[world]")


def add_common(p: argparse.ArgumentParser, results: bool = True) -> None:
    p.add_argument("--seed", type=int, help="seed of maps, spawns, schedules and noise")
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

    def __init__(self, console: Console) -> None:
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


def _consoles() -> tuple[Console, Console]:
    """Stdout console for results (120 columns when piped, so tables do not wrap) and stderr
    console for progress."""
    out = Console()
    if not out.is_terminal:
        out = Console(width=max(out.width, 120))
    return out, Console(stderr=True)


def _command() -> str:
    return shlex.join(["swarm", *sys.argv[1:]])


# ---------------------------------------------------------------------------- subcommands


def run_eval(world: WorldConfig, cfg: EvalConfig, progress: Any = None,
             faults: Any = None) -> list[dict[str, Any]]:
    """Evaluate each policy of `cfg.policy` on the same episodes; summaries in order."""
    from swarm.bench import NullProgress
    from swarm.evaluate import evaluate
    from swarm.policy_spec import build_policy, effective_checkpoint, resolve_policies

    names = resolve_policies(cfg.policy)
    if cfg.checkpoint is not None and len(names) > 1:
        raise ConfigError("--checkpoint needs a single --policy")
    policies = [build_policy(n, world, cfg.checkpoint) for n in names]  # fail before running
    progress = progress or NullProgress()
    out = []
    for name, policy in zip(names, policies, strict=True):
        progress.start(f"eval {name}", cfg.episodes)
        res = evaluate(world, policy, cfg.seed, cfg.episodes, batch=cfg.batch, greedy=cfg.greedy,
                       on_progress=progress.advance, faults=faults)
        out.append({**res.summary(world), "policy": name,
                    "checkpoint": effective_checkpoint(name, cfg.checkpoint),
                    **({"faults": faults.describe()} if faults is not None else {})})
    return out


def _eval_faults(args: argparse.Namespace, tables: dict[str, Any]) -> Any:
    """Message faults for the batched evaluator: `[faults]` loss/partition/seed and the flags."""
    from swarm.faults import plan_from_table

    table = {k: v for k, v in tables.get("faults", {}).items()
             if k in ("loss", "partition", "seed")}
    for key, flag in (("loss", args.loss), ("partition", args.partition),
                      ("seed", args.fault_seed)):
        if flag is not None:
            table[key] = flag
    return plan_from_table(table) if table else None


def cmd_eval(args: argparse.Namespace) -> int:
    tables = file_tables(args.config)
    world = world_config(args, tables)
    greedy = False if args.sample else None
    cfg = merged(EvalConfig, tables.get("eval", {}),
                 {"policy": args.policy, "checkpoint": args.checkpoint, "episodes": args.episodes,
                  "seed": args.seed, "batch": args.batch, "greedy": greedy, "json": args.json},
                 "[eval]")
    faults = _eval_faults(args, tables)
    out, err = _consoles()
    with RichProgress(err) as progress:
        summaries = run_eval(world, cfg, progress, faults)
    map_kind = f"dynamic (m={world.add_every})" if world.dynamic else "static"
    out.print(eval_table(summaries, f"eval: {world.n_robots} robots, {map_kind} map, "
                                    f"{cfg.episodes} episodes, seed {cfg.seed}"))
    if cfg.json:
        if len(summaries) == 1:
            obj: dict[str, Any] = summaries[0]
        else:
            obj = {"policy": ",".join(s["policy"] for s in summaries), "robots": world.n_robots,
                   "episodes": cfg.episodes, "seed": cfg.seed, "results": summaries}
        atomic.write_json(cfg.json, {**obj, "command": _command()})
        out.print(f"wrote {cfg.json}")
    return 0


def _ints(text: str | None) -> tuple[int, ...] | None:
    if text is None:
        return None
    try:
        return tuple(int(x) for x in text.split(",") if x.strip())
    except ValueError:
        raise ConfigError(f"expected comma-separated integers, got {text!r}") from None


def _names(text: str | None) -> tuple[str, ...] | None:
    return None if text is None else tuple(x.strip() for x in text.split(",") if x.strip())


def cmd_train(args: argparse.Namespace) -> int:
    from swarm import train, train_config

    tables = file_tables(args.config)
    world = world_config(args, tables)
    base = from_dict(train_config.TrainConfig, tables.get("train", {}), "[train]")
    cfg = train_config.from_args(args, base)
    out, _ = _consoles()
    train.main(cfg, world, args.out, resume=args.resume, console=out)
    return 0


def cmd_bench(args: argparse.Namespace) -> int:
    from swarm import bench
    from swarm.policy_spec import build_policy

    tables = file_tables(args.config)
    world = world_config(args, tables)
    table = tables.get("bench", {}).get(args.what, {})
    where = f"[bench.{args.what}]"
    out, err = _consoles()
    if args.what == "env":
        cfg = merged(bench.EnvBenchConfig, table,
                     {"batches": args.batch, "repeats": args.repeats, "episodes": args.episodes,
                      "seed": args.seed, "json": args.json}, where)
        with RichProgress(err) as progress:
            result = bench.bench_env(world, cfg, progress)
        out.print(env_bench_table(result))
    elif args.what == "train":
        from swarm.train import bench_train

        cfg = argparse.Namespace(json=args.json)
        result = bench_train(args.policy or "commattn", batch=args.batch or 288,
                             updates=args.updates or 3, threads=args.threads or 2, world=world,
                             seed=args.seed or 0, workers=args.workers or 1)
        out.print(kv_table("Training speed (median)", result))
    elif args.what == "rollout":
        from swarm.bench_rollout import RolloutBenchConfig, bench_rollout

        cfg = merged(RolloutBenchConfig, table,
                     {"workers": _ints(args.workers_list), "policy": args.policy,
                      "batch": args.batch, "seconds": args.seconds, "repeats": args.repeats,
                      "json": args.json}, where)
        result = bench_rollout(cfg, lambda row: err.print(f"  {row}"))
        out.print(rollout_bench_table(result))
    elif args.what == "swarm":
        from swarm.bench_swarm import SwarmBenchConfig, bench_swarm
        from swarm.console import swarm_bench_table

        cfg = merged(SwarmBenchConfig, table,
                     {"robots": _ints(args.robots_list), "policies": _names(args.policy),
                      "episodes": args.episodes, "seed": args.seed,
                      "checkpoint": args.checkpoint, "json": args.json}, where)
        for name in cfg.policies:
            build_policy(name, world, cfg.checkpoint)
        result = bench_swarm(world, cfg, lambda row: err.print(f"  {row}"))
        out.print(swarm_bench_table(result))
    else:
        cfg = merged(bench.PolicyBenchConfig, table,
                     {"policies": args.policies, "decisions": args.decisions,
                      "warmup": args.warmup, "seed": args.seed, "json": args.json}, where)
        for name in cfg.policies:  # fail on an unloadable policy before timing anything
            build_policy(name, world)
        with RichProgress(err) as progress:
            result = bench.bench_policy(world, cfg, progress)
        out.print(policy_bench_table(result))
    if cfg.json:
        atomic.write_json(cfg.json, {**result, "command": _command()})
        out.print(f"wrote {cfg.json}")
    return 0


def _checkpoint_pairs(pairs: list[str] | None, flag: str = "--checkpoint") -> dict[str, str] | None:
    if not pairs:
        return None
    out = {}
    for pair in pairs:
        name, sep, path = pair.partition("=")
        if not sep or not name or not path:
            raise ConfigError(f"{flag} wants NAME=FILE, got {pair!r}")
        out[name] = path
    return out


def cmd_repro(args: argparse.Namespace) -> int:
    from swarm import repro

    tables = file_tables(args.config)
    world = world_config(args, tables)
    cfg = merged(repro.ReproConfig, tables.get("repro", {}),
                 {"out": args.out, "episodes": args.episodes, "seed": args.seed,
                  "policies": args.policies, "checkpoints": _checkpoint_pairs(args.checkpoint),
                  "robots": args.robots, "add_every": args.add_every,
                  "decisions": args.decisions, "batch": args.batch, "json": args.json,
                  "table2_episodes": args.table2_episodes,
                  "curves": _checkpoint_pairs(args.curve, "--curve")},
                 "[repro]")
    items = repro.expand(args.item)
    out, err = _consoles()
    with RichProgress(err) as progress:
        results = repro.run(items, world, cfg, _command(), progress)
    for item, res in results.items():
        if item == "table1":
            out.print(table1_table(res["rows"]))
        elif item == "table2":
            out.print(table2_table(res["rows"]))
        elif item == "fig8":
            out.print(curves_table(res["rows"]))
        else:
            x = "robots" if item == "fig4" else "add_every"
            title = "Fig. 4 (static map)" if item == "fig4" else "Fig. 5 (dynamic map)"
            out.print(sweep_table(f"{title}: elratio mean ± std", x, res["rows"]))
    out.print(files_table({k: v["files"] for k, v in results.items()}))
    return 0


# ---------------------------------------------------------------------------- parser


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="swarm", description="CommAttn swarm emulator: evaluate, benchmark "
                     "and reproduce the paper's experiments.")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)

    p = sub.add_parser("eval", help="batched in-process evaluation of one or more policies",
                       description="Batched, in-process evaluation; prints a results table.")
    p.add_argument("--policy", help="policy name, comma list or 'all' (default nearest-frontier)")
    p.add_argument("--checkpoint", metavar="FILE", help="checkpoint of a learned policy")
    p.add_argument("--episodes", type=int, metavar="K", help="episodes (default 1000)")
    p.add_argument("--batch", type=int, metavar="B", help="episodes stepped at once (default 250)")
    p.add_argument("--sample", action="store_true", help="sample actions instead of greedy")
    f = p.add_argument_group("message faults (the swarm radio's seeded draws)")
    f.add_argument("--loss", metavar="P", help="message loss probability")
    f.add_argument("--partition", metavar="GROUPS", help="groups that cannot hear each other")
    f.add_argument("--fault-seed", type=int, metavar="S", help="seed of the fault draws")
    add_common(p)
    add_world(p)
    p.set_defaults(func=cmd_eval)

    p = sub.add_parser("bench", help="print throughput / planning-time figures",
                       description="Benchmarks: `env` (world step + view), `policy` (planning).")
    bsub = p.add_subparsers(dest="what", metavar="WHAT", parser_class=_Parser, required=True)
    b = bsub.add_parser("env", help="agent-steps/s of the batched world step + view",
                        description="Agent-steps/s of world.core.step + "
                                    "world.decentral.batch_view.")
    b.add_argument("--batch", metavar="B,B,..", help="batch sizes (default 1,64,1024)")
    b.add_argument("--repeats", type=int, help="timed repeats per batch size (default 5)")
    b.add_argument("--episodes", type=int, help="episodes per repeat (default 2)")
    add_common(b)
    add_world(b)
    b.set_defaults(func=cmd_bench)
    b = bsub.add_parser("policy", help="planning ms per decision of all N robots",
                        description="Planning ms per team decision (G=1, every robot deciding).")
    b.add_argument("--policies", metavar="A,B,..", help="policies (default: every registered one)")
    b.add_argument("--decisions", type=int, metavar="K",
                   help="timed decisions per policy (default 150)")
    b.add_argument("--warmup", type=int, metavar="E", help="untimed warm-up episodes (default 1)")
    add_common(b)
    add_world(b)
    b.set_defaults(func=cmd_bench)
    b = bsub.add_parser("train", help="seconds per REINFORCE update of a learned policy",
                        description="One update = rollout of --batch episodes (30 steps, N "
                                    "robots) + the REINFORCE step; median over --updates.")
    b.add_argument("--policy", help="learned policy (default commattn)")
    b.add_argument("--batch", type=int, help="episodes per update (default 288)")
    b.add_argument("--updates", type=int, help="timed updates after one warm-up (default 3)")
    b.add_argument("--threads", type=int, help="torch threads per process (default 2)")
    b.add_argument("--workers", type=int, help="training processes (default 1; see swarm train)")
    add_common(b)
    add_world(b)
    b.set_defaults(func=cmd_bench)
    b = bsub.add_parser("rollout", help="episodes/s a learner gathers from K rollout workers",
                        description="A gather-only learner (router) and K rollout-worker "
                                    "processes over Zenoh on loopback, per K in --workers.")
    b.add_argument("--workers", dest="workers_list", metavar="K,K,..",
                   help="worker counts (default 1,2)")
    b.add_argument("--policy", help="learned policy (default commattn)")
    b.add_argument("--batch", type=int, help="episodes per worker batch (default 16)")
    b.add_argument("--seconds", type=float, help="measuring window (default 10)")
    b.add_argument("--repeats", type=int, help="windows per count (default 3)")
    add_common(b)
    b.set_defaults(func=cmd_bench)
    b = bsub.add_parser("swarm", help="ticks/s, startup s and RSS per robot of real swarm runs",
                        description="Runs the distributed swarm (real processes, Zenoh on "
                                    "loopback) per team size and policy; prints the figures.")
    b.add_argument("--robots", dest="robots_list", metavar="N,N,..",
                   help="team sizes (default 10,25,50)")
    b.add_argument("--policy", metavar="A,B,..", help="policies (default nearest-frontier)")
    b.add_argument("--checkpoint", metavar="FILE", help="checkpoint of a learned policy")
    b.add_argument("--episodes", type=int, help="episodes per run (default 5)")
    add_common(b)
    add_world(b, robots=False)
    b.set_defaults(func=cmd_bench)

    p = sub.add_parser("repro", help="reproduce a paper item: table1, table2, fig4, fig5, fig8 "
                                     "or all",
                       description="Reproduce Table 1, Table 2, Fig. 4, Fig. 5 or Fig. 8: writes "
                                   "ITEM.csv, .md, .png and .json into --out. Learned policies "
                                   "use the shipped checkpoints/NAME.pt unless --checkpoint.")
    p.add_argument("item", metavar="ITEM", help="table1, table2, fig4, fig5, fig8 or all")
    p.add_argument("--out", metavar="DIR", help="output directory (required)")
    p.add_argument("--episodes", type=int, metavar="K", help="episodes per point (default 200)")
    p.add_argument("--policies", metavar="A,B,..",
                   help="policies (default: the four learned, three frontier and random)")
    p.add_argument("--table2-episodes", type=int, metavar="K",
                   help="Table 2 held-out episodes per policy (default 1000)")
    p.add_argument("--checkpoint", action="append", metavar="NAME=FILE",
                   help="checkpoint of a learned policy (repeatable)")
    p.add_argument("--curve", action="append", metavar="NAME=FILE",
                   help="Fig. 8 training-curve CSV of a learned policy (repeatable; default "
                        "checkpoints/NAME_curve.csv)")
    p.add_argument("--robots", metavar="N,N,..", help="Fig. 4 team sizes (default 2,4,6,8,10,12)")
    p.add_argument("--add-every", metavar="M,M,..", help="Fig. 5 periods (default 1,2,3,4,5,6,9)")
    p.add_argument("--decisions", type=int, metavar="K", help="Table 1 decisions (default 150)")
    p.add_argument("--batch", type=int, metavar="B", help="episodes stepped at once (default 250)")
    add_common(p)
    add_world(p, robots=False, schedule=False)
    p.set_defaults(func=cmd_repro)

    p = sub.add_parser("train", help="train a learned policy with REINFORCE (batched)",
                       description="REINFORCE with the state-specific baseline; checkpoint "
                                   "every epoch; --resume continues exactly.")
    add_common(p, results=False)
    add_world(p)
    from swarm.train_config import add_arguments as add_train_arguments

    add_train_arguments(p)
    p.set_defaults(func=cmd_train)

    from swarm.procs_cli import add_parsers  # run, world, robot: the distributed swarm

    add_parsers(sub, add_common, add_world)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the `swarm` console script; returns the exit status."""
    parser = build_parser()
    args = parser.parse_args(argv)
    if getattr(args, "func", None) is None:
        parser.print_help(sys.stderr)
        return 2
    try:
        return args.func(args)
    except ConfigError as exc:
        print(f"swarm: error: {' '.join(str(exc).split())}", file=sys.stderr)
        return 2
    except OSError as exc:
        print(f"swarm: error: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("swarm: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
