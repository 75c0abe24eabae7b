"""A training run's folder (swarm.learn.curves): what a kill mid-write leaves is gone once the
run resumes, what the files record across resumes (real tiny runs, in-process)."""

from __future__ import annotations

import csv
import dataclasses
import io
import json
from pathlib import Path

import pytest
from rich.console import Console

from policies.checkpoint import load_checkpoint, save_checkpoint
from swarm.learn.config import TrainConfig
from swarm.learn.curves import CURVE_FIELDS, fig8, read_curve
from swarm.learn.trainer import main
from world.config import WorldConfig

ROOT = Path(__file__).resolve().parents[1]

TINY = WorldConfig(height=6, width=6, n_static=4, n_dynamic=3, n_robots=3, horizon=9, add_every=3,
                   vision=3, comm_range=float("inf"))


def test_resume_removes_the_temp_files_a_killed_run_left(tmp_path: Path) -> None:
    """A SIGKILL mid-write leaves `.curve.csv.XXXX.tmp` (or of any file the run writes
    atomically); the resumed run removes them all, its curve and checkpoint intact."""
    cfg = TrainConfig(policy="commattn", epochs=1, updates=1, batch=2, threads=1, val_episodes=0)
    out = tmp_path / "run"
    main(cfg, TINY, out, console=Console(file=io.StringIO()))
    stale = [out / f".{name}.k1ll3d.tmp" for name in (
        "checkpoint.pt", "curve.csv", "log.jsonl", "curve.png")]
    for path in stale:
        path.write_bytes(b"half a write")
    main(dataclasses.replace(cfg, epochs=2), TINY, out, resume=True,
         console=Console(file=io.StringIO()))
    assert not [p.name for p in stale if p.exists()]
    assert len((out / "curve.csv").read_text().splitlines()) == 3  # header, two updates
    assert {"curve.csv", "curve.png"} <= {p.name for p in out.iterdir()}


def _train(cfg: TrainConfig, out: Path, argv: str, monkeypatch: pytest.MonkeyPatch,
           resume: bool = False) -> None:
    monkeypatch.setattr("sys.argv", argv.split())
    main(cfg, TINY, out, resume=resume, console=Console(file=io.StringIO()))


def test_the_log_records_the_estimator_and_fig8_reads_old_and_new_curves(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Under PPO the loss columns mean PPO's terms: every update line of log.jsonl names the
    estimator; curve.csv keeps its columns, so `swarm repro fig8` draws a new run's curve beside
    the shipped ones."""
    out = tmp_path / "run"
    _train(TrainConfig(policy="commattn", epochs=1, updates=2, batch=2, threads=1,
                       val_episodes=0, algo="ppo", ppo_epochs=2), out, "swarm train", monkeypatch)
    lines = [json.loads(line) for line in (out / "log.jsonl").read_text().splitlines()]
    assert [r["algo"] for r in lines if r["kind"] == "update"] == ["ppo", "ppo"]
    assert next(csv.reader((out / "curve.csv").open())) == CURVE_FIELDS
    res = fig8({"commattn": ROOT / "checkpoints" / "commattn_curve.csv",
                "mine": out / "curve.csv"}, 5, tmp_path / "fig8", "test", 0)
    assert {r["policy"] for r in res["rows"]} == {"commattn", "mine"}


def _strip_history(ckpt_path: Path) -> None:
    """Make a checkpoint as written before runs kept their commands and clock."""
    old = load_checkpoint(ckpt_path)
    old["meta"] = {k: v for k, v in old["meta"].items() if k != "commands"}
    old["train"] = {k: v for k, v in old["train"].items() if k != "elapsed_s"}
    save_checkpoint(ckpt_path, old)


CFG = TrainConfig(policy="commattn", epochs=1, updates=2, batch=2, threads=1, val_episodes=0)


def test_resume_keeps_every_command(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A resumed run's checkpoint names every command that made its epochs, in order
    (`meta.commands`; `meta.command` is the last); an older checkpoint's one command starts
    the list."""
    out = tmp_path / "run"
    _train(CFG, out, "swarm train --first", monkeypatch)
    assert load_checkpoint(out / "checkpoint.pt")["meta"]["commands"] == ["swarm train --first"]
    _train(dataclasses.replace(CFG, epochs=2), out, "swarm train --second", monkeypatch, True)
    meta = load_checkpoint(out / "checkpoint.pt")["meta"]
    assert meta["commands"] == ["swarm train --first", "swarm train --second"]
    assert meta["command"] == "swarm train --second"
    _strip_history(out / "checkpoint.pt")
    _train(dataclasses.replace(CFG, epochs=3), out, "swarm train --third", monkeypatch, True)
    assert load_checkpoint(out / "checkpoint.pt")["meta"]["commands"] == [
        "swarm train --second", "swarm train --third"]


def test_resume_continues_the_run_clock(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """curve.csv's elapsed_s is the run's training time: a resumed run goes on from its
    checkpoint's total instead of restarting at 0 (an older checkpoint: from its curve's last
    row)."""
    out = tmp_path / "run"
    _train(CFG, out, "swarm train", monkeypatch)
    _train(dataclasses.replace(CFG, epochs=2), out, "swarm train", monkeypatch, True)
    elapsed = read_curve(out / "curve.csv")["elapsed_s"]
    assert elapsed == sorted(elapsed) and elapsed[2] > elapsed[1], elapsed
    assert load_checkpoint(out / "checkpoint.pt")["train"]["elapsed_s"] >= elapsed[3]
    _strip_history(out / "checkpoint.pt")
    _train(dataclasses.replace(CFG, epochs=3), out, "swarm train", monkeypatch, True)
    elapsed = read_curve(out / "curve.csv")["elapsed_s"]
    assert len(elapsed) == 6 and elapsed == sorted(elapsed) and elapsed[4] > elapsed[3], elapsed


def test_fig8_says_when_the_curves_come_from_different_worlds(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
        capsys: pytest.CaptureFixture[str]) -> None:
    """`swarm repro fig8 --curve NAME=FILE` drew a run of another world beside the shipped
    curves without a word: the checkpoints beside the curves tell, in one line on stderr and in
    the Markdown; the shipped curves alone (one world) get no note."""
    out = tmp_path / "run"
    _train(CFG, out, "swarm train", monkeypatch)
    shipped = ROOT / "checkpoints" / "commattn_curve.csv"
    fig8({"commattn": shipped, "vain": shipped.with_name("vain_curve.csv")}, 5,
         tmp_path / "same", "test", 0)
    assert "Not comparable" not in (tmp_path / "same" / "fig8.md").read_text()
    assert capsys.readouterr().err == ""
    fig8({"commattn": shipped, "mine": out / "curve.csv"}, 5, tmp_path / "mixed", "test", 0)
    err = capsys.readouterr().err
    assert err.startswith("fig8: Not comparable") and err.count("\n") == 1, err
    assert "commattn: comm_range 10.0, height 20" in err and "mine: comm_range inf, height 6" in err
    assert err.removeprefix("fig8: ").strip() in (tmp_path / "mixed" / "fig8.md").read_text()
