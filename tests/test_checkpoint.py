"""Checkpoint files as every command reads them (policies.checkpoint): a checkpoint that is cut
short, holds fields of the wrong type or non-finite weights is refused in one line naming the
file, by the torch reader and the torch-free one alike (real files, a tiny real network)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
import torch
from conftest import swarm

from policies import make_policy
from policies.checkpoint import CheckpointError, load_checkpoint, read_checkpoint, save_checkpoint
from policies.infer.nets import CommAttnConfig
from world.config import WorldConfig

TINY_NET = CommAttnConfig(embed=4, hidden=4, state=4, match=4, action_embed=4)


def tiny_checkpoint(path: Path, **changes: Any) -> Path:
    """A commattn checkpoint of a tiny network for the default world, with `changes` to its
    top-level fields."""
    torch.manual_seed(0)
    payload = make_policy("commattn", WorldConfig(), model=TINY_NET).payload({"command": "test"})
    save_checkpoint(path, {**payload, **changes})
    return path


def test_both_readers_call_a_truncated_checkpoint_not_a_torch_file(tmp_path: Path) -> None:
    raw = tiny_checkpoint(tmp_path / "good.pt").read_bytes()
    cut = tmp_path / "cut.pt"
    cut.write_bytes(raw[:len(raw) // 2])
    for reader in (load_checkpoint, read_checkpoint):
        with pytest.raises(CheckpointError, match="unreadable: not a torch checkpoint file"):
            reader(cut)


def one_line_error(r: Any, words: str) -> None:
    assert r.returncode == 2, (r.returncode, r.stderr)
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("swarm: error: ") and words in lines[0], \
        r.stderr


@pytest.mark.procs
def test_train_resume_calls_a_truncated_checkpoint_not_a_torch_file(tmp_path: Path) -> None:
    run = tmp_path / "run"
    run.mkdir()
    raw = tiny_checkpoint(tmp_path / "good.pt").read_bytes()
    (run / "checkpoint.pt").write_bytes(raw[:len(raw) // 2])
    one_line_error(swarm("train", "--resume", "--out", str(run), timeout=60),
                   "not a torch checkpoint file")
