"""A learned policy that acts with numpy only: what robot processes run, and the acting half of
every torch `LearnedPolicy` (which subclasses this and adds training), so the batched evaluator,
the trainer's rollouts and a robot decide with the same code.

Acting: features from the View (policies.infer.tokens), the network (policies.infer.nets), then
greedy (argmax) or sampled actions by Gumbel-max with counter-based noise `world.noise.uniform(
seed, episode, tick, robot, 9, stream=0)`: a robot process and the batched evaluator draw the
same action. Chained networks (CommAttn) decode receivers in id order; the batched `decide` runs
the whole chain, a robot calls `act_with_chain` with its predecessor's message.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar, NamedTuple

import numpy as np

from policies.base import Policy
from policies.belief import Belief
from policies.checkpoint import CheckpointError, read_checkpoint
from policies.infer.layers import Weights, softmax
from policies.infer.nets import NETS, Encoded, NumpyCommAttn, NumpyNet, Shapes
from policies.infer.tokens import Featurizer, ModelConfig, Tokens
from world.config import ConfigError, WorldConfig, from_dict
from world.core import N_ACTIONS
from world.decentral import View, predecessor_of, remember
from world.noise import uniform

NO_ACTION = N_ACTIONS
WORLD_SHAPE_KEYS = ("vision", "recent_len")  # world fields that change the token width


class BadWeights(ValueError):
    """Weights that do not fit this policy's network; one line."""


@dataclass
class NetDecision:
    """What a network's batched decision computed, arrays [G, N, ...] (zeros off the
    receivers). Not `policies.base.Decision` (actions, state), the chained plugins' answer:
    this record has more fields and is read by name, never unpacked."""

    actions: np.ndarray  # [G, N] int64
    probs: np.ndarray  # [G, N, 9] float32 action distribution of each receiver
    value: np.ndarray  # [G, N] float32 baseline b(s)
    state: np.ndarray | None  # [G, N, S] decoder states s_i (chained policies), else None
    context: np.ndarray | None  # [G, N, 2H] communication vectors c_i (chained), else None
    inputs: Tokens | None = None  # the features, when kept for training
    attention: np.ndarray | None = None  # [G, N, N] receiver i's attention over ids (chained)


def featurizer(cfg: WorldConfig, model: Any) -> Featurizer:
    """The features a network of config `model` reads."""
    return Featurizer(cfg, crop=model.crop, team_pool=getattr(model, "team_pool", 0),
                      memory=getattr(model, "team_memory", False),
                      belief=getattr(model, "belief", False), hint=getattr(model, "hint", False),
                      hint_planner=getattr(model, "hint_planner", "coordinated-frontier"),
                      hint_search={"beam": getattr(model, "hint_beam", 8),
                                   "passes": getattr(model, "hint_passes", 1)})


def gumbel(view: View, group: np.ndarray, robot: np.ndarray) -> np.ndarray:
    """Gumbel noise [R, 9] float64 of each receiver, from the counter-based generator (stream 0)."""
    u = uniform(view.seed, view.episodes[group], view.tick, robot, N_ACTIONS, stream=0)
    with np.errstate(divide="ignore"):
        return -np.log(-np.log(u))


def chooser(noise: np.ndarray | None) -> Callable[[slice, np.ndarray], np.ndarray]:
    """Greedy argmax (noise None) or Gumbel-max sampling of a block of rows from their logits."""
    if noise is None:
        return lambda rows, logits: logits.argmax(-1)
    return lambda rows, logits: (logits.astype(np.float64) + noise[rows]).argmax(-1)


def check_checkpoint(data: dict[str, Any], path: Path, name: str, cfg: WorldConfig,
                     config_cls: type, net_cls: type[NumpyNet]) -> tuple[Any, dict[str, Any]]:
    """The model config and weights of a checkpoint dict, if they fit policy `name` on `cfg`;
    CheckpointError (one line) otherwise. Weights may be numpy arrays or torch tensors."""
    if data["policy"] != name:
        raise CheckpointError(f"checkpoint {path} holds policy {data['policy']!r}, not {name!r}")
    fields = dict(data["model"])
    fields.setdefault("team_pool", 0)  # checkpoints from before the team map had none
    fields.setdefault("team_memory", False)  # ... and from before the team memory
    try:
        model = from_dict(config_cls, fields, where=f"checkpoint {path} model")
    except ConfigError as exc:
        raise CheckpointError(str(exc)) from None
    for key in WORLD_SHAPE_KEYS:
        theirs, ours = data["world"].get(key), getattr(cfg, key)
        if theirs != ours:
            raise CheckpointError(f"checkpoint {path} was trained with {key}={theirs}, "
                                  f"this world has {key}={ours}")
    try:
        check_shapes(data["state_dict"], shapes_of(cfg, model, net_cls), f"checkpoint {path}",
                     name)
    except BadWeights as exc:
        raise CheckpointError(str(exc)) from None
    return model, data["state_dict"]


def shapes_of(cfg: WorldConfig, model: Any, net_cls: type[NumpyNet]) -> Shapes:
    feats = featurizer(cfg, model)
    return net_cls.shapes(model, feats.member_dim, feats.pair_dim, feats.own_dim)


def check_shapes(weights: dict[str, Any], expected: Shapes, what: str, name: str) -> None:
    """BadWeights unless `weights` has exactly the `expected` names and shapes."""
    for key, shape in expected.items():
        got = weights.get(key)
        if got is None or tuple(got.shape) != tuple(shape):
            have = None if got is None else tuple(got.shape)
            raise BadWeights(f"{what} does not fit {name}: {key} has shape {have}, "
                             f"expected {tuple(shape)}")
    extra = sorted(set(weights) - set(expected))
    if extra:
        raise BadWeights(f"{what} has unexpected weights {', '.join(extra[:3])}")


class _Finished:
    """An attribute of an `InferencePolicy` that a pending chained decision fills in when it is
    first read (`_finish`); setting it drops the pending one."""

    def __set_name__(self, owner: type, name: str) -> None:
        self.slot = f"_{name}"

    def __get__(self, obj: Any, owner: type | None = None) -> Any:
        if obj is None:
            return self
        obj._finish()
        return getattr(obj, self.slot, None)

    def __set__(self, obj: Any, value: np.ndarray | None) -> None:
        obj._finish()
        setattr(obj, self.slot, value)


class InferencePolicy(Policy):
    """A learned network behind the Policy interface, acting in numpy. Subclasses set `name`;
    `config_cls` and `numpy_cls` come from policies.infer.nets.NETS."""

    learned = True
    owns_weights = True
    """The numpy weights change only through `load_weights` (so the network may keep arrays
    derived from them); False where they are views of torch parameters (LearnedPolicy)."""
    config_cls: ClassVar[type]
    numpy_cls: ClassVar[type[NumpyNet]]

    def __init__(self, cfg: WorldConfig, checkpoint: str | Path | None = None,
                 model: Any | None = None) -> None:
        super().__init__(cfg)
        weights = None
        self.meta: dict[str, Any] = {}
        if checkpoint is not None:
            data = self.read(checkpoint)
            model, weights = check_checkpoint(data, Path(checkpoint), self.name, cfg,
                                              self.config_cls, self.numpy_cls)
            self.meta = dict(data.get("meta", {}))
        self._after: tuple[View, Tokens, Any] | None = None  # act_with_chain's extras, lazily
        self.last_probs = None  # [G, N, 9] of the last decision
        self.last_attention = None  # see act_with_chain
        self.model_cfg: ModelConfig = model if model is not None else self.config_cls()
        self.features = featurizer(cfg, self.model_cfg)
        self.np = self.numpy_cls(self.model_cfg, self.build(weights), keep=self.owns_weights)
        self.belief = Belief(cfg)  # folded only for networks that read it (model.belief)
        self.team = self.belief.team  # the team memory alone, for networks without the belief

    # ------------------------------------------------------------- weights
    def read(self, checkpoint: str | Path) -> dict[str, Any]:
        """The checkpoint dict (numpy arrays; no torch)."""
        return read_checkpoint(checkpoint)

    def build(self, weights: dict[str, Any] | None) -> Weights:
        """The numpy weight dict the network computes with (zeros without a checkpoint)."""
        shapes = shapes_of(self.cfg, self.model_cfg, self.numpy_cls)
        if weights is None:
            return {k: np.zeros(s, dtype=np.float32) for k, s in shapes.items()}
        return {k: np.ascontiguousarray(weights[k], dtype=np.float32) for k in shapes}

    @property
    def weights(self) -> Weights:
        """The arrays the network computes with, by torch state_dict name."""
        return self.np.w

    def check_weights(self, tensors: dict[str, np.ndarray], model: dict[str, Any],
                      what: str) -> None:
        """BadWeights (one line) if `tensors` are for another network config, do not have this
        network's names and shapes, or are not finite."""
        ours = dataclasses.asdict(self.model_cfg)
        if {k: model.get(k) for k in ours} != ours:
            raise BadWeights(f"{what} are for another {self.name} network ({model})")
        if set(tensors) != set(self.weights):
            odd = sorted(set(tensors) ^ set(self.weights))[:3]
            raise BadWeights(f"{what} have tensors {odd} that do not fit")
        check_shapes(tensors, {k: v.shape for k, v in self.weights.items()}, what, self.name)
        for k, v in tensors.items():
            if not np.isfinite(v).all():
                raise BadWeights(f"{what}: {k} is not finite")

    def load_weights(self, tensors: dict[str, np.ndarray], model: dict[str, Any],
                     what: str = "weights") -> None:
        """Copy checked `tensors` into the network in place (unchanged when they don't fit)."""
        self.check_weights(tensors, model, what)
        for k, v in tensors.items():
            np.copyto(self.weights[k], v, casting="same_kind")
        self.np.forget()

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
        self.np.cfg = model

    def reset(self, groups: int) -> None:
        if self.features.belief:
            self.belief.reset(groups)  # (its team memory included)
        else:
            self.team.reset(groups)

    def remember(self, view: View) -> None:
        """Fold the view into the receivers' team memory (and belief maps) and attach them
        (networks that read them)."""
        if self.features.belief:
            if view.belief is None:
                view.belief = self.belief.snapshot(view)  # its team memory is the same fold
                view.team_visited = self.belief.visited
        elif self.features.memory and view.team_visited is None:
            view.team_visited = self.team.update(view)

    def remember_episode(self, views: list[View]) -> None:
        """Set the memories of a recorded episode batch's views (tick order, the same groups in
        each) by folding them through fresh ones: what the acting robots computed."""
        if self.features.belief:
            belief = Belief(self.cfg)
            for view in views:
                view.belief = belief.snapshot(view)
                view.team_visited = belief.visited
        elif self.features.memory:
            remember(views, self.cfg)

    @property
    def plan_hint(self) -> Any:
        """The `chain-plan` hint planner of a chained network that reads it, else None: its
        chain runs beside the network's, so its plan rides in the hidden-state message after
        the decoder state."""
        hint = self.features.hint
        return hint if self.chained and getattr(hint, "name", "") == "chain-plan" else None

    @property
    def state_size(self) -> int:
        """Floats in a hidden-state message (chained policies): the decoder state, then the
        plan of a `chain-plan` hint."""
        if not self.chained:
            return 0
        plan = self.plan_hint
        return self.model_cfg.state + (0 if plan is None else plan.state_size)  # type: ignore[attr-defined]

    def state_ok(self, state: np.ndarray, tick: int) -> bool:
        plan = self.plan_hint
        return plan is None or plan.state_ok(
            np.asarray(state)[self.model_cfg.state:], tick)  # type: ignore[attr-defined]

    def _with_plans(self, state: np.ndarray, group: np.ndarray, robot: np.ndarray) -> np.ndarray:
        """Decoder states [R, S] followed by the plan each receiver's hint chain sent."""
        plan = self.plan_hint
        if plan is None:
            return state
        return np.concatenate([state, np.stack([plan.encode(plan.last_sent[(int(g), int(i))])
                                                for g, i in zip(group, robot, strict=True)])
                               if len(group) else np.zeros((0, plan.state_size), np.float32)],
                              axis=1)

    # ------------------------------------------------------------- acting
    def act(self, view: View, greedy: bool = True) -> np.ndarray:
        return self.decide(view, greedy).actions

    def decide(self, view: View, greedy: bool = True, keep_inputs: bool = False) -> NetDecision:
        """Actions, values and (chained) decoder states of every receiver of the view;
        `keep_inputs` keeps the features for a later `evaluate` (the trainer)."""
        self.remember(view)
        tokens = self.features(view)
        g, i = tokens.group, tokens.robot
        choose = chooser(None if greedy else gumbel(view, g, i))
        shape = view.receivers.shape
        actions = np.zeros(shape, dtype=np.int64)
        probs = np.zeros(shape + (N_ACTIONS,), dtype=np.float32)
        value = np.zeros(shape, dtype=np.float32)
        kept = tokens if keep_inputs else None
        if not self.chained:
            logits, v = self.np.forward(tokens)
            actions[g, i] = choose(slice(None), logits)
            probs[g, i] = softmax(logits)
            value[g, i] = v
            self.last_probs = probs
            return NetDecision(actions, probs, value, None, None, kept)
        net: NumpyCommAttn = self.np  # type: ignore[assignment]
        pred = pred_rows([view], tokens)
        if (pred == -2).any():
            raise ValueError("a receiver's predecessor is not a receiver of this view; "
                             "use act_with_chain with the predecessor's hidden-state message")
        out, a = net.chain(net.encode(tokens), i, pred, choose)
        actions[g, i] = a
        probs[g, i] = softmax(out.logits)
        value[g, i] = out.value
        self.last_probs = probs
        state = np.zeros(shape + (self.state_size,), dtype=np.float32)
        state[g, i] = self._with_plans(out.state, g, i)
        context = np.zeros(shape + (out.context.shape[1],), dtype=np.float32)
        context[g, i] = out.context
        return NetDecision(actions, probs, value, state, context, kept,
                        attention_by_id(view, tokens, out.alpha))

    # The probabilities and attention of a robot's chained decision are computed when first read,
    # after its hidden-state message has gone out (they are off the chain's critical path).
    last_probs = _Finished()
    last_attention = _Finished()

    def _finish(self) -> None:
        if self._after is None:
            return
        (view, tokens, out), self._after = self._after, None
        self._last_probs = np.zeros(view.receivers.shape + (N_ACTIONS,), dtype=np.float32)
        self._last_probs[tokens.group, tokens.robot] = softmax(out.logits)
        order = np.argsort(tokens.group, kind="stable")  # (robots in order within a group)
        att = attention_by_id(view, tokens, out.alpha)[tokens.group, tokens.robot][order]
        self._last_attention = att[0] if view.groups == 1 else att

    def prepare_chain(self, view: View, greedy: bool = True) -> Prepared:
        """The part of `act_with_chain` that needs no predecessor (features, the encoder, each
        receiver's predecessor and its sampling noise), so a robot process computes it while it
        waits for its predecessor's message."""
        if not self.chained:
            raise TypeError(f"{self.name} is not a chained policy")
        if (view.receivers.sum(1) != 1).any():
            raise ValueError("act_with_chain needs exactly one receiver per group")
        self.remember(view)
        if self.plan_hint is not None:  # its hint needs the predecessor's plan: later
            g, i = np.nonzero(view.receivers)  # (group order: one receiver per group)
            return Prepared(view, None, None, predecessor_of(view.hears[g, i], i), greedy, None)
        tokens = self.features(view)
        pred = predecessor_of(view.hears[tokens.group, tokens.robot], tokens.robot)
        noise = None if greedy else gumbel(view, tokens.group, tokens.robot)
        return Prepared(view, tokens, self.np.encode(tokens), pred,  # type: ignore[attr-defined]
                        greedy, noise)

    def _plan_features(self, prepared: Prepared, pred_state: np.ndarray | None) -> Prepared:
        """`prepare_chain`'s features for a network with a `chain-plan` hint, once the
        predecessors' plans (after their decoder states in `pred_state`) are known."""
        hint, s, view = self.plan_hint, self.model_cfg.state, prepared.view  # type: ignore[attr-defined]
        g, i = np.nonzero(view.receivers)  # one receiver per group
        p = predecessor_of(view.hears[g, i], i)
        if view.chain_ok is not None:
            p = np.where(view.chain_ok[g, i], p, -1)
        given = {}
        for k in np.flatnonzero(p >= 0):
            if pred_state is None:
                raise ValueError("a receiver has a predecessor but no hidden-state message "
                                 "was given")
            row = np.asarray(pred_state, np.float32).reshape(view.groups, -1)[g[k]]
            plan = hint.decode(row[s:], view.tick)
            if plan is None:
                raise ValueError("the predecessor's plan fails its checks (state_ok)")
            given[(int(g[k]), int(p[k]))] = plan
        hint.given = given
        try:
            tokens = self.features(view)
        finally:
            hint.given = {}
        pred = predecessor_of(view.hears[tokens.group, tokens.robot], tokens.robot)
        noise = None if prepared.greedy else gumbel(view, tokens.group, tokens.robot)
        return prepared._replace(tokens=tokens, encoded=self.np.encode(tokens),  # type: ignore[attr-defined]
                                 pred=pred, noise=noise)

    def act_with_chain(self, view: View, pred_state: np.ndarray | None,
                       pred_action: np.ndarray | None, greedy: bool = True,
                       prepared: Prepared | None = None,
                       ) -> tuple[np.ndarray, np.ndarray]:
        """One receiver per group given its predecessor's hidden-state message.

        pred_state [G, S] float32 and pred_action [G] int (rows of receivers without a
        predecessor are ignored; pass None when no receiver has one). Returns actions [G, N]
        and the receivers' new states [G, S] (their own hidden-state messages). `prepared` is
        `prepare_chain(view, greedy)` computed earlier (the same view; its chain_ok may be set
        since). Sets `last_probs` [G, N, 9] and `last_attention`, each group's receiver's
        attention over robot ids ([G, N]; [N] when there is one group, as in a robot process).
        """
        if prepared is None or prepared.greedy != greedy:
            if prepared is not None and prepared.view is not view:
                raise ValueError("prepared for another view")
            prepared = self.prepare_chain(view, greedy) if prepared is None else \
                prepared._replace(greedy=greedy) if prepared.tokens is None else \
                prepared._replace(greedy=greedy, noise=None if greedy else gumbel(
                    view, prepared.tokens.group, prepared.tokens.robot))
        elif prepared.view is not view:
            raise ValueError("prepared for another view")
        if prepared.tokens is None:
            prepared = self._plan_features(prepared, pred_state)
        tokens, p = prepared.tokens, prepared.pred
        net: NumpyCommAttn = self.np  # type: ignore[assignment]
        if view.chain_ok is not None:  # lost or late hidden-state message: no predecessor
            p = np.where(view.chain_ok[tokens.group, tokens.robot], p, -1)
        has = p >= 0
        s_prev = np.repeat(net.w["s0"][None, :], len(p), axis=0)
        a_prev = np.full(len(p), NO_ACTION, dtype=np.int64)
        if has.any():
            if pred_state is None or pred_action is None:
                raise ValueError("a receiver has a predecessor but no hidden-state message "
                                 "was given")
            ps = np.asarray(pred_state, dtype=np.float32).reshape(view.groups, -1)[tokens.group]
            ps = ps[:, :self.model_cfg.state] if self.plan_hint is not None else ps  # type: ignore[attr-defined]
            pa = np.asarray(pred_action, dtype=np.int64).reshape(view.groups)[tokens.group]
            if ((pa < 0) | (pa >= N_ACTIONS))[has].any():
                raise ValueError("predecessor action must lie in 0..8")
            if ps.shape[1] != s_prev.shape[1]:
                raise ValueError(f"predecessor state has {ps.shape[1]} floats, "
                                 f"expected {s_prev.shape[1]}")
            s_prev = np.where(has[:, None], ps, s_prev)
            a_prev = np.where(has, pa, a_prev)
        out = net.decode(prepared.encoded, s_prev, a_prev, value=False)  # (acting: no baseline)
        a = chooser(prepared.noise)(slice(None), out.logits)
        actions = np.zeros(view.receivers.shape, dtype=np.int64)
        actions[tokens.group, tokens.robot] = a
        self._after = (view, tokens, out)
        state = self._with_plans(out.state, tokens.group, tokens.robot)
        state = state if view.groups == 1 else state[np.argsort(tokens.group, kind="stable")]
        return actions, state.copy()


class Prepared(NamedTuple):
    """`prepare_chain`'s output: what a chained decision needs before the predecessor speaks."""

    view: View
    tokens: Tokens | None  # None (and encoded, noise) until a chain-plan hint has its plan
    encoded: Encoded | None
    pred: np.ndarray  # [R] each receiver's predecessor id (-1: none), chain_ok not applied
    # (in group order while tokens is None)
    greedy: bool
    noise: np.ndarray | None  # [R, 9] Gumbel noise when sampling


def attention_by_id(view: View, tokens: Tokens, alpha: np.ndarray) -> np.ndarray:
    """Attention [G, N, N] of receiver (g, i) over member ids j from per-slot weights [R, M]."""
    groups, n = view.receivers.shape
    out = np.zeros((groups, n, n), dtype=np.float32)
    idx, mask = tokens.pad_index(0)
    member = tokens.pair_member[idx] % n  # [R, M] id of each slot's member
    r = np.broadcast_to(np.arange(tokens.receivers)[:, None], mask.shape)[mask]
    out[tokens.group[r], tokens.robot[r], member[mask]] = alpha[:, :mask.shape[1]][mask]
    return out


def pred_rows(views: list[View], tokens: Tokens) -> np.ndarray:
    """Row of each receiver's predecessor: -1 none, -2 a predecessor that is not a receiver."""
    # a predecessor whose hidden-state message was lost or late counts as none (chain_ok)
    pred_id = np.concatenate([np.where(v.chain_ok, v.predecessor(), -1)
                              if v.chain_ok is not None else v.predecessor()
                              for v in views])  # [G_total, N]
    n = pred_id.shape[1]
    row_of = np.full(pred_id.shape, -2, dtype=np.int64)
    row_of[tokens.group, tokens.robot] = np.arange(tokens.receivers)
    p = pred_id[tokens.group, tokens.robot]
    return np.where(p >= 0, row_of[tokens.group, np.clip(p, 0, n - 1)], -1)


def inference_class(name: str) -> type[InferencePolicy]:
    """The torch-free policy class of learned policy `name`."""
    if name not in NETS:
        raise ValueError(f"{name!r} is not a learned policy")
    config_cls, numpy_cls = NETS[name]
    return type(f"{numpy_cls.__name__}Policy", (InferencePolicy,),
                {"name": name, "chained": numpy_cls.chained, "config_cls": config_cls,
                 "numpy_cls": numpy_cls})
