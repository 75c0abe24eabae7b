"""Versioned shared weights: a learned policy's tensors as a `Weights` message and back, with
every check a receiver needs (right policy, right network, right shapes, finite values).

Works on any `InferencePolicy` (numpy; what robots run) and so on a torch `LearnedPolicy`, whose
numpy weights are views of its parameters: adopting weights updates the torch network too.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from policies.infer.policy import BadWeights, InferencePolicy
from swarm.net.learning import Weights
from swarm.net.messages import BadMessage
from world.config import WorldConfig


def fresh_checkpoint(policy: str, cfg: WorldConfig, seed: int, path: Path) -> Path:
    """`swarm run --train` without `--checkpoint`: one fresh network (torch seed = run seed)
    saved at `path` for the robots and the learner alike, so every process starts from the same
    version 0."""
    import torch

    from policies import make_policy
    from policies.checkpoint import save_checkpoint

    torch.manual_seed(seed)
    pol = make_policy(policy, cfg)
    save_checkpoint(path, pol.payload({"command": "swarm run --train (initial weights)",
                                       "seed": seed}))
    return path


def weights_of(policy: InferencePolicy, version: int, origin: int = 0) -> Weights:
    return Weights(policy.name, version, dataclasses.asdict(policy.model_cfg),
                   {k: np.array(v, dtype=np.float32) for k, v in policy.weights.items()}, origin)


def adopt(policy: InferencePolicy, w: Weights) -> None:
    """Load `w` into `policy` (see `check_weights`; the policy is unchanged when they don't fit)."""
    check_weights(policy, w)
    policy.load_weights(w.tensors, w.model, f"weights v{w.version}")


def check_weights(policy: InferencePolicy, w: Weights) -> None:
    """A one-line BadMessage if `w` is for another policy or network, or carries tensors of the
    wrong shape or non-finite values."""
    if w.policy != policy.name:
        raise BadMessage(f"weights v{w.version} are for {w.policy!r}, not {policy.name!r}")
    try:
        policy.check_weights(w.tensors, w.model, f"weights v{w.version}")
    except BadWeights as exc:
        raise BadMessage(str(exc)) from None
