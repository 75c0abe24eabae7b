"""A training run's folder (swarm.learn.curves): what a kill mid-write leaves is gone once the
run resumes (a real tiny run, in-process)."""

from __future__ import annotations

import dataclasses
import io
from pathlib import Path

from rich.console import Console

from swarm.learn.config import TrainConfig
from swarm.learn.trainer import main
from world.config import WorldConfig

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
