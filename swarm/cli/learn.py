"""Command-line front ends of learning over the network: `swarm learner`, `swarm rollout-worker`."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from policies import check_learned
from swarm.cli.checks import distinct_paths
from swarm.cli.common import (
    _command,
    add_common,
    add_world,
    file_tables,
    named_dir,
    output_file,
    world_config,
    world_given,
)
from swarm.cli.run import _logging
from swarm.cli.secure import add_secure_flag, secure_options
from swarm.learn.config import (
    LEARNER_TRAIN_FIELDS,
    MAX_WORKER_BATCH,
    MAX_WORKER_ID,
    TrainConfig,
    check_worker,
    held_seed,
    held_world,
    learner_configs,
    learner_resume_point,
)
from swarm.learn.curves import RUN_FILES
from swarm.net import zconfig
from swarm.net.keys import check_run_id
from swarm.procs.runconfig import RunRecord
from world.config import ConfigError


def cmd_learner(args: argparse.Namespace) -> int:
    _logging(args.verbose)
    if args.spec:  # `swarm run --train`: the spec's train table is whole, every field meant
        rec = RunRecord.read(args.spec)
        world, seed = rec.world, rec.run.seed
        tables = {"learner": rec.learner or {}, "train": rec.train or {}}
        given = None
    else:
        tables = file_tables(args.config)
        world = world_config(args, tables)
        seed = args.seed or 0
        # what `--resume` holds against the checkpoint: the [train] keys of the file and the
        # flags given (threads is always set for this machine, see learner_configs)
        flags = [k for k in LEARNER_TRAIN_FIELDS if getattr(args, f"train_{k}", None) is not None]
        given = {*tables.get("train", {}), "threads", *flags}
    lc, tc = learner_configs(args, tables)
    named_dir(lc.out, "--out")  # (' ' made a folder named so)
    if not lc.out:
        raise ConfigError("swarm learner needs --out DIR")
    if lc.resume and not (Path(lc.out) / "checkpoint.pt").is_file():
        raise ConfigError(f"--resume: {Path(lc.out) / 'checkpoint.pt'} does not exist")
    if lc.resume and not args.spec and args.checkpoint:
        raise ConfigError("--checkpoint gives a new learner its first weights; --resume goes on "
                          "from OUT/checkpoint.pt (drop one of them)")
    check_learned(lc.policy, "the learner")  # (these refusals cost no torch import)
    if lc.resume:
        from policies.checkpoint import read_checkpoint

        out = Path(lc.out)
        data = read_checkpoint(out / "checkpoint.pt")
        learner_resume_point(data.get("learner"), tc, given, out)
        if not args.spec:  # (a run's spec is its own world, checked by `swarm run`)
            world = held_world(data, world, world_given(args, tables), f"the learner in {out}")
            seed = held_seed(data.get("learner"), args.seed, out)
    distinct_paths({}, {"--json": args.json, **{f"--out's {f}": str(Path(lc.out) / f)
                                                for f in RUN_FILES}})  # (it writes them)
    output_file(args.json)
    from swarm.procs.learning.learner import main as learner_main  # (torch: after the checks)

    try:
        zopts = secure_options(args, zconfig.from_args(args), "learner", lc.run_id)
        # checks everything first; creates --out only once they passed (and the session opened)
        status = learner_main(world, lc, tc, zopts, seed, given=given,
                              command=args.made_by or _command())
    except KeyboardInterrupt:
        return 130
    if args.json:
        from swarm.common.atomic import write_json

        write_json(args.json, status)
    return 0


def cmd_rollout_worker(args: argparse.Namespace) -> int:
    _logging(args.verbose)
    check_worker(args.worker_id, args.batch, args.threads, args.max_batches, args.wait)
    check_run_id(args.run_id)  # every flag before the banner and torch ('' took 2.3 s to refuse)
    zopts = secure_options(args, zconfig.from_args(args), f"worker-{args.worker_id}", args.run_id)
    from swarm.procs.learning.rollout_worker import main as worker_main  # (torch: after the checks)

    try:
        print(f"swarm rollout-worker: worker {args.worker_id} of run {args.run_id}: batches "
              "of episodes for its learner (Ctrl-C stops it)", file=sys.stderr, flush=True)
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
                                   "update the policy with the batched trainer's step (REINFORCE, "
                                   "or PPO with --algo ppo) every --batch episodes, write "
                                   "OUT/checkpoint.pt (atomically) after each update and only "
                                   "then publish its versioned weights; none before the first "
                                   "update, and a partial batch is never trained on.")
    add_common(p)
    add_world(p)
    p.add_argument("--run-id", help="the run to learn from")
    p.add_argument("--policy", help="learned policy (default commattn)")
    p.add_argument("--checkpoint", metavar="FILE", help="initial weights")
    p.add_argument("--out", metavar="DIR",
                   help="checkpoint.pt, curve.csv, log.jsonl, heard.log go here")
    p.add_argument("--resume", action="store_true",
                   help="continue from OUT/checkpoint.pt with its train settings, world and "
                        "seed (a loss flag that differs from them is refused; of those only "
                        "--threads may change; --max-staleness and --join-timeout, how this "
                        "learner gathers, are not held and may change); the episodes its "
                        "stopped self had heard of since its last update are counted lost")
    p.add_argument("--max-staleness", type=int, metavar="K",
                   help="drop episodes more than K >= 0 versions old (default 1)")
    p.add_argument("--join-timeout", type=float, metavar="S",
                   help="seconds to wait for an episode's robot records, in [0.01, 3600] "
                        "(default 5)")
    p.add_argument("--gather-only", action="store_true", help="count episodes, never update")
    g = p.add_argument_group("loss (override [train] of --config)")
    t = TrainConfig()  # (the defaults shown are swarm train's)
    g.add_argument("--batch", dest="train_batch", type=int, metavar="B",
                   help=f"episodes per update (default {t.batch})")
    g.add_argument("--lr", dest="train_lr", type=float,
                   help=f"Adam learning rate (default {t.lr:g})")
    g.add_argument("--alpha", dest="train_alpha", type=float,
                   help=f"baseline weight alpha (default {t.alpha:g})")
    g.add_argument("--gamma", dest="train_gamma", type=float,
                   help=f"discount (default {t.gamma:g})")
    g.add_argument("--ent-coef", dest="train_ent_coef", type=float,
                   help=f"entropy bonus (default {t.ent_coef:g})")
    g.add_argument("--threads", dest="train_threads", type=int,
                   help=f"torch threads (default {t.threads})")
    g.add_argument("--algo", dest="train_algo", choices=["reinforce", "ppo"],
                   help=f"estimator (default {t.algo}, the paper's; ppo is ours)")
    g.add_argument("--ppo-epochs", dest="train_ppo_epochs", type=int, metavar="K",
                   help=f"with --algo ppo: passes over each batch (default {t.ppo_epochs})")
    p.add_argument("--spec", metavar="FILE", help=argparse.SUPPRESS)
    p.add_argument("--made-by", metavar="COMMAND", help=argparse.SUPPRESS)  # (`swarm run`'s:
    # what its checkpoints record, not the spawned command naming temp files)
    p.add_argument("-v", "--verbose", action="store_true", help="log at INFO")
    zconfig.add_arguments(p)
    add_secure_flag(p)
    p.set_defaults(func=cmd_learner)

    p = sub.add_parser("rollout-worker", help="batched episodes for a learner, over Zenoh",
                       description="Run batched episodes with the learner's current weights and "
                                   "publish them to it (scale training out across cores and "
                                   "hosts).")
    p.add_argument("--run-id", required=True, help="the learner's run id")
    p.add_argument("--worker-id", type=int, default=0,
                   help=f"distinct per worker (its seed), in [0, {MAX_WORKER_ID}] (default 0)")
    p.add_argument("--batch", type=int, default=16,
                   help=f"episodes per batch, collected at once, in [1, {MAX_WORKER_BATCH}] "
                        f"(default 16)")
    p.add_argument("--threads", type=int, default=1, help="torch threads, 1-256 (default 1)")
    p.add_argument("--max-batches", type=int, default=0,
                   help="stop after this many (default 0: never)")
    p.add_argument("--wait", type=float, default=30.0, metavar="S",
                   help="seconds to wait for the learner, in [0.1, 3600] (default 30); a "
                        "client waits as long for its router to listen")
    p.add_argument("-v", "--verbose", action="store_true", help="log at INFO")
    zconfig.add_arguments(p)
    add_secure_flag(p)
    p.set_defaults(func=cmd_rollout_worker)
