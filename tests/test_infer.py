"""Torch-free inference (policies.infer) against the torch networks it twins: the checkpoint
reader, every layer, every learned policy (logits within 1e-5 relative, the same greedy and
sampled actions), the chain, maps of other sizes, and a robot's imports."""

from __future__ import annotations

import dataclasses
import pickle
import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest
import torch
from conftest import ROOT
from torch import nn

from policies import LEARNED, make_policy, policy_class
from policies.checkpoint import CheckpointError, read_checkpoint
from policies.features import Members, TokenEmbed, bigru
from policies.infer import layers
from policies.infer.nets import NETS
from policies.infer.policy import inference_class, pred_rows
from policies.infer.ptfile import PtFileError, load_pt
from policies.infer.tokens import Featurizer
from world import core
from world.config import WorldConfig
from world.decentral import TeamMemory, batch_view, heard_by, robot_view

CHECKPOINTS = sorted((ROOT / "checkpoints").rglob("*.pt"))
SMALL = WorldConfig(height=10, width=10, n_robots=5, n_static=15, n_dynamic=10, horizon=30,
                    add_every=3, comm_range=4.0)


def close(numpy_out: np.ndarray, torch_out: torch.Tensor) -> None:
    """Within 1e-5, relative to the magnitude (float32 logits reach ~40)."""
    np.testing.assert_allclose(numpy_out, torch_out.detach().numpy(), rtol=1e-5, atol=1e-5)


@pytest.mark.parametrize("path", CHECKPOINTS, ids=lambda p: p.name)
def test_checkpoints_read_without_torch_equal_torch_load(path: Path) -> None:
    ours, theirs = load_pt(path), torch.load(path, weights_only=True)

    def same(a: object, b: object) -> None:
        if isinstance(b, torch.Tensor):
            assert isinstance(a, np.ndarray) and a.dtype == b.numpy().dtype
            assert np.array_equal(a, b.numpy())
        elif isinstance(b, dict):
            assert isinstance(a, dict) and set(a) == set(b)
            for k in b:
                same(a[k], b[k])
        elif isinstance(b, (list, tuple)):
            assert len(a) == len(b)  # type: ignore[arg-type]
            for x, y in zip(a, b, strict=True):  # type: ignore[call-overload]
                same(x, y)
        else:
            assert a == b

    same(ours, theirs)


class Boom:
    def __reduce__(self) -> tuple:
        return (print, ("executed",))


def test_the_reader_refuses_code_and_garbage(tmp_path: Path) -> None:
    bad = tmp_path / "bad.pt"
    torch.save({"x": torch.zeros(2)}, bad)
    with zipfile.ZipFile(bad) as z:
        names = z.namelist()
    evil = tmp_path / "evil.pt"
    with zipfile.ZipFile(evil, "w") as z:
        z.writestr(names[0], pickle.dumps(Boom()))
    with pytest.raises(PtFileError, match="refuses to load builtins.print"):
        load_pt(evil)
    junk = tmp_path / "junk.pt"
    junk.write_bytes(b"not a zip")
    with pytest.raises(CheckpointError, match="unreadable"):
        read_checkpoint(junk)


def test_every_layer_equals_torch() -> None:
    torch.manual_seed(0)
    g = torch.Generator().manual_seed(1)
    lin = nn.Linear(7, 5)
    x = torch.randn(4, 7, generator=g)
    w = {f"l.{k}": v.detach().numpy() for k, v in lin.state_dict().items()}
    close(layers.linear(w, "l", x.numpy()), lin(x))
    cell = nn.GRUCell(7, 6)
    h = torch.randn(4, 6, generator=g)
    w = {f"c.{k}": v.detach().numpy() for k, v in cell.state_dict().items()}
    close(layers.gru_cell(w, "c", x.numpy(), h.numpy()), cell(x, h))
    close(layers.sigmoid(x.numpy() * 30), torch.sigmoid(x * 30))
    buf = x.numpy() * 30  # in place, as the GRU's gates call it
    assert layers.sigmoid(buf, out=buf) is buf
    close(buf, torch.sigmoid(x * 30))
    close(layers.softmax(x.numpy()), torch.softmax(x, -1))
    close(layers.log_softmax(x.numpy()), torch.log_softmax(x, -1))
    # token embedding and BiGRU over real tokens of a mid-game view (ragged neighbourhoods)
    pol = make_policy("bicnet", SMALL)
    state = core.reset(SMALL, 3, np.arange(4))
    for _ in range(6):
        core.step(SMALL, state, np.random.default_rng(0).integers(0, 9, (4, SMALL.n_robots)))
    view = batch_view(SMALL, state)
    pol.remember(view)
    tok = pol.features(view)
    assert len(set(tok.lens.tolist())) > 1  # neighbourhoods of different sizes
    emb = TokenEmbed(pol.features.member_dim, pol.features.pair_dim, 8, pol.features.own_dim)
    w = {f"e.{k}": v.detach().numpy() for k, v in emb.state_dict().items()}
    members = Members.of(tok)
    xe = emb(members)
    close(layers.token_embed(w, "e", tok), xe)
    gru = nn.GRU(8, 6, batch_first=True, bidirectional=True)
    w = {f"g.{k}": v.detach().numpy() for k, v in gru.state_dict().items()}
    for grad in (True, False):  # the bucketed and the packed torch paths
        with torch.set_grad_enabled(grad):
            seq = bigru(gru, xe, members)
            flat_t = seq.padded()[Members.of(tok).pad_index(0)[1]]
        close(layers.bigru(w, "g", xe.detach().numpy(), tok), flat_t)


@pytest.mark.parametrize("name", sorted(LEARNED))
def test_shapes_are_the_torch_state_dict_shapes(name: str) -> None:
    config_cls, numpy_cls = NETS[name]
    for changes in ({}, {"team_pool": 0}, {"crop": 5}, *([{"self_input": False}]
                                                        if name == "commattn" else [])):
        model = dataclasses.replace(config_cls(), **changes)
        pol = policy_class(name)(SMALL, model=model)
        f = pol.features
        want = {k: tuple(v.shape) for k, v in pol.net.state_dict().items()}
        assert numpy_cls.shapes(model, f.member_dim, f.pair_dim, f.own_dim) == want


def midgame(cfg: WorldConfig, groups: int, ticks: int, seed: int = 4) -> core.WorldState:
    state = core.reset(cfg, seed, np.arange(groups))
    rng = np.random.default_rng(seed)
    for _ in range(ticks):
        core.step(cfg, state, rng.integers(0, 9, (groups, cfg.n_robots)))
    return state


@pytest.mark.parametrize("robots,comm", [(10, 10.0), (30, 4.0)])
def test_a_robots_tokens_are_its_rows_of_the_batch_tokens(robots: int, comm: float) -> None:
    """Features of one robot's view (the member parts of the few rows it heard only, its own
    team map) equal its rows of the batched features, exactly, with and without team memory."""
    cfg = WorldConfig(n_robots=robots, comm_range=comm)
    state = midgame(cfg, 1, 12)
    view = batch_view(cfg, state)
    for memory in (False, True):
        feats = Featurizer(cfg, crop=9, team_pool=3, memory=memory)
        if memory:  # (one tick of memory: the union of this tick's messages, both ways)
            view.team_visited = TeamMemory(cfg).update(view)
        t = feats(view)
        for k, i in enumerate(t.robot.tolist()):
            rv = robot_view(cfg, view.seed, 0, view.tick, i, heard_by(cfg, view, 0, i), 0.0)
            if memory:
                rv.team_visited = TeamMemory(cfg).update(rv)
            r = feats(rv)
            assert r.robot.tolist() == [i] and r.lens[0] == t.lens[k]
            assert r.self_pos[0] == t.self_pos[k]
            rows = slice(t.start[k], t.start[k] + t.lens[k])
            np.testing.assert_array_equal(r.member_feats[r.pair_member],
                                          t.member_feats[t.pair_member[rows]])
            np.testing.assert_array_equal(r.pair_feats, t.pair_feats[rows])
            np.testing.assert_array_equal(r.own_feats[0], t.own_feats[k])


@pytest.mark.parametrize("name", sorted(LEARNED))
@pytest.mark.parametrize("size", [20, 40])
def test_shipped_policies_act_as_their_torch_twins(name: str, size: int) -> None:
    """The shipped checkpoint, read without torch, against the torch network on the default map
    and a 40 x 40 one (fixed-size features): logits, values, greedy and sampled actions."""
    cfg = WorldConfig() if size == 20 else WorldConfig(height=40, width=40, n_robots=20,
                                                       n_static=324, n_dynamic=280)
    ckpt = ROOT / "checkpoints" / f"{name}.pt"
    twin = make_policy(name, cfg, checkpoint=str(ckpt))
    light = inference_class(name)(cfg, checkpoint=ckpt)
    assert "torch" not in type(light.weights["s0" if name == "commattn" else
                                            next(iter(light.weights))]).__module__
    for ticks in (0, 12, 25):
        state = midgame(cfg, 3, ticks)
        twin.reset(3)
        light.reset(3)
        logits_t, value_t = twin.torch_logits(batch_view(cfg, state))
        view = batch_view(cfg, state)
        light.remember(view)
        tok = light.features(view)
        if light.chained:
            out, _ = light.np.chain(light.np.encode(tok), tok.robot, pred_rows([view], tok),
                                    lambda rows, lg: lg.argmax(-1))
            logits, value = out.logits, out.value
        else:
            logits, value = light.np.forward(tok)
        close(logits, logits_t)
        close(value, value_t)
        assert np.array_equal(logits.argmax(-1), logits_t.argmax(-1).numpy())
        for greedy in (True, False):
            light.reset(3)
            twin.reset(3)
            a = light.decide(batch_view(cfg, state), greedy=greedy).actions
            b = twin.decide(batch_view(cfg, state), greedy=greedy).actions
            assert np.array_equal(a, b)


def test_one_robot_chain_equals_the_batch_and_reports_attention() -> None:
    """A robot's act_with_chain (numpy) with its predecessor's message equals the batched chain;
    its attention is a distribution over the robots it heard."""
    cfg = WorldConfig()
    pol = inference_class("commattn")(cfg, checkpoint=ROOT / "checkpoints" / "commattn.pt")
    state = midgame(cfg, 1, 15)
    view = batch_view(cfg, state)
    pol.reset(1)
    d = pol.decide(view, greedy=True)
    assert d.attention is not None
    for i in range(cfg.n_robots):
        rv = robot_view(cfg, view.seed, 0, view.tick, i, heard_by(cfg, view, 0, i), 0.0)
        p = int(rv.predecessor()[0, i])
        ps = None if p < 0 else d.state[0, p][None]
        pa = None if p < 0 else np.array([d.actions[0, p]])
        pol.reset(1)
        actions, s = pol.act_with_chain(rv, ps, pa)
        assert actions[0, i] == d.actions[0, i]
        np.testing.assert_allclose(s[0], d.state[0, i], rtol=1e-5, atol=1e-6)
        att = pol.last_attention
        assert att.shape == (cfg.n_robots,) and att.sum() == pytest.approx(1, abs=1e-5)
        assert set(np.flatnonzero(att)) <= set(np.flatnonzero(view.hears[0, i]))
        np.testing.assert_allclose(att, d.attention[0, i], atol=1e-6)


@pytest.mark.parametrize("name", ["commattn", "bicnet"])
def test_a_robots_kept_arrays_compute_the_same_floats(name: str) -> None:
    """What a robot's decision keeps between calls (the BiGRU's packed recurrent weights) and
    skips (padding its one receiver's pairs) changes no bit, and adopted weights replace the
    kept pack (the decision then equals a policy's that packs on every call)."""
    cfg = WorldConfig()
    ckpt = ROOT / "checkpoints" / f"{name}.pt"
    pol = inference_class(name)(cfg, checkpoint=ckpt)
    view = batch_view(cfg, midgame(cfg, 2, 14))
    for i in range(cfg.n_robots):
        rv = robot_view(cfg, view.seed, 0, view.tick, i, heard_by(cfg, view, 0, i), 0.0)
        pol.reset(1)
        pol.remember(rv)
        tok = pol.features(rv)
        x = layers.token_embed(pol.weights, "embed", tok)
        assert np.array_equal(layers.bigru(pol.weights, "gru", x, tok, pol.np.packed_bigru("gru")),
                              layers.bigru(pol.weights, "gru", x, tok))
        idx, mask = tok.pad_index(len(x))
        padded, ones = tok.padded(x)
        assert ones.all() and mask.all() and np.array_equal(padded, x[idx])
    fresh = {k: v * np.float32(1.5) for k, v in pol.weights.items()}
    other = inference_class(name)(cfg, checkpoint=ckpt)
    for p in (pol, other):
        p.load_weights(fresh, dataclasses.asdict(p.model_cfg))
        p.reset(2)
    other.np.keep = False
    assert np.array_equal(pol.decide(view).probs, other.decide(view).probs)


@pytest.mark.parametrize("name", sorted(LEARNED))
def test_acting_log_probs_equal_the_torch_recomputation(name: str) -> None:
    """What a rollout records (numpy, sampled) and what the update recomputes (torch) for the
    shipped checkpoint: ratios of fresh episodes within 1e-5 of 1."""
    from swarm.learn.rollout import collect

    cfg = WorldConfig()
    pol = make_policy(name, cfg, checkpoint=str(ROOT / "checkpoints" / f"{name}.pt"))
    roll = collect(pol, cfg, 7, np.arange(3))
    with torch.no_grad():
        ev = pol.evaluate(roll.views, roll.actions, roll.inputs)
    recorded = roll.logp[ev.tick, ev.group, ev.robot]
    ratio = np.exp(ev.logp.numpy() - recorded)
    assert np.abs(ratio - 1).max() < 1e-5


def test_adopting_weights_updates_the_numpy_and_the_torch_network() -> None:
    from swarm.learn.weights import adopt, weights_of

    a, b = make_policy("commnet", SMALL), make_policy("commnet", SMALL)
    torch.manual_seed(3)
    for p in a.net.parameters():
        nn.init.normal_(p)
    adopt(b, weights_of(a, 5))
    for k, v in a.net.state_dict().items():
        assert torch.equal(b.net.state_dict()[k], v)
        assert np.array_equal(b.weights[k], v.numpy())


def test_a_learned_robot_never_imports_torch() -> None:
    """A robot process builds its CommAttn policy from the shipped checkpoint and decides."""
    code = ("import sys, numpy as np\n"
            "from swarm.common.policy_spec import build_inference\n"
            "from world.config import WorldConfig\n"
            "from world import core\n"
            "from world.decentral import batch_view\n"
            "cfg = WorldConfig()\n"
            "for name in ('commattn', 'commnet', 'vain', 'bicnet'):\n"
            "    pol = build_inference(name, cfg)\n"
            "    pol.reset(1)\n"
            "    pol.decide(batch_view(cfg, core.reset(cfg, 0, np.arange(1))))\n"
            "print('torch' in sys.modules)\n")
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True)
    assert out.stdout.strip() == "False", out.stderr[-2000:]


def test_registry_knows_the_learned_policies_without_importing_them() -> None:
    assert {n for n in NETS} == LEARNED
    assert all(policy_class(n).learned for n in LEARNED)
