"""The Fig. 10 / Fig. 11 studies (swarm.studies.commviz) on tiny budgets: files, columns, finite
numbers, and the label and neighbour definitions on hand-built maps."""

from __future__ import annotations

import csv
import math
import sys

import numpy as np
import pytest

from swarm.studies import commviz
from world import core
from world.config import ConfigError, WorldConfig
from world.decentral import batch_view


def read(path):
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


def test_fig10_writes_tsne_and_scores(tmp_path):
    pytest.importorskip("sklearn")
    res = commviz.fig10(tmp_path, seed=1, episodes=3, points=200, probe_points=800, batch=3)
    for name in ("fig10.csv", "fig10.png", "fig10_scores.csv", "fig10_scores.md"):
        assert (tmp_path / name).stat().st_size > 0
    rows = read(tmp_path / "fig10.csv")
    assert len(rows) == 200 == res["points"]
    assert set(rows[0]) == {"tsne_x", "tsne_y", "episode", "tick", "robot", "y", "x", "conflict",
                            "hear", "phase", "chain", "action"}
    assert all(math.isfinite(float(r["tsne_x"])) and math.isfinite(float(r["tsne_y"]))
               for r in rows)
    assert {r["conflict"] for r in rows} <= {"none", "adjacent", "same"}
    scores = read(tmp_path / "fig10_scores.csv")
    assert [s["label"] for s in scores] == ["conflict", "hear", "phase", "chain", "action"]
    for s in scores:
        for key in ("majority_rate", "probe_acc", "probe_bal_acc", "shuffled_acc",
                    "untrained_acc"):
            assert 0.0 <= float(s[key]) <= 1.0
        assert -1.0 <= float(s["silhouette"]) <= 1.0
    assert res["states"] == 3 * 30 * 10
    # a robot decoding from s_0 or from a predecessor is always linearly separable
    assert res["scores"]["chain"]["probe_bal_acc"] > 0.9


def test_fig10_needs_sklearn_and_a_static_map(tmp_path, monkeypatch):
    with pytest.raises(ValueError, match="static"):
        commviz.fig10(tmp_path, cfg=WorldConfig(), episodes=1)
    monkeypatch.setitem(sys.modules, "sklearn", None)
    with pytest.raises(ConfigError, match=r"commattn-swarm\[analysis\]"):
        commviz.fig10(tmp_path, episodes=1)


def test_fig11_writes_per_cell_norms(tmp_path):
    res = commviz.fig11(tmp_path, seed=2, episodes=8, batch=4, min_visits=1, permutations=50)
    for name in ("fig11.csv", "fig11.png", "fig11_by_neighbours.csv", "fig11_by_neighbours.md"):
        assert (tmp_path / name).stat().st_size > 0
    rows = read(tmp_path / "fig11.csv")
    cfg = WorldConfig(dynamic=False)
    blocks = core.generate_episode(cfg, 2, 0)[0]
    assert len(rows) == int((~blocks).sum())
    for col in ("y", "x", "free_neighbours", "visits", "mean_state_norm", "mean_context_norm"):
        assert col in rows[0]
    assert sum(int(r["visits"]) for r in rows) == res["decisions"] == 8 * 30 * 10
    for r in rows:
        assert not blocks[int(r["y"]), int(r["x"])]
        assert 0 <= int(r["free_neighbours"]) <= 8
        if int(r["visits"]):
            assert float(r["mean_state_norm"]) > 0 and math.isfinite(float(r["mean_context_norm"]))
    groups = read(tmp_path / "fig11_by_neighbours.csv")
    assert {g["grouping"] for g in groups} == {"free8", "free4", "passage"}
    assert sum(int(g["visits"]) for g in groups if g["grouping"] == "free8") == res["decisions"]
    rho, p = res["spearman"]["free8 (all)"]["state"]
    assert -1 <= rho <= 1 and 0 < p <= 1


def test_free_neighbours_and_passages():
    blocks = np.zeros((3, 4), dtype=bool)
    blocks[0, 1] = blocks[2, 1] = True
    n8, n4, passage = commviz.free_neighbours(blocks)
    assert n8[1, 1] == 6 and n4[1, 1] == 2  # between two blocks, N and S
    assert passage[1, 1] and not passage[1, 2]
    assert n8[0, 0] == 2 and n4[0, 0] == 1  # corner: off-grid counts as not free
    assert passage[0, 0]  # W off-grid and E blocked


def test_spearman_ranks_and_ties():
    a = np.array([1, 2, 3, 4, 5])
    assert commviz.spearman(a, a ** 3)[0] == pytest.approx(1.0)
    assert commviz.spearman(a, -a)[0] == pytest.approx(-1.0)
    assert math.isnan(commviz.spearman(a, np.ones(5))[0])
    rho, p = commviz.spearman(a, np.array([1, 1, 2, 2, 3]), np.random.default_rng(0), 200)
    assert rho == pytest.approx(np.corrcoef([0, 1, 2, 3, 4], [0.5, 0.5, 2.5, 2.5, 4])[0, 1])
    assert 0 < p <= 1


def test_situation_labels_on_a_hand_built_state():
    cfg = WorldConfig(height=5, width=5, n_static=0, dynamic=False, n_robots=3, comm_range=2.0)
    blocks = np.zeros((1, 5, 5), dtype=bool)
    starts = np.array([[[2, 0], [2, 2], [0, 4]]])  # 0 and 1 hear each other; 2 is out of range
    state = core.from_layout(cfg, blocks, starts, np.zeros((1, 0, 2), dtype=np.int64))
    view = batch_view(cfg, state)
    bucket_of, names = commviz.hear_buckets(cfg.n_robots, (1,))
    assert names == ["1", "2-3"]
    actions = np.array([[3, 0, 0]])  # robot 0 moves E onto (2, 1), next to robot 1 staying
    lab = commviz.situation_labels(cfg, state, view, actions, bucket_of)
    assert lab["conflict"].tolist() == [[1, 1, 0]]
    assert lab["hear"].tolist() == [[1, 1, 0]]
    assert lab["chain"].tolist() == [[0, 1, 0]]
    assert lab["phase"].tolist() == [[0, 0, 0]]
    lab = commviz.situation_labels(cfg, state, view, np.array([[3, 7, 0]]), bucket_of)
    assert lab["conflict"].tolist() == [[2, 2, 0]]  # both chose (2, 1)
