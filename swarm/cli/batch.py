"""The batched commands: `swarm eval`, `swarm train`, `swarm bench`, `swarm repro`, in-process
but for `swarm bench swarm|rollout|record`, which time real swarm processes."""

from __future__ import annotations

import argparse
import dataclasses
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from policies import BASELINES
from swarm.bench.train import TrainBenchConfig
from swarm.cli.checks import (
    buildable,
    check_out_and_json,
    check_repro_flags,
    eval_checkpoints,
    stray_checkpoints,
)
from swarm.cli.common import (
    RichProgress,
    _checkpoint_pairs,
    _command,
    _consoles,
    _ints,
    _names,
    _Parser,
    add_common,
    add_fault_flags,
    add_world,
    batched_fault_plan,
    file_tables,
    merged,
    output_dir,
    output_file,
    training_faults,
    world_config,
    world_given,
)
from swarm.common import atomic
from swarm.common.flags import add_flags, given
from swarm.common.report import counted, csv_text, paired, provenance
from world.config import (
    ConfigError,
    WorldConfig,
    check_count,
    check_seed,
    from_dict,
    to_dict,
    toml_bools,
)


@dataclass(frozen=True)
class EvalConfig:
    """Options of `swarm eval` (TOML table `[eval]`)."""

    policy: str = "nearest-frontier"
    """Registry name, a comma-separated list, or `all` (every baseline)."""
    checkpoint: str | None = None
    """Checkpoint of the one learned policy evaluated."""
    checkpoints: dict[str, str] = dataclasses.field(default_factory=dict)
    """Checkpoint per learned policy (`--checkpoint NAME=FILE`), for several policies at once."""
    episodes: int = 1000
    """Episodes per policy (episode numbers 0 .. episodes-1 of the seed)."""
    seed: int = 0
    """Seed of maps, spawns, block schedules and policy noise."""
    batch: int = 250
    """Episodes stepped at once."""
    greedy: bool = True
    """Greedy actions (false: sample where the policy is stochastic)."""
    tick_timeout: float = 2.0
    """The tick's virtual length in seconds (message deadlines under faults, as `swarm run`)."""
    json: str | None = None
    """Write the results to this JSON file."""
    episodes_csv: str | None = None
    """Write every policy's per-episode metrics to this CSV file (paired analyses)."""

    def __post_init__(self) -> None:
        check_seed(self.seed)
        if not isinstance(self.checkpoints, dict) or not all(
                isinstance(k, str) and isinstance(v, str) for k, v in self.checkpoints.items()):
            raise ConfigError("checkpoints must map policy names to file names")
        if self.checkpoint is not None and self.checkpoints:
            raise ConfigError("give --checkpoint FILE (one policy) or --checkpoint NAME=FILE, "
                              "not both")
        check_count(self.episodes, "episodes")  # (10^400 ran on, its progress bar broke)
        check_count(self.batch, "batch")  # (evaluate steps min(batch, episodes) at once)
        if not 1e-3 <= self.tick_timeout <= 3600:  # also NaN
            raise ConfigError(f"tick_timeout must lie in [0.001, 3600], got {self.tick_timeout}")


# ---------------------------------------------------------------------------- subcommands


def eval_policies(world: WorldConfig, cfg: EvalConfig) -> list[tuple[str, Any]]:
    """(label, built policy) per `labelled_policies(cfg.policy)`; any bad input fails here."""
    from swarm.common.policy_spec import build_policy, labelled_policies

    runs = labelled_policies(cfg.policy)
    if cfg.checkpoint is not None and len(runs) > 1:
        raise ConfigError("--checkpoint FILE needs a single --policy; name each policy's "
                          "checkpoint with --checkpoint NAME=FILE")
    stray_checkpoints(cfg.checkpoints, [label for label, _ in runs], "--policy")
    return [(label, build_policy(n, world, checkpoint_of(cfg, label))) for label, n in runs]


def checkpoint_of(cfg: EvalConfig, name: str) -> str | None:
    """The checkpoint given for policy `name` (None: the shipped one, if learned)."""
    return cfg.checkpoints.get(name, cfg.checkpoint)


def run_eval(world: WorldConfig, cfg: EvalConfig, progress: Any = None,
             faults: Any = None, built: list[tuple[str, Any]] | None = None
             ) -> list[dict[str, Any]]:
    """Evaluate each policy of `cfg.policy` on the same episodes; summaries in order."""
    from swarm.bench.micro import NullProgress
    from swarm.common.policy_spec import effective_checkpoint, labelled_policies, shown
    from swarm.learn.evaluate import evaluate

    built, runs = built or eval_policies(world, cfg), dict(labelled_policies(cfg.policy))
    names, policies = [n for n, _ in built], [p for _, p in built]
    progress = progress or NullProgress()
    out, results = [], []
    for name, policy in zip(names, policies, strict=True):
        progress.start(f"eval {name}", cfg.episodes)
        res = evaluate(world, policy, cfg.seed, cfg.episodes, batch=cfg.batch, greedy=cfg.greedy,
                       on_progress=progress.advance, faults=faults, tick_s=cfg.tick_timeout)
        results.append(res)
        out.append({**res.summary(world), "policy": name, **({"runs": runs[name]} if runs[name]
                    != name else {}), "checkpoint": shown(effective_checkpoint(
                        runs[name], checkpoint_of(cfg, name))),
                    "decentralized": bool(policy.decentralized),
                    **({"faults": faults.describe()} if faults is not None else {})})
        if len(out) > 1:  # the same episodes: each policy against the first, episode by episode
            mean, se = paired(res.elratio, results[0].elratio)
            out[-1]["elratio_paired"] = {"vs": names[0], "mean": mean, "se": se}
    if cfg.episodes_csv:  # every (policy, episode) row behind the summaries
        atomic.write_text(cfg.episodes_csv, csv_text([
            row for name, res in zip(names, results, strict=True) for row in res.rows(name)]))
    return out


def cmd_eval(args: argparse.Namespace) -> int:
    from swarm.cli.console import eval_table

    tables = file_tables(args.config)
    world = world_config(args, tables)
    greedy = False if args.sample else None
    single, pairs = eval_checkpoints(args.checkpoint)
    cfg = merged(EvalConfig, tables.get("eval", {}),
                 {"policy": args.policy, "checkpoint": single, "checkpoints": pairs,
                  "episodes": args.episodes, "seed": args.seed, "batch": args.batch,
                  "greedy": greedy, "json": args.json, "tick_timeout": args.tick_timeout,
                  "episodes_csv": args.episodes_csv},
                 "[eval]")
    faults = batched_fault_plan(args, tables, world, cfg.seed)
    built = eval_policies(world, cfg)  # every bad input fails before the progress bar
    output_file(cfg.json)
    output_file(cfg.episodes_csv, "--episodes-csv")
    out, err = _consoles()
    with RichProgress(err) as progress:
        summaries = run_eval(world, cfg, progress, faults, built)
    map_kind = f"dynamic (m={world.add_every})" if world.dynamic else "static"
    shown_faults = "; ".join(faults.describe()) if faults is not None else ""
    out.print(eval_table(summaries, f"eval: {world.n_robots} robots, {map_kind} map, "
                                    f"{counted(cfg.episodes, 'episode')}, seed {cfg.seed}"
                                    + (f"; faults: {shown_faults}" if shown_faults else ""),
                         out.width))
    if cfg.json:
        if len(summaries) == 1:
            obj: dict[str, Any] = summaries[0]
        else:
            obj = {"policy": ",".join(s["policy"] for s in summaries), "robots": world.n_robots,
                   "episodes": cfg.episodes, "seed": cfg.seed, "results": summaries}
        made = {"greedy": cfg.greedy, "tick_timeout": cfg.tick_timeout, "world": to_dict(world),
                "faults": shown_faults or None, "fault_plan": faults and faults.to_record()}
        atomic.write_json(cfg.json, {**obj, **made, "command": _command(),
                                     "provenance": provenance()})
        out.print(f"wrote {cfg.json}")
    return 0


def cmd_train(args: argparse.Namespace) -> int:
    from swarm.learn import config as train_config

    tables = file_tables(args.config)
    world = world_config(args, tables)
    toml_bools(train_config.TrainConfig, tables.get("train", {}), "[train]")
    base = from_dict(train_config.TrainConfig, tables.get("train", {}), "[train]")
    cfg = train_config.from_args(args, base)
    faults = training_faults(args, tables, cfg.faults, world.n_robots)
    cfg = dataclasses.replace(cfg, faults=json.dumps(faults) if faults else "")
    asked = {*tables.get("train", {}), *given(train_config.TrainConfig, args),
             *(["faults"] if faults else [])}  # what --resume checks against the checkpoint
    ckpt = Path(args.out) / "checkpoint.pt"
    if args.resume and not ckpt.is_file():  # (a mistyped --out started a fresh run)
        raise ConfigError(f"--resume: {ckpt} does not exist, nothing to resume (without "
                          "--resume a new run starts there)")
    output_dir(args.out, "--out", make=False)  # (a path under a file failed once running)
    if args.resume:  # a refused resume costs no torch import
        from policies.checkpoint import read_checkpoint

        train_config.resume_point(read_checkpoint(ckpt), cfg, asked, world,
                                  world_given(args, tables), str(args.out))
    from swarm.learn import trainer as train

    out, _ = _consoles()
    train.main(cfg, world, args.out, resume=args.resume, console=out, given=asked,
               world_given=world_given(args, tables))
    return 0


def cmd_bench(args: argparse.Namespace) -> int:
    from swarm.bench import micro as bench
    from swarm.cli.console import env_bench_table, kv_table, policy_bench_table, rollout_bench_table
    from swarm.common.policy_spec import build_policy, shown

    tables = file_tables(args.config)
    world = world_config(args, tables)
    table = tables.get("bench", {}).get(args.what, {})
    where = f"[bench.{args.what}]"
    # where the figures go, checked before the benchmark runs (a bad path lost them at the end)
    json_flag = getattr(args, "json", None)  # ('' is a name, refused: not "the table's")
    output_file(json_flag if json_flag is not None else table.get("json"))
    if args.what == "record" and (getattr(args, "out", None) or table.get("out")):
        out_path = Path(args.out or table["out"])
        if out_path.exists() and not out_path.is_dir():
            raise ConfigError(f"--out {out_path} is a file, not a directory")
    out, err = _consoles()
    if args.what == "env":
        cfg = merged(bench.EnvBenchConfig, table,
                     {"batches": args.batch, "repeats": args.repeats, "episodes": args.episodes,
                      "seed": args.seed, "json": args.json}, where)
        with RichProgress(err) as progress:
            result = bench.bench_env(world, cfg, progress)
        out.print(env_bench_table(result))
    elif args.what == "train":
        from swarm.bench.train import TrainBenchConfig, bench_train

        cfg = merged(TrainBenchConfig, table, given(TrainBenchConfig, args), where)
        result = bench_train(cfg.policy, batch=cfg.batch, updates=cfg.updates,
                             threads=cfg.threads, world=world, seed=cfg.seed, workers=cfg.workers)
        out.print(kv_table("Training speed (median)", result))
    elif args.what == "rollout":
        from swarm.bench.rollout import RolloutBenchConfig, bench_rollout

        cfg = merged(RolloutBenchConfig, table,
                     {"workers": _ints(args.workers_list, "--workers"), "policy": args.policy,
                      "batch": args.batch, "seconds": args.seconds, "repeats": args.repeats,
                      "json": args.json}, where)
        result = bench_rollout(cfg, lambda row: err.print(_row_line(row)))
        out.print(rollout_bench_table(result))
    elif args.what == "record":
        from swarm.bench.record import RecordBenchConfig, bench_record

        cfg = merged(RecordBenchConfig, table,
                     {"policy": args.policy, "checkpoint": args.checkpoint,
                      "episodes": args.episodes, "pairs": args.pairs, "seed": args.seed,
                      "out": args.out, "json": args.json}, where)
        build_policy(cfg.policy, world, cfg.checkpoint)
        output_dir(cfg.out, "--out", make=False)  # (a path under a file: one line, exit 2)
        result = bench_record(world, cfg, lambda row: err.print(_row_line(row)))
        out.print(kv_table("Recording cost (medians of interleaved pairs)",
                           {k: v for k, v in result.items() if k != "rows"}))
    elif args.what == "swarm":
        from swarm.bench.swarm import SwarmBenchConfig, bench_swarm
        from swarm.cli.console import swarm_bench_table

        cfg = merged(SwarmBenchConfig, table,
                     {"robots": _ints(args.robots_list, "--robots"),
                      "policies": _names(args.policy, "--policy"),
                      "episodes": args.episodes, "seed": args.seed,
                      "checkpoint": args.checkpoint, "json": args.json,
                      "repeats": args.repeats, "delivery": args.delivery,
                      "hosts": args.hosts, "secure": args.secure}, where)
        for name in cfg.policies:
            build_policy(name, world, cfg.checkpoint)
        result = bench_swarm(world, cfg, lambda row: err.print(_row_line(row)))
        out.print(swarm_bench_table(result))
    else:
        cfg = merged(bench.PolicyBenchConfig, table,
                     {"policies": args.policies, "decisions": args.decisions,
                      "warmup": args.warmup, "seed": args.seed, "json": args.json,
                      "one_robot": args.one_robot}, where)
        ckpts = _checkpoint_pairs(args.checkpoint) or {}
        stray_checkpoints(ckpts, list(cfg.policies), "--policies")
        asked_for = args.policies is not None or "policies" in table
        cfg = dataclasses.replace(cfg, policies=buildable(cfg.policies, world, ckpts, asked_for))
        with RichProgress(err) as progress:
            result = bench.bench_policy(world, cfg, progress, ckpts,
                                        skip_failing_plugins=not asked_for)
        result["checkpoints"] = {n: shown(c) for n, c in ckpts.items()}
        out.print(policy_bench_table(result))
    if cfg.json:
        atomic.write_json(cfg.json, {**result, "command": _command(), "provenance": provenance()})
        out.print(f"wrote {cfg.json}")
    return 0


def _row_line(row: dict[str, Any]) -> str:
    """One finished row of a long benchmark as a progress line: its scalar figures."""
    parts = [f"{k} {v:.4g}" if isinstance(v, float) else f"{k} {v}"
             for k, v in row.items() if isinstance(v, (int, float, str))]
    return "  " + ", ".join(parts)


def cmd_repro(args: argparse.Namespace) -> int:
    from swarm.cli.console import curves_table, files_table, sweep_table, table1_table, table2_table
    from swarm.studies import repro

    tables = file_tables(args.config)
    world = world_config(args, tables)
    flags = {k: getattr(args, k) for k in (
        "out", "episodes", "seed", "policies", "robots", "add_every", "decisions", "batch", "json",
        "comm_policies", "table2_episodes", "comm_episodes", "resume")}
    flags.update(checkpoints=_checkpoint_pairs(args.checkpoint),
                 curves=_checkpoint_pairs(args.curve, "--curve"))
    cfg = merged(repro.ReproConfig, tables.get("repro", {}), flags, "[repro]")
    # every check before the progress display (whose closing would print a blank line)
    items = repro.prepare(repro.expand(args.item), world, cfg)
    check_repro_flags(items, args, cfg)  # (after prepare: `all` drops items it cannot make)
    check_out_and_json(cfg.out, cfg.json)  # before the work, which can take hours
    out, err = _consoles()
    with RichProgress(err) as progress:
        results = repro.run(items, world, cfg, _command(), progress, prepared=True)
    for item, res in results.items():
        if item == "table1":
            out.print(table1_table(res["rows"]))
        elif item == "table2":
            out.print(table2_table(res["rows"]))
        elif item == "fig8":
            out.print(curves_table(res["rows"]))
        elif item not in ("fig9", "fig10", "fig11", "comm"):  # (theirs: the files below)
            x, title = ("robots", "Fig. 4 (static map)") if item == "fig4" else \
                ("add_every", "Fig. 5 (dynamic map)")
            out.print(sweep_table(f"{title}: elratio mean ± std", x, res["rows"]))
    out.print(files_table({k: v["files"] for k, v in results.items()}))
    return 0


def add_parsers(sub: Any) -> None:
    """Register `eval`, `bench`, `repro` and `train` on the `swarm` subparsers."""
    p = sub.add_parser("eval", help="batched in-process evaluation of one or more policies")
    p.add_argument("--policy", help="policy name, comma list or 'all' (the four baselines: "
                   f"{', '.join(BASELINES)}; default nearest-frontier); LABEL=NAME runs NAME "
                   "under a label, e.g. commattn,mine=commattn --checkpoint mine=FILE")
    p.add_argument("--checkpoint", action="append", metavar="FILE|NAME=FILE",
                   help="checkpoint of the learned policy, or NAME=FILE per learned policy "
                        "(repeatable; default: the shipped one)")
    p.add_argument("--episodes", type=int, metavar="K", help="episodes (default 1000)")
    p.add_argument("--episodes-csv", metavar="FILE", help="also write every episode's metrics "
                   "per policy (reward: episode return per robot; columns: README)")
    p.add_argument("--batch", type=int, metavar="B", help="episodes stepped at once (default 250)")
    p.add_argument("--sample", action="store_true", help="sample actions instead of greedy")
    p.add_argument("--tick-timeout", type=float, metavar="S",
                   help="the tick's virtual length, as in swarm run (default 2)")
    add_fault_flags(p, process=False)
    add_common(p)
    add_world(p)
    p.set_defaults(func=cmd_eval)

    p = sub.add_parser("bench", help="print throughput / planning-time figures",
                       description="Benchmarks that print figures: `env` (world step + view), "
                                   "`policy` (planning time), `train` (update speed), `rollout` "
                                   "(rollout workers over Zenoh), `swarm` (real processes: "
                                   "ticks/s, memory, CPU, where a tick goes), `record` "
                                   "(recording cost).")
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
    b.add_argument("--one-robot", action="store_true", default=None,
                   help="time one robot's decision as a robot process makes it (numpy networks, "
                        "its own view; chained: prepare, then decode with its predecessor's "
                        "message) instead of the team's")
    b.add_argument("--checkpoint", action="append", metavar="NAME=FILE",
                   help="checkpoint of a learned policy (repeatable; default: the shipped one)")
    add_common(b)
    add_world(b)
    b.set_defaults(func=cmd_bench)
    b = bsub.add_parser("train", help="seconds per REINFORCE update of a learned policy",
                        description="One update = rollout of --batch episodes (30 steps, N "
                                    "robots) + the REINFORCE step; median over --updates.")
    add_common(b)
    add_flags(b, TrainBenchConfig)
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
    b = bsub.add_parser("record", help="ticks/s of swarm runs with and without --record",
                        description="Pairs of the same headless swarm run, plain and recorded, "
                                    "interleaved; medians of ticks/s and CPU ms per tick.")
    b.add_argument("--policy", help="policy (default nearest-frontier)")
    b.add_argument("--checkpoint", metavar="FILE", help="checkpoint of a learned policy")
    b.add_argument("--episodes", type=int, help="episodes per run (default 3)")
    b.add_argument("--pairs", type=int, help="(plain, recorded) pairs (default 5)")
    b.add_argument("--out", metavar="DIR", help="keep the recordings here (default: a temporary "
                                                "folder, removed at the end)")
    add_common(b)
    add_world(b)
    b.set_defaults(func=cmd_bench)
    b = bsub.add_parser("swarm", help="ticks/s, startup s and RSS per robot of real swarm runs",
                        description="Runs the distributed swarm (real processes, Zenoh on "
                                    "loopback) per team size and policy; prints the figures.")
    b.add_argument("--robots", dest="robots_list", metavar="N,N,..",
                   help="team sizes (default 10,25,50)")
    b.add_argument("--policy", metavar="A,B,..", help="policies (default nearest-frontier)")
    b.add_argument("--checkpoint", metavar="FILE", help="checkpoint of a learned policy")
    b.add_argument("--episodes", type=int, help="episodes per run (default 5)")
    b.add_argument("--repeats", type=int, metavar="K",
                   help="interleaved rounds of every run; medians over rounds, and each "
                        "policy's per-round speed ratio to the first (default 1)")
    b.add_argument("--delivery", choices=["radio", "direct"],
                   help="who delivers robot-to-robot messages (default radio)")
    b.add_argument("--hosts", type=int, metavar="K", help="emulated hosts (root; default 0)")
    b.add_argument("--secure", metavar="DIR",
                   help="also run each with --secure DIR (interleaved; listed as POLICY+secure)")
    add_common(b)
    add_world(b, robots=False)
    b.set_defaults(func=cmd_bench)

    p = sub.add_parser("repro", help="reproduce a paper item: table1, table2, fig4, fig5, fig8, "
                                     "fig9, fig10, fig11, comm or all",
                       description="Reproduce the paper's Table 1, Table 2, Fig. 4, 5, 8, 9, 10, "
                                   "11 or where communication matters (comm): writes ITEM.csv, "
                                   ".md, .png and .json into --out (Fig. 10 and 11: their CSV "
                                   "and PNG and a scores or by-neighbours table). Learned policies "
                                   "use the shipped checkpoints/NAME.pt unless --checkpoint.")
    p.add_argument("item", metavar="ITEM",
                   help="table1, table2, fig4, fig5, fig8, fig9, fig10, fig11, comm or all")
    p.add_argument("--out", metavar="DIR", help="output directory (required)")
    p.add_argument("--episodes", type=int, metavar="K",
                   help="Fig. 4 and Fig. 5 episodes per point (default 200; the other items "
                        "have their own: --table2-episodes, --comm-episodes, and [repro] "
                        "fig9_episodes, fig10_episodes, fig11_episodes in --config)")
    p.add_argument("--policies", metavar="A,B,..",
                   help="policies (default: the four learned, three frontier and random; "
                        "Table 2 then adds team-beam, chain-plan, central and oracle; fig9 draws "
                        "commnet and commattn; comm takes --comm-policies)")
    p.add_argument("--table2-episodes", type=int, metavar="K",
                   help="Table 2 held-out episodes per policy (default 1000)")
    p.add_argument("--comm-episodes", type=int, metavar="K",
                   help="comm: held-out episodes per policy and condition (default 200)")
    p.add_argument("--comm-policies", metavar="A,B,..",
                   help="comm: policies compared, the first paired against the others "
                        "(default commattn,coordinated-frontier,central)")
    p.add_argument("--checkpoint", action="append", metavar="NAME=FILE",
                   help="checkpoint of a learned policy (repeatable)")
    p.add_argument("--curve", action="append", metavar="NAME=FILE",
                   help="Fig. 8 training-curve CSV of a learned policy (repeatable; default "
                        "checkpoints/NAME_curve.csv; NAME:TAG=FILE draws one more of NAME)")
    p.add_argument("--robots", metavar="N,N,..", help="Fig. 4 team sizes (default 2,4,6,8,10,12)")
    p.add_argument("--add-every", metavar="M,M,..", help="Fig. 5 periods (default 1,2,3,4,5,6,9)")
    p.add_argument("--decisions", type=int, metavar="K", help="Table 1 decisions (default 150)")
    p.add_argument("--batch", type=int, metavar="B", help="episodes stepped at once (default 250)")
    p.add_argument("--resume", action="store_true", default=None,
                   help="comm: go on from an interrupted comm's cells in --out (same settings)")
    add_common(p)
    add_world(p, robots=False, schedule=False)
    p.set_defaults(func=cmd_repro)

    p = sub.add_parser("train", help="train a learned policy with REINFORCE (batched)",
                       description="REINFORCE with the state-specific baseline; checkpoint "
                                   "every epoch; --resume continues exactly.")
    add_common(p, results=False)
    add_world(p)
    from swarm.learn.config import add_arguments as add_train_arguments

    add_fault_flags(p, process=False)
    add_train_arguments(p)
    p.set_defaults(func=cmd_train)
