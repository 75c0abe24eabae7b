"""`swarm train`'s configuration and flags, importable without torch (the CLI builds every
subcommand's parser in every process, robots included)."""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
from collections.abc import Collection
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from swarm.common.flags import add_flags, check_wait, from_flags
from swarm.net.keys import check_run_id
from world.config import ConfigError, WorldConfig, from_dict, toml_bools

PPO_FIELDS = ("gae_lambda", "ppo_epochs", "ppo_clip")
"""TrainConfig fields only `algo = "ppo"` reads: set to anything but their default for another
estimator, they are refused (they would silently do nothing)."""


@dataclass
class TrainConfig:
    """Everything that determines a training run besides the world."""

    policy: str = "commattn"
    """Registry name of a learned policy: commattn, commnet, vain, bicnet."""
    init: str = ""
    """Start from the weights of this checkpoint (same policy and network) instead of fresh
    ones, e.g. to fine-tune a trained policy under faults; "" starts fresh."""
    team_memory: bool = False
    """Turn the team memory (the team map from every bitmap heard this episode, see
    policies.features) on for an --init checkpoint trained without it; fresh networks have it
    (the model default), and false keeps a checkpoint's own setting."""
    belief: bool = False
    """Turn the belief features (the receiver's belief map as two egocentric windows, see
    policies.infer.tokens) on for an --init checkpoint trained without them: the new inputs'
    weights start at zero, so the network first acts as the checkpoint did. A fresh network
    takes them with --model '{"belief": true}'."""
    hint: bool = False
    """Turn coordinated frontier's suggested moves on as inputs (see policies.infer.tokens,
    ours) for an --init checkpoint, widened with zero weights like --belief (which it needs,
    from the checkpoint or this run). A fresh network takes '{"belief": true, "hint": true}'."""
    hint_planner: str = ""
    """Set the planner behind the hint of an --init checkpoint: "team-beam" (its one move, ours),
    "chain-plan" (its move, ours) or "coordinated-frontier" (see ModelConfig.hint_planner); ""
    keeps the checkpoint's. The inputs keep their width and weights. A fresh network takes it in
    --model."""
    hint_prior: float = -1.0
    """Set an --init checkpoint's `hint_prior` (ModelConfig.hint_prior, ours: added to the
    hinted move's logit) to this, in [0, 64]; -1 keeps the checkpoint's. A fresh network takes
    it in --model."""
    train_loss: float = 0.0
    """Fault-aware training: drop each robot-to-robot message (trajectory and hidden-state)
    with this probability, with the swarm radio's seeded loss model (0: no faults)."""
    faults: str = ""
    """Fault-aware training under any radio fault: the `[faults]` table as JSON, set by the same
    fault flags as `swarm run` (--latency, --jitter, --loss, --bandwidth, --partition,
    --compute-ms); applied by the virtual-time channel model (swarm.net.channel)."""
    model: str = ""
    """Sizes of a fresh network, as a JSON object of the policy's model-config fields, e.g.
    '{"hidden": 64, "state": 128}' for a wider CommAttn (the rest keep their defaults); ""
    keeps every default. An --init checkpoint brings its own sizes."""
    tick_s: float = 2.0
    """The tick's virtual length under `faults` (as `swarm run --tick-timeout`)."""
    seed: int = 0
    """Run seed: initial weights and the training / validation episode seeds."""
    epochs: int = 50
    """Epochs (the paper: 50); a checkpoint is written after each."""
    updates: int = 100
    """Weight updates per epoch (the paper: 100)."""
    batch: int = 288
    """Episodes per update (the paper: 288)."""
    lr: float = 3e-3
    """Adam learning rate (1e-3 learned several times slower in pilots)."""
    alpha: float = 0.03
    """Weight of the baseline term alpha (G - b)^2 (the paper's alpha)."""
    gamma: float = 1.0
    """Discount of the return G_t; 1.0 sums the rewards as the paper does."""
    reward_scale: float = 0.01
    """Rewards are multiplied by this before the loss: returns of order 1 keep the baseline term
    alpha (G - b)^2 from swamping the policy gradient in the shared layers (at 0.1 the policy
    did not learn in pilots)."""
    adv_norm: bool = True
    """Normalise G - b over the batch (zero mean, unit std) in the policy-gradient term."""
    ent_coef: float = 0.01
    """Entropy bonus per decision (0 disables)."""
    max_grad_norm: float = 1.0
    """Clip the global gradient norm to this (0 disables)."""
    is_clip: float = 1.0
    """Learner only: a stale episode (acted by an older weights version) weights each decision's
    policy-gradient term by the truncated importance ratio min(is_clip, pi_now(a) / pi_acted(a))
    (V-trace's rho-bar); 0 turns the correction off. Fresh episodes always weigh 1."""
    algo: str = "reinforce"
    """`reinforce` (the paper's estimator: G_t - b(s_t), one step per batch) or `ppo` (ours, not
    the paper's: GAE(gamma, gae_lambda) advantages, `ppo_epochs` steps per batch on the clipped
    surrogate of Schulman et al. 2017, the baseline fit to the GAE returns)."""
    gae_lambda: float = 0.95
    """PPO: the lambda of the generalized advantage estimate (1: returns minus the baseline)."""
    ppo_epochs: int = 4
    """PPO: optimizer steps on each batch (each over the whole batch)."""
    ppo_clip: float = 0.2
    """PPO: the probability ratio is clipped to [1 - clip, 1 + clip] in the surrogate."""
    curriculum_step: int = 10
    """Dynamic blocks added per curriculum level (levels 0, step, 2 step, .. up to the world's
    n_dynamic); 0 trains on the full world from the start."""
    curriculum_threshold: float = 0.65
    """Advance a level when the running mean elratio of the training episodes reaches this."""
    curriculum_min_updates: int = 5
    """Updates spent at a level before it may advance."""
    curriculum_max_updates: int = 30
    """Updates after which a level advances regardless of elratio (0: never forced)."""
    curriculum_ema: float = 0.9
    """Smoothing of the running mean elratio: ema = ema * c + (1 - c) * batch mean."""
    train_seed_offset: int = 1_000_000
    """Training episodes use world seed offset + seed; validation uses 2 * offset + seed."""
    val_episodes: int = 96
    """Validation episodes (greedy, then sampled) on the full world after every epoch, on a
    seed of their own (0 disables)."""
    threads: int = 1
    """torch.set_num_threads of each training process. One by default: on a 2-core machine
    whose other core is busy a second thread spin-waits, and an update took ~50x longer (UA
    pass 76: 74 s against 1.4 s); raise it only with idle cores to spare."""
    workers: int = 1
    """Processes that collect and backpropagate the episodes of each update in parallel (this
    one plus workers - 1 spawned ones, see swarm.learn.parallel); the update is the same for
    any count up to float rounding. On 2 cores, --workers 2 --threads 1 is fastest."""
    imitate: str = ""
    """Teacher (ours, not the paper's): a non-learned policy, e.g. `team-beam`, whose action at
    every state the learner visits is the target (DAgger: the learner's own sampled actions
    drive the episodes, the loss is the cross-entropy to the teacher's action plus the
    baseline's); empty: REINFORCE."""
    imitate_samples: int = 1
    """Teacher draws per state, each under another seed of its tie-break noise; the target is
    the set of their actions and the loss -log of its total probability (K > 1: a pick among
    equally good moves stops being noise in the labels)."""
    chunk_ticks: int = 3
    """Ticks per backward pass: bounds memory and keeps tensors cache-sized (3 is fastest here);
    the gradient is the same for any value."""

    def __post_init__(self) -> None:
        ranges = {"train_loss": (0, 1), "seed": (0, 2**31 - 1), "epochs": (1, 10**6),
                  "updates": (1, 10**6), "batch": (1, 10**6), "lr": (1e-12, 10.0),
                  "alpha": (0, 1e6), "gamma": (0, 1), "reward_scale": (1e-12, 1e6),
                  "ent_coef": (0, 1e6), "max_grad_norm": (0, 1e12), "is_clip": (0, 1e6),
                  "curriculum_step": (0, 10**6), "curriculum_threshold": (0, 1),
                  "curriculum_min_updates": (0, 10**6), "curriculum_max_updates": (0, 10**6),
                  "curriculum_ema": (0, 1), "train_seed_offset": (0, 2**40),
                  "val_episodes": (0, 10**7), "threads": (1, 256), "workers": (1, 256),
                  "chunk_ticks": (1, 10**6), "tick_s": (1e-3, 3600), "gae_lambda": (0, 1),
                  "ppo_epochs": (1, 1000), "ppo_clip": (1e-6, 10),
                  "imitate_samples": (1, 16)}
        counts = {f.name for f in dataclasses.fields(self) if f.type in ("int", int)}
        for name, (lo, hi) in ranges.items():
            v = getattr(self, name)
            kinds = int if name in counts else (int, float)  # a count is never 2.5
            if isinstance(v, bool) or not (isinstance(v, kinds) and lo <= v <= hi):  # also NaN
                raise ConfigError(f"train {name} must lie in [{lo}, {hi}], got {v!r}")
        if self.algo not in ("reinforce", "ppo"):
            raise ConfigError(f"train algo must be reinforce or ppo, got {self.algo!r}")
        if self.faults:  # the [faults] table as JSON: an object, each value checked as the flags
            from swarm.net.faults import plan_from_table

            try:
                table = json.loads(self.faults)
            except ValueError:
                raise ConfigError(f"train faults must be a JSON object, got {self.faults!r}"
                                  ) from None
            if not isinstance(table, dict):
                raise ConfigError(f"train faults must be a JSON object, got {self.faults!r}")
            plan_from_table(table)
            if self.train_loss > 0 and "loss" in table:
                raise ConfigError("train train_loss and a loss in faults: give the loss once")
        if self.algo != "ppo":  # PPO's own settings, set for another estimator, would do nothing
            ppo_only = [f"{f.name} = {getattr(self, f.name)!r}" for f in dataclasses.fields(self)
                        if f.name in PPO_FIELDS and getattr(self, f.name) != f.default]
            if ppo_only:
                raise ConfigError(f"train {', '.join(ppo_only)} only applies with algo ppo "
                                  f"(--algo ppo; swarm run: --train-algo ppo), but algo is "
                                  f"{self.algo!r}")
        if self.imitate and self.algo == "ppo":
            raise ConfigError("train imitate needs algo reinforce (its loss is not a surrogate)")
        if self.imitate_samples > 1 and not self.imitate:
            raise ConfigError("train imitate_samples needs a teacher (imitate)")
        if self.belief and not self.init:
            raise ConfigError("train belief widens an --init checkpoint; a fresh network takes "
                              "--model '{\"belief\": true}'")
        if self.hint and not self.init:
            raise ConfigError("train hint widens an --init checkpoint; a fresh network takes "
                              "--model '{\"belief\": true, \"hint\": true}'")
        if self.hint_planner:
            from policies.infer.tokens import HINT_PLANNERS

            if self.hint_planner not in HINT_PLANNERS:
                raise ConfigError(f"train hint_planner must be one of {', '.join(HINT_PLANNERS)}, "
                                  f"got {self.hint_planner!r}")
            if not self.init:
                raise ConfigError("train hint_planner sets an --init checkpoint's hint; a fresh "
                                  "network takes --model '{\"belief\": true, \"hint\": true, "
                                  "\"hint_planner\": \"team-beam\"}'")
        if self.hint_prior != -1.0:
            if isinstance(self.hint_prior, bool) or not 0 <= self.hint_prior <= 64:
                raise ConfigError(f"train hint_prior must be -1 (keep) or a number in [0, 64], "
                                  f"got {self.hint_prior!r}")
            if not self.init:
                raise ConfigError("train hint_prior sets an --init checkpoint's; a fresh network "
                                  "takes --model '{\"belief\": true, \"hint\": true, "
                                  "\"hint_prior\": 8}'")
        if self.model:
            self.model_config()
        if self.imitate:
            from policies import TEACHERS

            if self.imitate not in TEACHERS:
                raise ConfigError(f"train imitate must name a teacher "
                                  f"({', '.join(TEACHERS)}), got {self.imitate!r}")

    def model_config(self) -> Any:
        """The policy's model config with `model`'s fields set (ConfigError, one line, for
        anything that is not an object of known fields with sane values)."""
        from policies import policy_class

        try:
            changes = json.loads(self.model) if self.model else {}
        except json.JSONDecodeError as exc:
            raise ConfigError(f"train model must be a JSON object, e.g. '{{\"hidden\": 64}}': "
                              f"{exc.msg}") from None
        if not isinstance(changes, dict):
            raise ConfigError(f"train model must be a JSON object, got {self.model!r}")
        cls = getattr(policy_class(self.policy), "config_cls", None)
        if cls is None:
            raise ConfigError(f"train model needs a learned policy, got {self.policy!r}")
        if changes and self.init:
            raise ConfigError("train model sets a fresh network's sizes; an --init checkpoint "
                              "brings its own")
        return from_dict(cls, changes, where="train model")


# ------------------------------------------------------------------------------------ resume
RESUME_MAY_CHANGE = ("epochs", "workers", "threads")
"""What `--resume` may change: how long and on how many processes the run goes on, never its
math (the update is the same for any worker count, up to float rounding)."""


def held_to_checkpoint(saved: TrainConfig, asked: TrainConfig, given: Collection[str] | None,
                       may_change: Collection[str], where: str, restart: str) -> dict[str, Any]:
    """What a resumed run takes from `asked`: its `given` fields (None: every field is meant)
    that are in `may_change`. Every other given field must equal the checkpoint's (`saved`): the
    checkpoint's optimizer state and curve belong to it; else one ConfigError naming each."""
    names = [f.name for f in dataclasses.fields(TrainConfig) if given is None or f.name in given]
    differ = [f"{n} = {getattr(asked, n)!r} differs from its {getattr(saved, n)!r}"
              for n in names if n not in may_change and getattr(asked, n) != getattr(saved, n)
              and not (n == "faults" and _same_faults(saved.faults, asked.faults))]
    if differ:
        raise ConfigError(f"--resume continues {where} as it was trained: {', '.join(differ)} "
                          f"(of the training settings only {', '.join(may_change)} may change; "
                          f"{restart})")
    return {n: getattr(asked, n) for n in names if n in may_change}


def _same_faults(a: str, b: str) -> bool:
    """Whether two `faults` JSON tables are the same fault plan (however their values read:
    `--loss 0.30` is `--loss 0.3`, `--latency 0.05s` is `50ms`)."""
    from swarm.net.faults import plan_from_table

    if not (a and b):
        return a == b
    ta, tb = json.loads(a), json.loads(b)
    return plan_from_table(ta).to_record() == plan_from_table(tb).to_record() and \
        ta.get("seed") == tb.get("seed")


def resumed(saved: TrainConfig, asked: TrainConfig, given: Collection[str] | None,
            done: int, where: str) -> TrainConfig:
    """The config a resumed run goes on with: `saved` (the checkpoint's) with the `given` fields
    of `asked` that `--resume` may change (None: every field of `asked` is meant). ConfigError,
    one line, for a given field that would change the run itself, or epochs already `done`."""
    changes = held_to_checkpoint(saved, asked, given, RESUME_MAY_CHANGE, where,
                                 "a new --out with --init starts another run from its weights")
    if given is None:  # the Python API's old contract: epochs only ever extend a run
        changes["epochs"] = max(asked.epochs, saved.epochs)
    if changes.get("epochs", saved.epochs) < done:
        raise ConfigError(f"--resume --epochs {changes['epochs']}: {where} has already done "
                          f"{done} epochs")
    return dataclasses.replace(saved, **changes)


def resume_point(data: dict[str, Any], cfg: TrainConfig, given: Collection[str] | None,
                 world: WorldConfig, world_given: Collection[str] | None,
                 where: str) -> tuple[TrainConfig, WorldConfig, dict[str, Any]]:
    """What `swarm train --resume` goes on with, from a checkpoint's `data` (torch's or the
    torch-free reader's): its config with the flags that may change (`resumed`), its world (a
    `world_given` field that differs is refused; None: all are given) and its trainer state.
    CheckpointError or ConfigError, one line."""
    from policies.checkpoint import CheckpointError

    tr = data.get("train")
    if not isinstance(tr, dict) or not isinstance(tr.get("config"), dict) or \
            not isinstance(tr.get("epoch"), int):
        raise CheckpointError(f"{where}/checkpoint.pt holds no trainer state; cannot resume")
    saved = from_dict(TrainConfig, tr["config"], where="checkpoint train config")
    cfg = resumed(saved, cfg, given, tr["epoch"], where)
    return cfg, held_world(data, world, world_given, where), tr


def held_world(data: dict[str, Any], world: WorldConfig, world_given: Collection[str] | None,
               where: str) -> WorldConfig:
    """The world a resumed run (`swarm train` or `swarm learner --resume`) goes on with: its
    checkpoint's; a `world_given` field of `world` that differs from it (None: every field is
    given) is a one-line ConfigError."""
    theirs = from_dict(WorldConfig, data.get("world"), where="checkpoint world")
    names = [f.name for f in dataclasses.fields(WorldConfig)] if world_given is None \
        else sorted(world_given)
    key = next((k for k in names if getattr(world, k) != getattr(theirs, k)), None)
    if key is not None:
        raise ConfigError(f"--resume continues {where} on the world it was trained on: "
                          f"{key} = {getattr(world, key)!r} differs from its "
                          f"{getattr(theirs, key)!r}")
    return theirs


LEARNER_MAY_CHANGE = ("threads",)
"""What a resumed learner's TrainConfig may change: how many torch threads, never its math."""


def learner_resume_point(state: Any, asked: TrainConfig, given: Collection[str] | None,
                         out: Path) -> TrainConfig:
    """The TrainConfig a resumed learner goes on with, from its checkpoint's `learner` state
    (torch's or the torch-free reader's): the saved one, with the `given` fields of `asked`
    that may change (None: every field of `asked` is meant). A given field that would change
    the run's math is a one-line ConfigError naming every such field, as `swarm train
    --resume` does: the checkpoint's optimizer state and curve belong to it."""
    from policies.checkpoint import CheckpointError

    if not isinstance(state, dict) or not isinstance(state.get("train"), dict):
        raise CheckpointError(f"{out / 'checkpoint.pt'} holds no learner state; cannot resume")
    saved = from_dict(TrainConfig, state["train"], where="checkpoint train config")
    return dataclasses.replace(saved, **held_to_checkpoint(
        saved, asked, given, LEARNER_MAY_CHANGE, f"the learner in {out}",
        f"a new --out with --checkpoint {out / 'checkpoint.pt'} starts another run from its "
        f"weights"))


def held_seed(state: Any, asked: int | None, out: Path) -> int:
    """The seed a resumed learner joins its episodes with: its checkpoint's (the run's seed its
    episodes were joined with, held like its train settings); a given `--seed` that differs is
    a one-line ConfigError. A checkpoint from before the seed was saved: `asked`, else 0."""
    held = state.get("seed") if isinstance(state, dict) else None
    if not isinstance(held, int) or isinstance(held, bool):
        return asked or 0
    if asked is not None and asked != held:
        raise ConfigError(f"--resume continues the learner in {out} on its run's episodes: "
                          f"seed = {asked} differs from its {held} (the seed they are joined "
                          f"with; a new --out with --checkpoint {out / 'checkpoint.pt'} learns "
                          "from another run)")
    return held


# ---------------------------------------------------------------------------- rollout worker
MAX_WORKER_ID = 999_999
"""Worker ids are seeds and name their worker's key (`worker/<k>/episodes`, an id of at most
six digits as every id in a key): [0, MAX_WORKER_ID]."""
MAX_WORKER_BATCH = 4096
"""Episodes a rollout worker collects at once, all in its memory (the paper's batch is 288)."""


def check_worker(worker_id: int, batch: int, threads: int, max_batches: int,
                 wait: float) -> None:
    """A rollout worker's options (`swarm rollout-worker`), checked before anything starts:
    ConfigError, one line."""
    for flag, v, lo, hi in (("--worker-id", worker_id, 0, MAX_WORKER_ID),
                            ("--batch", batch, 1, MAX_WORKER_BATCH), ("--threads", threads, 1, 256),
                            ("--max-batches", max_batches, 0, 2**31 - 1)):
        if isinstance(v, bool) or not isinstance(v, int) or not lo <= v <= hi:
            raise ConfigError(f"{flag} must be an integer in [{lo}, {hi}], got {v!r}")
    check_wait(wait)


# --------------------------------------------------------------------------------------- CLI
def _run_dir(text: str) -> Path:
    """`--out`: a directory; an empty string (Path("") is ".") or an existing file is refused."""
    if not text.strip():
        raise argparse.ArgumentTypeError("must name a directory, not an empty string")
    try:  # (a name the file system cannot hold: ENAMETOOLONG, raised while the flags parse)
        if Path(text).exists() and not Path(text).is_dir():
            raise argparse.ArgumentTypeError(f"{text} exists and is not a directory")
    except OSError as exc:
        raise argparse.ArgumentTypeError(f"{text[:40]}{'...' * (len(text) > 40)}: "
                                         f"{exc.strerror}") from None
    return Path(text)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """`swarm train` flags; every TrainConfig field is a flag (unset flags keep the default).
    Flags the parser already has (a shared --seed, say) are left as they are."""
    parser.add_argument("--out", type=_run_dir, required=True,
                        help="run directory (checkpoint, logs)")
    parser.add_argument("--resume", action="store_true", help="continue from OUT/checkpoint.pt")
    add_flags(parser, TrainConfig)


def from_args(args: argparse.Namespace, base: TrainConfig | None = None) -> TrainConfig:
    """TrainConfig from parsed flags over `base` (e.g. a TOML [train] table)."""
    return from_flags(TrainConfig, args, base)


@dataclass
class LearnerConfig:
    """What a learner does (TOML table `[learner]`; the loss settings come from `[train]`)."""

    run_id: str = "run"
    """The run whose rollouts it gathers."""
    policy: str = "commattn"
    """Learned policy trained."""
    checkpoint: str | None = None
    """Initial weights (a policy checkpoint); without one, fresh weights from `seed`."""
    out: str | None = None
    """Directory of the learner's checkpoint.pt, curve.csv and log.jsonl (required)."""
    resume: bool = False
    """Continue from OUT/checkpoint.pt (version, optimizer and counters)."""
    max_staleness: int = 1
    """Use episodes at most this many versions behind the current one; drop older ones."""
    join_timeout: float = 5.0
    """Seconds after the world's episode record to wait for the robots' records."""
    gather_only: bool = False
    """Gather and count episodes without updating (rollout benchmarks)."""
    status_every: float = 0.5
    """Seconds between status records on learner/status."""
    seed: int = 0
    """Seed of fresh initial weights."""

    def __post_init__(self) -> None:
        if not isinstance(self.run_id, str):
            raise ConfigError(f"learner run_id must be a string, got {self.run_id!r}")
        check_run_id(self.run_id)
        for name, lo, hi in (("max_staleness", 0, 10**6), ("seed", 0, 2**31 - 1)):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or not lo <= v <= hi:
                raise ConfigError(f"learner {name} must be an integer in [{lo}, {hi}], got {v!r}")
        for name, lo, hi in (("join_timeout", 0.01, 3600.0), ("status_every", 0.01, 3600.0)):
            v = getattr(self, name)
            if (isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v)
                    or not lo <= v <= hi):
                raise ConfigError(f"learner {name} must lie in [{lo}, {hi}] seconds, got {v!r}")
        if self.gather_only and self.resume:  # (its counts would mix a trainer's checkpoint's)
            raise ConfigError("--gather-only never updates or checkpoints: nothing to --resume")


LEARNER_TRAIN_FIELDS = ("batch", "lr", "alpha", "gamma", "reward_scale", "adv_norm", "ent_coef",
                        "max_grad_norm", "threads", "chunk_ticks", "algo", "ppo_epochs")

# TrainConfig fields that only the batched trainer implements
BATCH_TRAIN_FIELDS = ("init", "team_memory", "belief", "hint", "hint_planner", "hint_prior",
                      "model", "imitate", "imitate_samples")


def learner_configs(args: argparse.Namespace,
                    tables: dict[str, Any]) -> tuple[LearnerConfig, TrainConfig]:
    """LearnerConfig and TrainConfig from `[learner]` / `[train]` of the file and the flags."""
    lflags = {"run_id": getattr(args, "run_id", None), "policy": getattr(args, "policy", None),
              "checkpoint": getattr(args, "checkpoint", None), "out": getattr(args, "out", None),
              "resume": True if getattr(args, "resume", False) else None,
              "max_staleness": getattr(args, "max_staleness", None),
              "join_timeout": getattr(args, "join_timeout", None),
              "gather_only": True if getattr(args, "gather_only", False) else None,
              "seed": getattr(args, "seed", None)}
    toml_bools(LearnerConfig, tables.get("learner", {}), "[learner]")
    toml_bools(TrainConfig, tables.get("train", {}), "[train]")
    ldata = {**tables.get("learner", {}), **{k: v for k, v in lflags.items() if v is not None}}
    tflags = {k: getattr(args, f"train_{k}", None) for k in LEARNER_TRAIN_FIELDS}
    tdata = {**tables.get("train", {}), **{k: v for k, v in tflags.items() if v is not None}}
    defaults = TrainConfig()
    batch_only = sorted(k for k in BATCH_TRAIN_FIELDS
                        if k in tdata and tdata[k] != getattr(defaults, k))
    if batch_only:  # the learner would ignore them: say so instead of training without them
        raise ConfigError(f"[train] {', '.join(batch_only)}: only `swarm train` (the batched "
                          f"trainer) takes these; a field learner starts from --checkpoint")
    try:
        return (from_dict(LearnerConfig, ldata, "[learner]"),
                from_dict(TrainConfig, tdata, "[train]"))
    except ValueError as exc:
        raise ConfigError(str(exc)) from None
