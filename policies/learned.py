"""The trainable half of a learned policy: a torch network beside the numpy one it acts with.

`LearnedPolicy` is an `InferencePolicy` (policies.infer.policy: features, acting, chaining and
weights in numpy, the code robot processes run) whose numpy weights are views of its torch
network's parameters, so an optimizer step or `load_state_dict` is seen by both at once.
Training: `evaluate(views, actions)` recomputes log-probabilities, values and entropies with
gradients for a recorded batch of ticks (teacher-forcing the chain with the recorded actions).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
import torch
from torch import nn

from policies.checkpoint import load_checkpoint
from policies.features import Members
from policies.infer.layers import Weights
from policies.infer.policy import InferencePolicy, NetDecision, pred_rows
from policies.infer.tokens import Tokens
from world.config import ConfigError, to_dict
from world.core import N_ACTIONS
from world.decentral import View

__all__ = ["Evaluation", "LearnedPolicy", "NetDecision"]


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
    agree: np.ndarray | None = None  # [R] greedy action == target (evaluated with targets)


class LearnedPolicy(InferencePolicy):
    """A torch network behind the Policy interface; subclasses set name, config_cls, numpy_cls
    (the acting twin) and net_cls (the torch module)."""

    net_cls: ClassVar[type[nn.Module]]
    owns_weights = False  # an optimizer step moves the numpy views of the torch parameters

    def read(self, checkpoint: str | Path) -> dict[str, Any]:
        return load_checkpoint(checkpoint)

    def build(self, weights: dict[str, Any] | None) -> Weights:
        """The torch network (loaded with `weights`) and numpy views of its parameters."""
        f = self.features
        self.net = self.net_cls(self.model_cfg, f.member_dim, f.pair_dim, f.own_dim)
        if weights is not None:
            self.net.load_state_dict({k: torch.as_tensor(v) for k, v in weights.items()})
        return {k: v.detach().numpy() for k, v in self.net.state_dict(keep_vars=True).items()}

    def set_model(self, **changes: Any) -> None:
        super().set_model(**changes)
        self.net.cfg = self.model_cfg  # (the torch network reads hint_prior from it)

    def widen(self, **changes: Any) -> None:
        """Change model-config fields that add inputs to the receiver's own token (`belief`),
        keeping every weight: the own embedding gains zero columns for the new inputs (they
        come last), so the network acts exactly as before until training moves them."""
        import dataclasses

        from policies.infer.policy import featurizer, shapes_of

        model = dataclasses.replace(self.model_cfg, **changes)
        old = {k: v.detach().clone() for k, v in self.net.state_dict().items()}
        for k, shape in shapes_of(self.cfg, model, self.numpy_cls).items():  # check, then change
            was = tuple(old[k].shape) if k in old else None
            if was != shape and not (k.endswith("own.weight") and was is not None and
                                     was[0] == shape[0] and was[1] <= shape[1]):
                raise ConfigError(f"{', '.join(changes)} would change {k} ({was} -> {shape}), "
                                  f"not only the own token's inputs")
        self.model_cfg, self.features = model, featurizer(self.cfg, model)
        self.np = self.numpy_cls(model, self.build(None))
        with torch.no_grad():
            for k, v in self.net.state_dict().items():
                v.zero_()
                v[tuple(slice(0, n) for n in old[k].shape)] = old[k]

    def payload(self, meta: dict[str, Any] | None = None) -> dict[str, Any]:
        """The checkpoint dict of this policy (see policies.checkpoint)."""
        import dataclasses

        return {"policy": self.name, "model": dataclasses.asdict(self.model_cfg),
                "world": to_dict(self.cfg), "state_dict": self.net.state_dict(),
                "meta": dict(meta or {})}

    # --------------------------------------------------------------- training
    def evaluate(self, views: Sequence[View], actions: Sequence[np.ndarray],
                 inputs: Sequence[Tokens] | None = None,
                 targets: Sequence[np.ndarray] | None = None) -> Evaluation:
        """Log-probs of the recorded actions [G, N] per view, values and entropies, with grad.
        `inputs` are the views' features kept at acting time (recomputed when None). With
        `targets` (a teacher's label sets [G, N] uint16, bit a for action a), the log-probs are
        of each set (log of its total probability), while a chained network still conditions on
        the actions taken (what the predecessors sent); `agree`: the greedy action is in it."""
        parts = list(inputs) if inputs is not None else [self.features(v) for v in views]
        groups = np.cumsum([0] + [v.receivers.shape[0] for v in views])
        tokens = Tokens.cat(parts)
        members = Members.of(tokens)
        tick = np.searchsorted(groups, members.group, side="right") - 1
        group = members.group - groups[tick]
        flat = np.concatenate([a.reshape(-1) for a in actions])
        n = views[0].receivers.shape[1]
        taken = torch.from_numpy(flat[members.group * n + members.robot].astype(np.int64))
        if self.chained:
            pred = torch.from_numpy(pred_rows(list(views), tokens))
            out, _ = self.net.chain(self.net.encode(members), members.robot, pred,
                                    lambda rows, logits: taken[rows])
            logits, value = out.logits, out.value
        else:
            logits, value = self.net(members)
        logp_all = torch.log_softmax(logits, dim=-1)
        agree = None
        if targets is None:
            logp = logp_all.gather(1, taken[:, None])[:, 0]
        else:
            flat_t = np.concatenate([a.reshape(-1) for a in targets])
            sets = flat_t[members.group * n + members.robot].astype(np.int64)
            inset = torch.from_numpy((sets[:, None] >> np.arange(N_ACTIONS)) & 1 == 1)
            if not bool(inset.any(1).all()):
                raise ValueError("a teacher label set is empty")
            logp = torch.logsumexp(logp_all.masked_fill(~inset, float("-inf")), dim=1)
            greedy = logits.detach().argmax(-1, keepdim=True)
            agree = inset.gather(1, greedy)[:, 0].numpy()
        entropy = -(logp_all.exp() * logp_all).sum(-1)
        return Evaluation(logp, value, entropy, tick, group, members.robot, agree)

    def torch_logits(self, view: View) -> tuple[torch.Tensor, torch.Tensor]:
        """Greedy logits [R, 9] and values [R] of every receiver of a view from the torch network:
        the reference the numpy network is tested against.

        Rows are in the features' order, robot-major (robot 0 of every group, then robot 1 ...;
        `self.features(view).group/.robot` index them), not `receiver_index`'s group-major order.
        Like a decision it calls `remember(view)`, so it advances the policy's memory: give it
        the views a fresh `reset` policy would decide on, in tick order."""
        self.remember(view)
        members = Members.of(self.features(view))
        with torch.inference_mode():
            if not self.chained:
                return self.net(members)
            pred = torch.from_numpy(pred_rows([view], self.features(view)))
            out, _ = self.net.chain(self.net.encode(members), members.robot, pred,
                                    lambda rows, logits: logits.argmax(-1))
            return out.logits, out.value
