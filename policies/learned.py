"""The wrapper that makes a torch network a `Policy`: acting, chaining, training, checkpoints.

Acting: features from the View, the network under `torch.inference_mode`, then greedy (argmax) or
sampled actions by Gumbel-max with counter-based noise `world.noise.uniform(seed, episode, tick,
robot, 9, stream=0)`, never torch's generator: a robot process and the batched evaluator draw
the same action. Chained networks (CommAttn) decode receivers in id order; the batched `act`
runs the whole chain, a robot process calls `act_with_chain` with its predecessor's message.

Training: `evaluate(views, actions)` recomputes log-probabilities, values and entropies with
gradients for a recorded batch of ticks (teacher-forcing the chain with the recorded actions).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
import torch
from torch import nn

from policies.base import Policy
from policies.checkpoint import CheckpointError, load_checkpoint
from policies.features import Featurizer, Members
from world.config import ConfigError, WorldConfig, from_dict, to_dict
from world.core import N_ACTIONS
from world.decentral import TeamMemory, View
from world.noise import uniform

NO_ACTION = N_ACTIONS
WORLD_SHAPE_KEYS = ("vision", "recent_len")  # world fields that change the token width


@dataclass
class Decision:
    """What a batched decision computed, arrays [G, N, ...] (zeros off the receivers)."""

    actions: np.ndarray  # [G, N] int64
    probs: np.ndarray  # [G, N, 9] float32 action distribution of each receiver
    value: np.ndarray  # [G, N] float32 baseline b(s)
    state: np.ndarray | None  # [G, N, S] decoder states s_i (chained policies), else None
    context: np.ndarray | None  # [G, N, 2H] communication vectors c_i (chained), else None
    inputs: Members | None = None  # the features, when kept for training


@dataclass
class Evaluation:
    """Per-decision outputs with gradients for a batch of recorded ticks, rows in tick-major,
    group-major, id order (the order of `np.nonzero(view.receivers)` per tick)."""

    logp: torch.Tensor  # [R] log p(a | s) of the recorded action
    value: torch.Tensor  # [R] b(s)
    entropy: torch.Tensor  # [R]
    tick: np.ndarray  # [R] index into the `views` list
    group: np.ndarray  # [R]
    robot: np.ndarray  # [R]


def featurizer(cfg: WorldConfig, model: Any) -> Featurizer:
    """The features a network of config `model` reads."""
    return Featurizer(cfg, crop=model.crop, team_pool=getattr(model, "team_pool", 0),
                      memory=getattr(model, "team_memory", False))


def gumbel(view: View, group: np.ndarray, robot: np.ndarray) -> torch.Tensor:
    """Gumbel noise [R, 9] float64 of each receiver, from the counter-based generator (stream 0)."""
    u = uniform(view.seed, view.episodes[group], view.tick, robot, N_ACTIONS, stream=0)
    with np.errstate(divide="ignore"):
        return torch.from_numpy(-np.log(-np.log(u)))


def chooser(noise: torch.Tensor | None) -> Callable[[slice, torch.Tensor], torch.Tensor]:
    """Greedy argmax (noise None) or Gumbel-max sampling of a block of rows from their logits."""
    if noise is None:
        return lambda rows, logits: logits.argmax(-1)
    return lambda rows, logits: (logits.double() + noise[rows]).argmax(-1)


class LearnedPolicy(Policy):
    """A torch network behind the Policy interface; subclasses set name, config_cls, net_cls."""

    learned = True
    config_cls: ClassVar[type]
    net_cls: ClassVar[type[nn.Module]]

    def __init__(self, cfg: WorldConfig, checkpoint: str | Path | None = None,
                 model: Any | None = None) -> None:
        super().__init__(cfg)
        state_dict = None
        self.meta: dict[str, Any] = {}
        if checkpoint is not None:
            data = load_checkpoint(checkpoint)
            model, state_dict = self._check(data, Path(checkpoint))
            self.meta = dict(data.get("meta", {}))
        self.last_probs: np.ndarray | None = None  # [G, N, 9] of the last decision
        self.model_cfg = model if model is not None else self.config_cls()
        self.features = featurizer(cfg, self.model_cfg)
        self.net = self.net_cls(self.model_cfg, self.features.member_dim, self.features.pair_dim,
                                self.features.own_dim)
        if state_dict is not None:
            self.net.load_state_dict(state_dict)
        self.team = TeamMemory(cfg)

    def set_model(self, **changes: Any) -> None:
        """Change model-config fields that leave every weight shape alone (e.g. team_memory),
        keeping the weights: how a checkpoint is fine-tuned with a memory it was not trained
        with."""
        model = dataclasses.replace(self.model_cfg, **changes)
        feats = featurizer(self.cfg, model)
        if (feats.member_dim, feats.pair_dim, feats.own_dim) != (
                self.features.member_dim, self.features.pair_dim, self.features.own_dim):
            raise ConfigError(f"{', '.join(changes)} would change the network's input width")
        self.model_cfg, self.features = model, feats

    def reset(self, groups: int) -> None:
        self.team.reset(groups)

    def remember(self, view: View) -> None:
        """Fold the view into the receivers' team memory and attach it (networks that read it)."""
        if self.features.memory and view.team_visited is None:
            view.team_visited = self.team.update(view)

    def _check(self, data: dict[str, Any], path: Path) -> tuple[Any, dict[str, torch.Tensor]]:
        """The model config and weights of a checkpoint, if they fit this policy and world."""
        if data["policy"] != self.name:
            raise CheckpointError(f"checkpoint {path} holds policy {data['policy']!r}, "
                                  f"not {self.name!r}")
        fields = dict(data["model"])
        fields.setdefault("team_pool", 0)  # checkpoints from before the team map had none
        fields.setdefault("team_memory", False)  # ... and from before the team memory
        try:
            model = from_dict(self.config_cls, fields, where=f"checkpoint {path} model")
        except ConfigError as exc:
            raise CheckpointError(str(exc)) from None
        for key in WORLD_SHAPE_KEYS:
            theirs, ours = data["world"].get(key), getattr(self.cfg, key)
            if theirs != ours:
                raise CheckpointError(f"checkpoint {path} was trained with {key}={theirs}, "
                                      f"this world has {key}={ours}")
        feats = featurizer(self.cfg, model)
        expected = self.net_cls(model, feats.member_dim, feats.pair_dim,
                                feats.own_dim).state_dict()
        weights = data["state_dict"]
        for name, tensor in expected.items():
            got = weights.get(name)
            if got is None or tuple(got.shape) != tuple(tensor.shape):
                shape = None if got is None else tuple(got.shape)
                raise CheckpointError(f"checkpoint {path} does not fit {self.name}: {name} has "
                                      f"shape {shape}, expected {tuple(tensor.shape)}")
        extra = sorted(set(weights) - set(expected))
        if extra:
            raise CheckpointError(f"checkpoint {path} has unexpected weights "
                                  f"{', '.join(extra[:3])}")
        return model, weights

    def payload(self, meta: dict[str, Any] | None = None) -> dict[str, Any]:
        """The checkpoint dict of this policy (see policies.checkpoint)."""
        return {"policy": self.name, "model": dataclasses.asdict(self.model_cfg),
                "world": to_dict(self.cfg), "state_dict": self.net.state_dict(),
                "meta": dict(meta or {})}

    @property
    def state_size(self) -> int:
        """Floats in a hidden-state message (chained policies)."""
        return self.model_cfg.state if self.chained else 0

    # ----------------------------------------------------------------- acting
    def act(self, view: View, greedy: bool = True) -> np.ndarray:
        return self.decide(view, greedy).actions

    def decide(self, view: View, greedy: bool = True, keep_inputs: bool = False) -> Decision:
        """Actions, values and (chained) decoder states of every receiver of the view;
        `keep_inputs` keeps the features for a later `evaluate` (the trainer)."""
        self.remember(view)
        with torch.inference_mode():
            members = self.features(view)
            g, i = members.group, members.robot
            choose = chooser(None if greedy else gumbel(view, g, i))
            shape = view.receivers.shape
            actions = np.zeros(shape, dtype=np.int64)
            probs = np.zeros(shape + (N_ACTIONS,), dtype=np.float32)
            value = np.zeros(shape, dtype=np.float32)
            kept = members if keep_inputs else None
            if not self.chained:
                logits, v = self.net(members)
                actions[g, i] = choose(slice(None), logits).numpy()
                probs[g, i] = torch.softmax(logits, -1).numpy()
                value[g, i] = v.numpy()
                self.last_probs = probs
                return Decision(actions, probs, value, None, None, kept)
            pred = self._pred_rows([view], members)
            if bool((pred == -2).any()):
                raise ValueError("a receiver's predecessor is not a receiver of this view; "
                                 "use act_with_chain with the predecessor's hidden-state message")
            out, a = self.net.chain(self.net.encode(members), i, pred, choose)
            actions[g, i] = a.numpy()
            probs[g, i] = torch.softmax(out.logits, -1).numpy()
            value[g, i] = out.value.numpy()
            self.last_probs = probs
            state = np.zeros(shape + (self.state_size,), dtype=np.float32)
            state[g, i] = out.state.numpy()
            context = np.zeros(shape + (out.context.shape[1],), dtype=np.float32)
            context[g, i] = out.context.numpy()
            return Decision(actions, probs, value, state, context, kept)

    def prepare_chain(self, view: View) -> tuple[View, Members, Any]:
        """The part of `act_with_chain` that needs no predecessor (features and the encoder),
        so a robot process computes it while it waits for its predecessor's message."""
        if not self.chained:
            raise TypeError(f"{self.name} is not a chained policy")
        if (view.receivers.sum(1) != 1).any():
            raise ValueError("act_with_chain needs exactly one receiver per group")
        self.remember(view)
        with torch.inference_mode():
            members = self.features(view)
            return view, members, self.net.encode(members)

    def act_with_chain(self, view: View, pred_state: np.ndarray | None,
                       pred_action: np.ndarray | None, greedy: bool = True,
                       prepared: tuple[View, Members, Any] | None = None,
                       ) -> tuple[np.ndarray, np.ndarray]:
        """One receiver per group given its predecessor's hidden-state message.

        pred_state [G, S] float32 and pred_action [G] int (rows of receivers without a
        predecessor are ignored; pass None when no receiver has one). Returns actions [G, N]
        and the receivers' new states [G, S] (their own hidden-state messages). `prepared` is
        `prepare_chain(view)` computed earlier (the same view; its chain_ok may be set since).
        """
        if prepared is None:
            prepared = self.prepare_chain(view)
        elif prepared[0] is not view:
            raise ValueError("prepared for another view")
        _, members, encoded = prepared
        with torch.inference_mode():
            order = np.argsort(members.group)  # group g's receiver is row order[g]
            p = view.predecessor()[members.group, members.robot]
            if view.chain_ok is not None:  # lost or late hidden-state message: no predecessor
                p = np.where(view.chain_ok[members.group, members.robot], p, -1)
            has = torch.from_numpy(p >= 0)
            s_prev = self.net.s0.expand(len(p), -1)
            a_prev = torch.full((len(p),), NO_ACTION, dtype=torch.long)
            if bool(has.any()):
                if pred_state is None or pred_action is None:
                    raise ValueError("a receiver has a predecessor but no hidden-state message "
                                     "was given")
                rows = torch.from_numpy(members.group)
                ps = torch.as_tensor(np.asarray(pred_state, dtype=np.float32))
                ps = ps.reshape(view.groups, -1)[rows]
                pa = torch.as_tensor(np.asarray(pred_action, dtype=np.int64))
                pa = pa.reshape(view.groups)[rows]
                if bool(((pa < 0) | (pa >= N_ACTIONS))[has].any()):
                    raise ValueError("predecessor action must lie in 0..8")
                s_prev = torch.where(has[:, None], ps, s_prev)
                a_prev = torch.where(has, pa, a_prev)
            noise = None if greedy else gumbel(view, members.group, members.robot)
            out = self.net.decode(encoded, s_prev, a_prev)
            a = chooser(noise)(slice(None), out.logits)
            actions = np.zeros(view.receivers.shape, dtype=np.int64)
            actions[members.group, members.robot] = a.numpy()
            self.last_probs = np.zeros(view.receivers.shape + (N_ACTIONS,), dtype=np.float32)
            self.last_probs[members.group, members.robot] = torch.softmax(out.logits, -1).numpy()
            return actions, out.state.numpy()[order].copy()

    # --------------------------------------------------------------- training
    def evaluate(self, views: Sequence[View], actions: Sequence[np.ndarray],
                 inputs: Sequence[Members] | None = None) -> Evaluation:
        """Log-probs of the recorded actions [G, N] per view, values and entropies, with grad.
        `inputs` are the views' features kept at acting time (recomputed when None)."""
        parts = list(inputs) if inputs is not None else [self.features(v) for v in views]
        groups = np.cumsum([0] + [v.receivers.shape[0] for v in views])
        members = Members.cat(parts)
        tick = np.searchsorted(groups, members.group, side="right") - 1
        group = members.group - groups[tick]
        flat = np.concatenate([a.reshape(-1) for a in actions])
        n = views[0].receivers.shape[1]
        taken = torch.from_numpy(flat[members.group * n + members.robot].astype(np.int64))
        if self.chained:
            pred = self._pred_rows(views, members)
            out, _ = self.net.chain(self.net.encode(members), members.robot, pred,
                                    lambda rows, logits: taken[rows])
            logits, value = out.logits, out.value
        else:
            logits, value = self.net(members)
        logp_all = torch.log_softmax(logits, dim=-1)
        logp = logp_all.gather(1, taken[:, None])[:, 0]
        entropy = -(logp_all.exp() * logp_all).sum(-1)
        return Evaluation(logp, value, entropy, tick, group, members.robot)

    @staticmethod
    def _pred_rows(views: Sequence[View], members: Members) -> torch.Tensor:
        """Row of each receiver's predecessor: -1 none, -2 a predecessor that is not a receiver."""
        # a predecessor whose hidden-state message was lost or late counts as none (chain_ok)
        pred_id = np.concatenate([np.where(v.chain_ok, v.predecessor(), -1)
                                  if v.chain_ok is not None else v.predecessor()
                                  for v in views])  # [G_total, N]
        n = pred_id.shape[1]
        row_of = np.full(pred_id.shape, -2, dtype=np.int64)
        row_of[members.group, members.robot] = np.arange(members.receivers)
        p = pred_id[members.group, members.robot]
        return torch.from_numpy(np.where(p >= 0, row_of[members.group, np.clip(p, 0, n - 1)], -1))
