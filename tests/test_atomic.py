"""Atomic result files: complete content or the old file, never a leftover temp file."""

from __future__ import annotations

import json
import os
import stat
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


def test_a_fifo_and_a_device_are_written_in_place_not_replaced(tmp_path: Path) -> None:
    """A special file given as the output (a FIFO, /dev/null) is opened and written: replacing
    it with a regular file would lose it (as root, /dev/null itself)."""
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)
    reader = os.open(fifo, os.O_RDONLY | os.O_NONBLOCK)  # a reader, so the writer's open returns
    try:
        atomic.write_json(fifo, {"a": 1})
        assert json.loads(os.read(reader, 1 << 16)) == {"a": 1}
    finally:
        os.close(reader)
    assert stat.S_ISFIFO(fifo.stat().st_mode)
    if os.geteuid() == 0:  # a null device of our own (never the machine's /dev/null)
        null = tmp_path / "null"
        os.mknod(null, 0o666 | stat.S_IFCHR, os.makedev(1, 3))
        atomic.write_text(null, "gone")
        assert stat.S_ISCHR(null.stat().st_mode)
    assert not list(tmp_path.glob(".*.tmp"))


def test_a_descriptor_link_appends_to_the_open_file(tmp_path: Path) -> None:
    """`--json /dev/stdout > FILE`: the output is a link to a descriptor's file; the result is
    added after what was printed there, and the link stays (a link of our own in tmp_path: as
    root, replacing /dev/stdout would break the machine)."""
    out = tmp_path / "out.txt"
    with open(out, "w") as fh:
        fh.write("table\n")
        fh.flush()
        link = tmp_path / "stdout"
        link.symlink_to(f"/proc/self/fd/{fh.fileno()}")
        atomic.write_text(link, "json\n")
    assert link.is_symlink()
    assert out.read_text() == "table\njson\n"
