"""The belief features of the learned networks (model field `belief`): the windows of a
receiver's belief map against a plain search, a robot's rows against the batch's, the learner's
refold against acting, and a checkpoint widened to read them acting exactly as before."""

from __future__ import annotations

import json
from collections import deque
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
import torch
from conftest import ROOT, swarm

from policies import make_policy
from policies.belief import BLOCK, Belief
from policies.infer.policy import pred_rows
from policies.infer.tokens import BELIEF_CAP, Featurizer
from swarm.learn.config import TrainConfig
from world import core
from world.config import ConfigError, WorldConfig
from world.decentral import batch_view, heard_by, robot_view

CKPT = ROOT / "checkpoints" / "commattn.pt"


def played(cfg: WorldConfig, groups: int, ticks: int, seed: int = 3) -> list:
    """Views of `ticks` ticks of random play (a belief needs a history)."""
    state = core.reset(cfg, seed, np.arange(groups))
    rng = np.random.default_rng(seed)
    views = []
    for _ in range(ticks):
        views.append(batch_view(cfg, state))
        core.step(cfg, state, rng.integers(0, 9, (groups, cfg.n_robots)))
    return views


def assert_refold_acts_as_kept(learner: object, roll: object) -> None:
    """The learner's refold of a rollout's views (swarm.learn.join: the memories folded
    afresh, then the features) gives the own features kept when the rollout acted."""
    for view in roll.views:  # type: ignore[attr-defined]
        view.belief = view.team_visited = None
    learner.remember_episode(roll.views)  # type: ignore[attr-defined]
    for view, kept in zip(roll.views, roll.inputs, strict=True):  # type: ignore[attr-defined]
        np.testing.assert_array_equal(learner.features(view).own_feats,  # type: ignore[attr-defined]
                                      kept.own_feats)


def hinted(cfg: WorldConfig, feats: Featurizer, planner: object, ticks: int) -> Iterator:
    """(the view, the planner's actions [G, N], the tokens, their 9 hint bits) at every tick
    of 2 groups' random play, the hint computed on the belief the batch folds."""
    batch = Belief(cfg)
    planner.reset(2)  # type: ignore[attr-defined]
    for view in played(cfg, 2, ticks):
        acted = planner.act(view)  # type: ignore[attr-defined]
        view.belief = batch.snapshot(view)
        view.team_visited = batch.visited
        t = feats(view)
        yield view, acted, t, t.own_feats[:, -9:]


def plain_windows(known: np.ndarray, explored: np.ndarray, cell: tuple[int, int],
                  crop: int) -> np.ndarray:
    """The two windows by loops: known blocks, and the 8-neighbour path length from the nearest
    target (not explored, not a block) through non-block cells, capped and scaled."""
    h, w = known.shape
    block = known == BLOCK
    passable = ~block
    passable[cell] = True
    dist = np.full((h, w), 10**6)
    todo: deque[tuple[int, int]] = deque()
    for y in range(h):
        for x in range(w):
            if not explored[y, x] and not block[y, x]:
                dist[y, x] = 0
                todo.append((y, x))
    while todo:
        y, x = todo.popleft()
        for dy in (-1, 0, 1):
            for dx in (-1, 0, 1):
                v, u = y + dy, x + dx
                if 0 <= v < h and 0 <= u < w and passable[v, u] and dist[v, u] > dist[y, x] + 1:
                    dist[v, u] = dist[y, x] + 1
                    todo.append((v, u))
    half = crop // 2
    out = np.full((2, crop, crop), -1.0, dtype=np.float32)
    for a in range(crop):
        for b in range(crop):
            y, x = cell[0] + a - half, cell[1] + b - half
            if 0 <= y < h and 0 <= x < w:
                out[0, a, b] = float(block[y, x])
                out[1, a, b] = min(dist[y, x], BELIEF_CAP) / BELIEF_CAP
    return out.reshape(-1)


@pytest.mark.parametrize("size", [(20, 20), (13, 27)])
def test_belief_windows_equal_a_plain_search(size: tuple[int, int]) -> None:
    cfg = WorldConfig(height=size[0], width=size[1], n_robots=6, n_static=40, n_dynamic=30,
                      comm_range=6.0)
    feats = Featurizer(cfg, crop=9, team_pool=3, memory=True, belief=True)
    belief = Belief(cfg)
    for view in played(cfg, 2, 14):
        view.belief = belief.snapshot(view)
        view.team_visited = belief.visited
    t = feats(view)
    snap = view.belief
    assert t.own_feats.shape[1] == feats.own_dim
    for k, (g, i) in enumerate(zip(t.group.tolist(), t.robot.tolist(), strict=True)):
        row = int(np.flatnonzero((snap.g == g) & (snap.i == i))[0])
        cell = tuple(int(c) for c in view.msgs.pos[g, i])
        want = plain_windows(snap.known[row], snap.explored[row], cell, 9)
        np.testing.assert_array_equal(t.own_feats[k, -2 * 81:], want)


def test_belief_needs_the_team_map_and_its_memory(tmp_path: Path) -> None:
    from policies.infer.nets import CommAttnConfig

    with pytest.raises(ConfigError, match="belief features need"):
        Featurizer(WorldConfig(), team_pool=3, memory=False, belief=True)
    with pytest.raises(ConfigError, match="model belief needs"):  # however the config came
        CommAttnConfig(belief=True, team_pool=0)
    with pytest.raises(ConfigError, match="widens an --init"):
        TrainConfig(belief=True)
    # a field learner does not widen (nor imitate): one line, exit 2, nothing spawned
    toml = tmp_path / "run.toml"
    toml.write_text('[train]\nbelief = true\ninit = "checkpoints/commattn.pt"\n')
    r = swarm("run", "--train", "--headless", "--policy", "commattn", "--config", str(toml),
              timeout=60)
    assert r.returncode == 2 and "only `swarm train`" in r.stderr, r.stderr
    assert len(r.stderr.strip().splitlines()) == 1


@pytest.mark.parametrize("hint", ["", "coordinated-frontier", "team-beam"])
def test_a_robots_belief_tokens_are_its_rows_of_the_batch(hint: str) -> None:
    """Each robot folding only what it heard, tick by tick, computes its rows of the batch
    (with the hint: coordinated frontier, or team-beam planning its heard team, run on its own
    belief)."""
    cfg = WorldConfig(comm_range=5.0)
    feats = Featurizer(cfg, crop=9, team_pool=3, memory=True, belief=True, hint=bool(hint),
                       **({"hint_planner": hint} if hint else {}))
    views = played(cfg, 1, 12)
    batch = Belief(cfg)
    mine = [Belief(cfg) for _ in range(cfg.n_robots)]
    for view in views:
        own = []
        for i in range(cfg.n_robots):
            rv = robot_view(cfg, view.seed, 0, view.tick, i, heard_by(cfg, view, 0, i), 0.0)
            rv.belief = mine[i].snapshot(rv)
            rv.team_visited = mine[i].visited
            own.append(feats(rv).own_feats[0])
        view.belief = batch.snapshot(view)
        view.team_visited = batch.visited
        t = feats(view)
        for k, i in enumerate(t.robot.tolist()):
            np.testing.assert_array_equal(own[i], t.own_feats[k])


def test_hint_without_the_belief_is_one_line_and_leaves_no_folder(tmp_path: Path) -> None:
    from swarm.learn.trainer import main

    out = tmp_path / "run"
    with pytest.raises(ConfigError, match="model hint needs the belief"):
        main(TrainConfig(policy="commattn", init=str(CKPT), hint=True, threads=1), WorldConfig(),
             out)
    assert not out.exists()


def test_hint_needs_the_belief_and_is_coordinated_frontiers_moves() -> None:
    """The hint bits of a receiver are the moves coordinated frontier, on the same belief map,
    would start toward its target: its own action is one of them (unless it shares its cell:
    then it steps off the path, policies.nearest_frontier.pick)."""
    from policies.infer.nets import CommAttnConfig

    with pytest.raises(ConfigError, match="hint features need the belief"):
        Featurizer(WorldConfig(), team_pool=3, memory=True, hint=True)
    with pytest.raises(ConfigError, match="model hint needs the belief"):
        CommAttnConfig(hint=True)
    with pytest.raises(ConfigError, match="widens an --init"):
        TrainConfig(hint=True)
    cfg = WorldConfig(comm_range=5.0)
    feats = Featurizer(cfg, crop=9, team_pool=3, memory=True, belief=True, hint=True)
    some = 0
    for view, acted, t, bits in hinted(cfg, feats, make_policy("coordinated-frontier", cfg), 12):
        assert set(np.unique(bits)) <= {0.0, 1.0}
        has = bits.any(axis=1)
        some += int(has.sum())
        chosen = acted[t.group, t.robot]
        pos = view.msgs.pos[t.group]  # (a robot sharing its cell steps off the path instead)
        alone = (pos == pos[np.arange(len(chosen)), t.robot][:, None]).all(-1).sum(1) == 1
        assert (bits[np.arange(len(chosen)), chosen][has & alone] == 1).all()
    assert some > 100  # (most receivers have a target)


@pytest.mark.parametrize("light", [True, False])
def test_a_team_beam_hint_is_the_one_move_team_beam_takes(light: bool) -> None:
    """`hint_planner` "team-beam": the 9 hint bits are one-hot, at the move `team-beam` (with
    the hint's light search) takes on the same belief; a bad planner name is one line, and
    `swarm train --hint-planner` needs an --init checkpoint."""
    from policies.central import CentralConfig
    from policies.infer.nets import CommAttnConfig
    from policies.infer.tokens import HINT_BEAM
    from policies.team_beam import TeamBeam

    with pytest.raises(ConfigError, match="hint_planner must be one of"):
        CommAttnConfig(belief=True, hint=True, hint_planner="oracle")
    with pytest.raises(ConfigError, match="hint_passes must be an integer in"):
        CommAttnConfig(belief=True, hint=True, hint_planner="team-beam", hint_passes=5)
    with pytest.raises(ConfigError, match="hint_planner must be one of"):
        TrainConfig(init=str(CKPT), hint_planner="central")
    with pytest.raises(ConfigError, match="a fresh network takes --model"):
        TrainConfig(hint_planner="team-beam")
    cfg = WorldConfig(comm_range=5.0)
    search = HINT_BEAM if light else {"beam": 24, "passes": 2}  # (the latter: team-beam's own)
    feats = Featurizer(cfg, crop=9, team_pool=3, memory=True, belief=True, hint=True,
                       hint_planner="team-beam", hint_search=search)
    planner = TeamBeam(cfg, CentralConfig(**search)) if light else make_policy("team-beam", cfg)
    moved = 0
    for _view, acted, t, bits in hinted(cfg, feats, planner, 10):
        np.testing.assert_array_equal(bits.sum(1), 1.0)
        np.testing.assert_array_equal(bits.argmax(1), acted[t.group, t.robot])
        moved += int((bits.argmax(1) != 0).sum())
    assert moved > 100


def test_a_chain_plan_hint_is_chain_plans_move() -> None:
    """`hint_planner` "chain-plan": the 9 hint bits are one-hot at the move `chain-plan` (its
    chain run over the batch, the light search of beam 8 and one round: ChainConfig(1, 8, 0,
    8)) takes on the same views; beam 32 and 4 passes are `chain-plan`'s own search."""
    from policies.chain_plan import ChainConfig, ChainPlan
    from policies.infer.tokens import HINT_BEAM, chain_search

    assert ChainConfig(**chain_search(32, 4)) == ChainConfig()  # the full search is chain-plan's
    cfg = WorldConfig(comm_range=5.0)
    feats = Featurizer(cfg, crop=9, team_pool=3, memory=True, belief=True, hint=True,
                       hint_planner="chain-plan", hint_search=HINT_BEAM)
    moved = 0
    for _view, acted, t, bits in hinted(cfg, feats, ChainPlan(cfg, ChainConfig(1, 8, 0, 8)), 8):
        np.testing.assert_array_equal(bits.sum(1), 1.0)
        np.testing.assert_array_equal(bits.argmax(1), acted[t.group, t.robot])
        moved += int((bits.argmax(1) != 0).sum())
    assert moved > 80
    # a chained network with it sends its decoder state, then the plan; a robot checks both
    from policies.infer.nets import CommAttnConfig
    from policies.infer.policy import inference_class

    net = inference_class("commattn")(cfg, model=CommAttnConfig(
        belief=True, hint=True, hint_planner="chain-plan"))
    view = played(cfg, 1, 4)[-1]
    state = net.decide(view).state[0]
    assert state.shape == (cfg.n_robots, 64 + cfg.n_robots * 7)
    for i in range(cfg.n_robots):
        assert net.state_ok(state[i], view.tick)
        bad = state[i].copy()
        bad[64 + 1] = cfg.cells  # its first row's first cell off the grid
        assert not net.state_ok(bad, view.tick)


@pytest.mark.parametrize("changes", [{"belief": True}, {"belief": True, "hint": True}])
def test_a_widened_checkpoint_acts_as_before_and_numpy_equals_torch(changes: dict) -> None:
    """`widen(belief=True)` (and `hint`) adds zero columns: the same actions as the checkpoint;
    with the new weights moved, the numpy and torch networks still agree, and the learner's
    refold of a recorded episode gives the features the robots acted on."""
    from swarm.learn.evaluate import evaluate
    from swarm.learn.rollout import collect

    cfg = WorldConfig()
    base = make_policy("commattn", cfg, checkpoint=str(CKPT))
    wide = make_policy("commattn", cfg, checkpoint=str(CKPT))
    wide.widen(**changes)
    extra = 2 * 81 + (9 if changes.get("hint") else 0)
    assert wide.features.own_dim == base.features.own_dim + extra
    a = evaluate(cfg, base, 0, 6, record_actions=True)
    b = evaluate(cfg, wide, 0, 6, record_actions=True)
    assert np.array_equal(a.actions, b.actions)
    with torch.no_grad():
        own = wide.net.embed.own.weight
        own[:, base.features.own_dim:] = 0.05 * torch.randn(  # a trained layer's scale
            own.shape[0], extra, generator=torch.Generator().manual_seed(0))
    view = played(cfg, 2, 10)[-1]
    wide.reset(2)
    logits_t, _ = wide.torch_logits(view)
    view = played(cfg, 2, 10)[-1]
    wide.reset(2)
    wide.remember(view)
    tok = wide.features(view)
    out, _ = wide.np.chain(wide.np.encode(tok), tok.robot, pred_rows([view], tok),
                           lambda rows, lg: lg.argmax(-1))
    np.testing.assert_allclose(out.logits, logits_t.numpy(), rtol=1e-5, atol=1e-5)
    roll = collect(wide, cfg, 7, np.arange(2))
    with torch.no_grad():
        ev = wide.evaluate(roll.views, roll.actions, roll.inputs)
    # (float32 sums in two orders: ~1e-6 typical, the largest of ~600 decisions near 1e-5)
    assert np.abs(ev.logp.numpy() - roll.logp[ev.tick, ev.group, ev.robot]).max() < 2e-5
    assert_refold_acts_as_kept(wide, roll)


def test_robots_passing_a_chain_plan_hint_on_decide_as_the_batch() -> None:
    """A network with `chain-plan`'s hint, one policy per robot deciding in id order from its
    own view and its predecessor's message (decoder state, then plan), sampled (its prepare
    made greedy, as a robot process may), gives the batch's actions and messages."""
    from policies.infer.nets import CommAttnConfig
    from policies.infer.policy import inference_class

    cfg = WorldConfig(n_robots=5)
    model = CommAttnConfig(belief=True, hint=True, hint_planner="chain-plan", hint_prior=1.5)
    make = inference_class("commattn")
    batch, robots = make(cfg, model=model), [make(cfg, model=model) for _ in range(5)]
    chained = 0
    for view in played(cfg, 1, 7, seed=4):
        want = batch.decide(view, greedy=False)
        sent: dict[int, tuple[np.ndarray, int]] = {}
        for i in range(cfg.n_robots):
            rv = robot_view(cfg, view.seed, 0, view.tick, i, heard_by(cfg, view, 0, i), 0.0)
            prepared = robots[i].prepare_chain(rv, greedy=True)
            p = int(prepared.pred[0])
            state, action = sent[p] if p >= 0 else (None, None)
            chained += p >= 0
            acts, out = robots[i].act_with_chain(
                rv, None if p < 0 else state[None], None if p < 0 else np.array([action]),
                greedy=False, prepared=prepared)
            sent[i] = (out[0], int(acts[0, i]))
            assert acts[0, i] == want.actions[0, i]
            np.testing.assert_array_equal(out[0], want.state[0, i])
    assert chained > 10


def test_a_learners_refold_of_a_chain_plan_hint_gives_the_acting_features() -> None:
    """The learner rebuilds a recorded episode's features on a fresh network (swarm.learn.join:
    remember_episode, then the features tick by tick): with `chain-plan`'s hint, whose head
    warm-starts from the plan it sent last tick, they equal the ones the batch acted on, under
    lost hidden-state messages too (chain_ok)."""
    from swarm.learn.rollout import collect
    from swarm.net.faults import plan_from_table

    cfg = WorldConfig(n_robots=5)

    def network() -> object:
        pol = make_policy("commattn", cfg, checkpoint=str(CKPT))
        pol.widen(belief=True, hint=True)
        pol.set_model(hint_planner="chain-plan", hint_prior=2.0)
        return pol

    faults = plan_from_table({"loss": 0.3, "seed": 2}, 2)
    roll = collect(network(), cfg, 9, np.arange(2), faults=faults)
    assert any(v.chain_ok is not None and not v.chain_ok.all() for v in roll.views)
    learner = network()
    assert_refold_acts_as_kept(learner, roll)


def test_a_hint_prior_adds_to_the_hinted_logits_in_numpy_torch_and_training() -> None:
    """Model field `hint_prior`: the numpy network's logits are the prior-free ones plus the
    prior on the hint bits, the torch network's equal them, the trainer's log-probs equal the
    acting ones, a prior of 64 makes every greedy move a hinted one; bad values are one line."""
    from policies.infer.nets import CommAttnConfig
    from swarm.learn.rollout import collect

    for bad in (-1.0, 65, float("nan"), True, "8"):
        with pytest.raises(ConfigError, match="hint_prior must be a number in"):
            CommAttnConfig(belief=True, hint=True, hint_prior=bad)
    with pytest.raises(ConfigError, match="hint_prior sets an --init checkpoint's"):
        TrainConfig(hint_prior=8)
    with pytest.raises(ConfigError, match="hint_prior must be -1"):
        TrainConfig(init=str(CKPT), hint_prior=70)
    cfg = WorldConfig()
    pol = make_policy("commattn", cfg, checkpoint=str(CKPT))
    pol.widen(belief=True, hint=True)
    with torch.no_grad():
        own = pol.net.embed.own.weight
        own[:, -9:] = 0.05 * torch.randn(own.shape[0], 9,
                                         generator=torch.Generator().manual_seed(1))
    view = played(cfg, 2, 10)[-1]

    def logits(prior: float, forced: bool = True) -> tuple[np.ndarray, ...]:
        pol.set_model(hint_prior=prior)
        pol.reset(2)
        pol.remember(view)
        tok = pol.features(view)
        pick = (lambda rows, lg: np.zeros(len(lg), dtype=np.int64)) if forced else \
            (lambda rows, lg: lg.argmax(-1))
        out, acts = pol.np.chain(pol.np.encode(tok), tok.robot, pred_rows([view], tok), pick)
        return out.logits, acts, tok.own_feats[:, -9:]

    plain, _, bits = logits(0.0)
    assert bits.sum() > 0
    with_prior, _, _ = logits(2.5)
    np.testing.assert_allclose(with_prior, plain + 2.5 * bits, rtol=1e-5, atol=1e-5)
    greedy, acts, bits = logits(2.5, forced=False)
    pol.reset(2)
    logits_t, _ = pol.torch_logits(view)
    np.testing.assert_allclose(greedy, logits_t.numpy(), rtol=1e-5, atol=1e-5)
    roll = collect(pol, cfg, 7, np.arange(2))
    with torch.no_grad():
        ev = pol.evaluate(roll.views, roll.actions, roll.inputs)
    assert np.abs(ev.logp.numpy() - roll.logp[ev.tick, ev.group, ev.robot]).max() < 2e-5
    _, acts, bits = logits(64.0, forced=False)
    assert bits[np.arange(len(acts)), acts].all()


def test_widen_refuses_other_changes_and_leaves_the_network_alone() -> None:
    cfg = WorldConfig()
    pol = make_policy("commattn", cfg, checkpoint=str(CKPT))
    before = {k: v.clone() for k, v in pol.net.state_dict().items()}
    with pytest.raises(ConfigError, match="would change gru"):
        pol.widen(hidden=48)
    assert not pol.model_cfg.belief and pol.model_cfg.hidden == 32
    for k, v in pol.net.state_dict().items():
        assert torch.equal(v, before[k])


@pytest.mark.procs
@pytest.mark.parametrize("changes", [{"belief": True, "hint": True},  # (belief alone: in both)
                                     {"belief": True, "hint": True, "planner": "chain-plan"}])
def test_a_belief_network_in_the_swarm_equals_the_batched_eval(tmp_path: Path,
                                                               changes: dict) -> None:
    """Robot processes fold their own belief maps from what they heard (and run coordinated
    frontier on them for the hint; or `chain-plan`, its plan riding in the hidden-state message
    after the decoder state, with a hint_prior): a widened checkpoint whose new weights matter
    acts in the swarm exactly as in the batched evaluator (sampled, so every probability
    counts)."""
    from policies.checkpoint import save_checkpoint
    from swarm.learn.evaluate import evaluate

    cfg = WorldConfig(n_robots=6)
    changes = dict(changes)
    planner = changes.pop("planner", None)
    pol = make_policy("commattn", cfg, checkpoint=str(CKPT))
    pol.widen(**changes)
    if planner:
        pol.set_model(hint_planner=planner, hint_prior=3.0)
        assert pol.state_size == 64 + 6 * (2 + 5)  # the decoder state, then the plan
    extra = 162 + (9 if changes.get("hint") else 0)
    with torch.no_grad():
        own = pol.net.embed.own.weight
        own[:, -extra:] = 0.2 * torch.randn(own.shape[0], extra,
                                            generator=torch.Generator().manual_seed(1))
    ckpt = tmp_path / "belief.pt"
    save_checkpoint(ckpt, pol.payload())
    out = tmp_path / "run.json"
    r = swarm("run", "--headless", "--robots", "6", "--policy", "commattn", "--checkpoint",
              str(ckpt), "--episodes", "1", "--seed", "5", "--sample", "--run-id", "eqbelief",
              "--json", str(out), timeout=180)
    assert r.returncode == 0, r.stderr[-2000:]
    res = json.loads(out.read_text())
    ev = evaluate(cfg, make_policy("commattn", cfg, checkpoint=str(ckpt)), 5, 1,
                  record_actions=True, greedy=False)
    base = evaluate(cfg, make_policy("commattn", cfg, checkpoint=str(CKPT)), 5, 1,
                    record_actions=True, greedy=False)
    assert not np.array_equal(ev.actions, base.actions)  # the belief inputs changed decisions
    assert np.array_equal(np.array(res["actions"]), np.stack(ev.actions, 1))
    assert res["timeouts"] == 0 and res["messages"]["bad"] == 0
