"""Command-line front ends of learning over the network: `swarm learner`, `swarm rollout-worker`."""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

from swarm.cli.common import (
    add_common,
    add_world,
    file_tables,
    output_dir,
    output_file,
    world_config,
)
from swarm.cli.run import _logging, learner_configs
from swarm.cli.secure import add_secure_flag, secure_options
from swarm.net import zconfig
from swarm.procs.runconfig import RunRecord
from world.config import ConfigError


def cmd_learner(args: argparse.Namespace) -> int:
    from swarm.procs.learner import main as learner_main

    _logging(args.verbose)
    if args.spec:
        rec = RunRecord.read(args.spec)
        world, seed = rec.world, rec.run.seed
        tables = {"learner": rec.learner or {}, "train": rec.train or {}}
    else:
        tables = file_tables(args.config)
        world = world_config(args, tables)
        seed = args.seed or 0
    lc, tc = learner_configs(args, tables)
    if not lc.out:
        raise ConfigError("swarm learner needs --out DIR")
    if lc.resume and not (Path(lc.out) / "checkpoint.pt").is_file():
        raise ConfigError(f"--resume: {Path(lc.out) / 'checkpoint.pt'} does not exist")
    output_dir(lc.out, "--out")
    output_file(args.json)
    try:
        zopts = secure_options(args, zconfig.from_args(args), "learner", lc.run_id)
        status = learner_main(world, lc, tc, zopts, seed)
    except KeyboardInterrupt:
        return 130
    if args.json:
        from swarm.common.atomic import write_json

        write_json(args.json, status)
    return 0


def cmd_rollout_worker(args: argparse.Namespace) -> int:
    from swarm.procs.rollout_worker import main as worker_main

    _logging(args.verbose)
    if args.batch < 1 or args.threads < 1:
        raise ConfigError("--batch and --threads must be >= 1")
    try:
        zopts = secure_options(args, zconfig.from_args(args), f"worker-{args.worker_id}",
                               args.run_id)
        res = worker_main(args.run_id, zopts, args.worker_id, args.batch, args.threads,
                          args.max_batches, args.wait)
    except KeyboardInterrupt:
        return 130
    except TimeoutError as exc:
        raise ConfigError(str(exc)) from None
    print(json.dumps(res), flush=True)
    return 0


def add_parsers(sub: Any) -> None:
    """Register `learner` and `rollout-worker` on the `swarm` subparsers."""
    p = sub.add_parser("learner", help="the learner process: trains from the swarm's rollouts",
                       description="Gather robots' and rollout workers' episodes of run RUN_ID, "
                                   "update the policy with the batched trainer's REINFORCE step, "
                                   "publish versioned weights; checkpoint every update.")
    add_common(p)
    add_world(p)
    p.add_argument("--run-id", help="the run to learn from")
    p.add_argument("--policy", help="learned policy (default commattn)")
    p.add_argument("--checkpoint", metavar="FILE", help="initial weights")
    p.add_argument("--out", metavar="DIR", help="checkpoint.pt, curve.csv, log.jsonl go here")
    p.add_argument("--resume", action="store_true", help="continue from OUT/checkpoint.pt")
    p.add_argument("--max-staleness", type=int, metavar="K",
                   help="drop episodes more than K versions old (default 1)")
    p.add_argument("--join-timeout", type=float, metavar="S",
                   help="seconds to wait for an episode's robot records (default 5)")
    p.add_argument("--gather-only", action="store_true", help="count episodes, never update")
    g = p.add_argument_group("loss (override [train] of --config)")
    g.add_argument("--batch", dest="train_batch", type=int, metavar="B",
                   help="episodes per update (default 288)")
    g.add_argument("--lr", dest="train_lr", type=float, help="Adam learning rate")
    g.add_argument("--alpha", dest="train_alpha", type=float, help="baseline weight alpha")
    g.add_argument("--gamma", dest="train_gamma", type=float, help="discount")
    g.add_argument("--ent-coef", dest="train_ent_coef", type=float, help="entropy bonus")
    g.add_argument("--threads", dest="train_threads", type=int, help="torch threads")
    g.add_argument("--algo", dest="train_algo", choices=["reinforce", "ppo"],
                   help="estimator (default reinforce, the paper's; ppo is ours)")
    g.add_argument("--ppo-epochs", dest="train_ppo_epochs", type=int, metavar="K",
                   help="with --algo ppo: passes over each batch (default 4)")
    p.add_argument("--spec", metavar="FILE", help=argparse.SUPPRESS)
    p.add_argument("-v", "--verbose", action="store_true", help="log at INFO")
    zconfig.add_arguments(p)
    add_secure_flag(p)
    p.set_defaults(func=cmd_learner)

    p = sub.add_parser("rollout-worker", help="batched episodes for a learner, over Zenoh",
                       description="Run batched episodes with the learner's current weights and "
                                   "publish them to it (scale training out across cores and "
                                   "hosts).")
    p.add_argument("--run-id", required=True, help="the learner's run id")
    p.add_argument("--worker-id", type=int, default=0, help="distinct per worker (its seed)")
    p.add_argument("--batch", type=int, default=16, help="episodes per batch (default 16)")
    p.add_argument("--threads", type=int, default=1, help="torch threads (default 1)")
    p.add_argument("--max-batches", type=int, default=0, help="stop after this many (0: never)")
    p.add_argument("--wait", type=float, default=30.0, help="seconds to wait for the learner")
    p.add_argument("-v", "--verbose", action="store_true", help="log at INFO")
    zconfig.add_arguments(p)
    add_secure_flag(p)
    p.set_defaults(func=cmd_rollout_worker)
