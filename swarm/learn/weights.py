"""Versioned shared weights: a learned policy's tensors as a `Weights` message and back, with
every check a receiver needs (right policy, right network, right shapes, finite values)."""

from __future__ import annotations

import dataclasses

import numpy as np
import torch

from policies.learned import LearnedPolicy
from swarm.net.messages import BadMessage, Weights


def weights_of(policy: LearnedPolicy, version: int) -> Weights:
    return Weights(policy.name, version, dataclasses.asdict(policy.model_cfg),
                   {k: v.detach().numpy().astype(np.float32)
                    for k, v in policy.net.state_dict().items()})


def adopt(policy: LearnedPolicy, w: Weights) -> None:
    """Load `w` into `policy` (see `check_weights`; the policy is unchanged when they don't fit)."""
    check_weights(policy, w)
    policy.net.load_state_dict({k: torch.from_numpy(v) for k, v in w.tensors.items()})


def check_weights(policy: LearnedPolicy, w: Weights) -> None:
    """A one-line BadMessage if `w` is for another policy or network, or carries tensors of the
    wrong shape or non-finite values."""
    if w.policy != policy.name:
        raise BadMessage(f"weights v{w.version} are for {w.policy!r}, not {policy.name!r}")
    ours = dataclasses.asdict(policy.model_cfg)
    if {k: w.model.get(k) for k in ours} != ours:
        raise BadMessage(f"weights v{w.version} are for another {policy.name} network "
                         f"({w.model})")
    state = policy.net.state_dict()
    if set(w.tensors) != set(state):
        odd = sorted(set(w.tensors) ^ set(state))[:3]
        raise BadMessage(f"weights v{w.version} have tensors {odd} that do not fit")
    for k, v in state.items():
        if tuple(w.tensors[k].shape) != tuple(v.shape):
            raise BadMessage(f"weights v{w.version}: {k} has shape {tuple(w.tensors[k].shape)}, "
                             f"expected {tuple(v.shape)}")
        if not np.isfinite(w.tensors[k]).all():
            raise BadMessage(f"weights v{w.version}: {k} is not finite")
