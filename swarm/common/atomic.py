"""Atomic result files: a reader sees the old file or the whole new one, never half of it.

Each write goes to a temporary file in the target's directory (same filesystem, so the rename is
atomic), is flushed and fsynced, replaces the target with `os.replace`, and the directory is
fsynced so the rename itself survives a crash. An existing target that is not a regular file
(a device such as /dev/null, a FIFO, a socket, or /dev/stdout, an open descriptor's link) is
written in place, as Unix tools do: there is no file to swap and nothing to keep whole.
"""

from __future__ import annotations

import json
import math
import os
import stat
import tempfile
from pathlib import Path
from typing import Any


def write_bytes(path: str | Path, data: bytes) -> Path:
    """Atomically write `data` to `path` (parent directories are created); returns the path."""
    path = Path(path)
    if in_place(path):  # appended to: `--json /dev/stdout > FILE` keeps what was printed before
        with open(os.open(path, os.O_WRONLY | os.O_APPEND), "wb") as fh:
            fh.write(data)
        return path
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        os.fchmod(fd, _mode(path))  # mkstemp makes 0600; results are ordinary files
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        try:
            os.unlink(tmp)
        except FileNotFoundError:
            pass
        raise
    _fsync_dir(path.parent)
    return path


def in_place(path: str | Path) -> bool:
    """Whether `path` is written in place rather than replaced: it exists and is not a regular
    file or a directory, or it is reached through a process's descriptor links (/dev/stdout,
    /dev/fd/N, /proc/self/fd/N: replacing the link would not reach the descriptor, and as root
    it would swap /dev/stdout itself for a file)."""
    try:
        mode = os.stat(path).st_mode
    except OSError:  # missing (or unreadable: the write says why)
        return False
    return not (stat.S_ISREG(mode) or stat.S_ISDIR(mode)) or _through_proc(Path(path))


def _through_proc(path: Path) -> bool:
    """Whether resolving `path`'s symbolic links passes through /proc."""
    current = Path(os.path.abspath(path))
    for _ in range(40):  # the kernel's own limit on links followed
        parent = Path(os.path.realpath(current.parent))
        if parent.parts[:2] == ("/", "proc"):
            return True
        current = parent / current.name
        if not current.is_symlink():
            return False
        current = Path(os.path.normpath(parent / os.readlink(current)))
    return False


def remove_stale(directory: str | Path, names: tuple[str, ...]) -> None:
    """Delete the temporary files a writer of `directory/NAME` (one of `names`) left when it was
    killed mid-write (`.NAME.*.tmp`); call it where nothing else writes them, e.g. on resume."""
    for name in names:
        for stale in Path(directory).glob(f".{name}.*.tmp"):
            stale.unlink(missing_ok=True)


def write_text(path: str | Path, text: str) -> Path:
    """Atomically write UTF-8 `text` to `path`."""
    return write_bytes(path, text.encode("utf-8"))


def write_json(path: str | Path, obj: Any) -> Path:
    """Atomically write `obj` as indented JSON (numpy scalars/arrays and inf/nan made JSON-safe)."""
    return write_text(path, json.dumps(json_safe(obj), indent=2, sort_keys=False) + "\n")


def json_safe(obj: Any) -> Any:
    """`obj` with numpy values turned into Python ones and non-finite floats into strings."""
    if isinstance(obj, dict):
        return {str(k): json_safe(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [json_safe(v) for v in obj]
    if hasattr(obj, "tolist"):  # numpy scalar or array
        return json_safe(obj.tolist())
    if isinstance(obj, float) and not math.isfinite(obj):
        return str(obj)
    if isinstance(obj, Path):
        return str(obj)
    return obj


def _mode(path: Path) -> int:
    """The permission bits for `path`: those of the file it replaces, else 0666 less umask."""
    try:
        return path.stat().st_mode & 0o7777
    except FileNotFoundError:
        umask = os.umask(0)
        os.umask(umask)
        return 0o666 & ~umask


def _fsync_dir(directory: Path) -> None:
    """Persist a rename in `directory` (a no-op where directories cannot be opened)."""
    try:
        fd = os.open(directory, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)
