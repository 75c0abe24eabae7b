"""Atomic result files: complete content or the old file, never a leftover temp file."""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pytest

from swarm.common import atomic


def test_write_json_roundtrip_numpy_and_inf(tmp_path: Path) -> None:
    path = tmp_path / "deep" / "r.json"
    atomic.write_json(path, {"a": np.float64(0.5), "b": np.arange(3), "c": float("inf"), 1: True})
    assert json.loads(path.read_text()) == {"a": 0.5, "b": [0, 1, 2], "c": "inf", "1": True}
    assert [p.name for p in path.parent.iterdir()] == ["r.json"]
    umask = os.umask(0)
    os.umask(umask)
    assert path.stat().st_mode & 0o777 == 0o666 & ~umask  # an ordinary file, not mkstemp's 0600


def test_replace_keeps_old_file_when_write_fails(tmp_path: Path) -> None:
    path = tmp_path / "r.txt"
    atomic.write_text(path, "old")

    with pytest.raises(TypeError):
        atomic.write_bytes(path, object())  # type: ignore[arg-type]
    assert path.read_text() == "old"
    assert [p.name for p in tmp_path.iterdir()] == ["r.txt"]
    atomic.write_bytes(path, b"new")
    assert path.read_bytes() == b"new"
