"""`swarm trace` of a direct-delivery recording, and the flags `swarm replay` and `swarm trace`
refuse: real runs and the real CLI (subprocesses), no mocks."""

from __future__ import annotations

import csv
import json
from pathlib import Path
from typing import Any

import pytest
from conftest import ROOT, swarm, swarm_here

pytest.importorskip("mcap")  # the `record` extra (in `test` too)

CKPT = str(ROOT / "checkpoints" / "commattn.pt")
ROBOTS, HORIZON = 3, 12


@pytest.fixture(scope="module")
def direct(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    """A recorded CommAttn run with direct delivery under loss, latency, a cap and a
    partition (the acceptance pass's run, shorter)."""
    d = tmp_path_factory.mktemp("dtrace")
    f, res = d / "direct.mcap", d / "direct.json"
    r = swarm("run", "--headless", "--robots", str(ROBOTS), "--episodes", "1", "--horizon",
              str(HORIZON), "--policy", "commattn", "--checkpoint", CKPT, "--delivery", "direct",
              "--loss", "0.2", "--latency", "50ms", "--bandwidth", "200B/s", "--partition",
              "0/1-2", "--run-id", "dtrace", "--record", str(f), "--json", str(res),
              "--log-dir", str(d / "logs"), timeout=120)
    assert r.returncode == 0, r.stderr[-2000:]
    return {"dir": d, "file": f, "result": json.loads(res.read_text())}


def _rows(path: Path) -> list[dict[str, str]]:
    with open(path) as fh:
        return list(csv.DictReader(fh))


@pytest.mark.procs
def test_trace_of_a_direct_run_counts_what_each_link_delivered(direct: dict[str, Any]) -> None:
    """Each robot's action says whom it heard: the links' delivered copies add up to the run's
    own count; the robots' status records give the attention table and the per-link misses;
    what a direct recording cannot say (hidden-state copies per link) is empty and noted."""
    out, js = direct["dir"] / "trace", direct["dir"] / "trace.json"
    r = swarm("trace", str(direct["file"]), "--out", str(out), "--json", str(js))
    assert r.returncode == 0, r.stderr
    m, ticks = direct["result"]["messages"], direct["result"]["ticks"]
    links = _rows(out / "links.csv")
    delivered = sum(int(x["delivered_traj"]) for x in links)
    assert delivered == m["traj_delivered"] - ticks * ROBOTS > 0  # less each robot's own
    assert delivered == m["traj_to_others"]  # the robots' reports, summed by the world
    missed = sum(m["by_kind"][k][f] for k in ("traj", "hidden")
                 for f in ("lost", "cut", "dropped_bw"))
    assert sum(int(x["dropped_both_kinds"]) for x in links) == missed
    assert all(x[k] == "" for x in links for k in (
        "delivered_hidden", "hidden_miss_sender", "hidden_miss_radio", "delivery_ratio"))
    attention = _rows(out / "attention.csv")
    assert attention and any(x["distance"] == "0" for x in attention)
    assert (out / "attention.png").stat().st_size > 0
    kinds = {x["kind"] for x in _rows(out / "kinds.csv")}
    assert {"direct_traj", "direct_hidden"} <= kinds and "direct" not in kinds
    rep = json.loads(js.read_text())
    assert any("hidden-state copies each link delivered is not in the recording" in n
               for n in rep["notes"])
    assert "delivered_hidden" in (out / "notes.txt").read_text()
    assert "note: direct delivery" in r.stderr


@pytest.mark.procs
def test_replay_refuses_flags_it_would_ignore_or_that_do_not_fit(
        direct: dict[str, Any], capsys: pytest.CaptureFixture[str]) -> None:
    f = str(direct["file"])
    cases = [(["--attention", "9"], f"--attention 9: run dtrace has robots 0..{ROBOTS - 1}"),
             (["--verify", "--from", "3"], "--from does nothing with --verify"),
             (["--verify", "--speed", "3"], "--speed does nothing with --verify"),
             (["--verify", "--attention", "2"], "--attention does nothing with --verify"),
             (["--verify", "--until", "5"], "--until does nothing with --verify"),
             (["--speed", "1e9"], "--speed must lie in [0, 1000000]"),
             (["--speed", "-1"], "--speed must lie in [0, 1000000]")]
    for flags, why in cases:
        r = swarm_here("replay", f, *flags, capsys=capsys)
        assert r.returncode == 2, (flags, r.stdout[-500:], r.stderr)
        assert len(r.stderr.strip().splitlines()) == 1 and why in r.stderr, (flags, r.stderr)
    r = swarm_here("replay", f, "--verify", capsys=capsys)  # the flags it takes still work
    assert r.returncode == 0 and "every one as recorded" in r.stdout, r.stdout + r.stderr


@pytest.mark.procs
def test_a_failed_trace_leaves_no_output_folder(tmp_path: Path) -> None:
    out = tmp_path / "t2" / "deeper"
    r = swarm("trace", str(tmp_path / "missing.mcap"), "--out", str(out))
    assert r.returncode == 2 and "cannot read" in r.stderr, r.stderr
    assert len(r.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "t2").exists()
    (tmp_path / "afile").write_text("x")
    r = swarm("trace", str(tmp_path / "missing.mcap"), "--out", str(tmp_path / "afile"))
    assert r.returncode == 2 and "is not a directory" in r.stderr, r.stderr
