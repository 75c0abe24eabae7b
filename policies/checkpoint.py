"""Small checkpoint files: the model and world config that made them, the weights, and metadata.

A checkpoint is a torch file holding a plain dict:

    format      1
    policy      registry name ("commattn", ...)
    model       the network's config dataclass as a dict
    world       the WorldConfig it was trained on (world.config.to_dict)
    state_dict  the network's weights
    meta        command, seed, epoch, update, ... (free-form, JSON-safe)
    train       optional trainer state (optimizer, RNG, counters) for `swarm train --resume`
    learner     optional field learner state (`swarm learner --resume`)

Both readers check the same: the fields' types, that every weight is a floating-point array
(`WEIGHT_DTYPES`; the networks compute in float32, so the others are converted when loaded) and
that every weight is finite.

Writes are atomic (temp file in the same directory, fsync, os.replace), so a crash mid-write
leaves the previous checkpoint intact. `read_checkpoint` reads one without torch (numpy arrays,
policies.infer.ptfile): what robot processes do.
"""

from __future__ import annotations

import os
import tempfile
import zipfile
from pathlib import Path
from typing import Any

import numpy as np

from world.config import ConfigError

FORMAT = 1


class CheckpointError(ConfigError):
    """A checkpoint that is missing, unreadable or does not fit; one line for the user."""


def save_checkpoint(path: str | Path, payload: dict[str, Any]) -> None:
    """Write `payload` to `path` atomically."""
    import torch

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as fh:
            torch.save({"format": FORMAT, **payload}, fh)
            fh.flush()
            os.fsync(fh.fileno())
        os.chmod(tmp, 0o644)  # mkstemp creates 0600; a checkpoint is meant to be shared
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    dir_fd = os.open(path.parent, os.O_RDONLY)
    try:
        os.fsync(dir_fd)
    finally:
        os.close(dir_fd)
    for stale in path.parent.glob(f".{path.name}.*.tmp"):  # a writer SIGKILLed mid-write left it
        stale.unlink(missing_ok=True)


def check_exists(path: Path) -> None:
    """A one-line CheckpointError unless `path` is a file (a relative one names the folder it
    was looked for in: an experiment file's paths are the current directory's, not its own)."""
    if path.is_dir():
        raise CheckpointError(f"checkpoint {path} is a directory, not a checkpoint file")
    if path.exists() and not path.is_file():  # (/dev/null, a FIFO: "not found" misled)
        raise CheckpointError(f"checkpoint {path} is a special file (a device or FIFO), not a "
                              "checkpoint file")
    if not path.is_file():
        where = "" if path.is_absolute() else f" (relative to {Path.cwd()})"
        repo = Path(__file__).resolve().parents[1] / path  # (a result file's relative paths
        if not path.is_absolute() and repo.is_file():      # are the repository's)
            where += f"; results name the repository's {repo} so"
        raise CheckpointError(f"checkpoint not found: {path}{where}")


def check_readable(path: Path) -> None:
    """`check_exists`, and a one-line CheckpointError unless `path` is a zip archive (what
    torch.save writes) whose every member matches its CRC: both readers refuse a truncated,
    corrupted or foreign file in the same words (torch.load does not check the CRCs: a file
    with flipped bytes loaded, and acted, with other weights)."""
    check_exists(path)
    if not zipfile.is_zipfile(path):  # (else torch's advice, or zipfile's, misleads)
        raise CheckpointError(f"checkpoint {path} is unreadable: not a torch checkpoint file "
                              "(a .pt that swarm train wrote)")
    try:
        with zipfile.ZipFile(path) as z:
            bad = z.testzip()
    except (zipfile.BadZipFile, OSError, EOFError, ValueError) as exc:
        raise CheckpointError(f"checkpoint {path} is unreadable: {exc}") from None
    if bad is not None:
        raise CheckpointError(f"checkpoint {path} is unreadable: Bad CRC-32 for file {bad!r}")
    with zipfile.ZipFile(path) as z:  # (torch.save writes ARCHIVE/version and ARCHIVE/data.pkl)
        names = z.namelist()
    if not any(n.endswith("/version") for n in names) or \
            not any(n.endswith("/data.pkl") for n in names):  # (else PyTorch's own words, or
        raise CheckpointError(                               # "pickle data was truncated")
            f"checkpoint {path} is unreadable: not a torch checkpoint file (a zip archive "
            "without torch.save's version record and data)")


def load_checkpoint(path: str | Path) -> dict[str, Any]:
    """Read a checkpoint written by `save_checkpoint`; any problem is a one-line CheckpointError."""
    import torch

    check_readable(path := Path(path))
    try:
        data = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # noqa: BLE001 - any unpickling problem means "not a checkpoint"
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        if first.startswith("Weights only load failed"):
            first = "it holds objects beyond tensors and plain data (refused: loading them " \
                    "could run code)"
        raise CheckpointError(f"checkpoint {path} is unreadable: {first}") from None
    return _checked(data, path)


def read_checkpoint(path: str | Path) -> dict[str, Any]:
    """`load_checkpoint` without torch: the same dict with numpy arrays for tensors."""
    from policies.infer.ptfile import PtFileError, load_pt

    check_readable(path := Path(path))
    try:
        data = load_pt(path)
    except PtFileError as exc:
        raise CheckpointError(f"checkpoint {path} is unreadable: {exc}") from None
    return _checked(data, path)


FIELDS = {"policy": str, "model": dict, "world": dict, "state_dict": dict}
"""The fields every checkpoint has, and their type."""
OPTIONAL = {"meta": dict, "train": dict, "learner": dict}
"""Fields some checkpoints have (trainer or learner state), and their type."""
WEIGHT_DTYPES = ("float32", "float16", "float64", "bfloat16")
"""The weight dtypes a checkpoint may hold (torch's and numpy's names agree); the torch-free
reader widens bfloat16 to float32 (exactly: it is float32's upper half), numpy having none."""


def _checked(data: Any, path: Path) -> dict[str, Any]:
    """`data` if it is a checkpoint dict: the fields of their types, weights floating-point
    arrays (numpy or torch) with names (an integer, bool or complex one was cast and run), and
    every weight finite (a diverged run's NaNs left robots standing still); a one-line
    CheckpointError naming the file and the field otherwise."""
    if not isinstance(data, dict) or data.get("format") != FORMAT:
        raise CheckpointError(f"checkpoint {path} is not a format-{FORMAT} checkpoint")
    missing = [k for k in FIELDS if k not in data]
    if missing:
        raise CheckpointError(f"checkpoint {path} lacks {', '.join(missing)}")
    for key, kind in {**FIELDS, **OPTIONAL}.items():
        if key in data and not isinstance(data[key], kind):
            what = "None" if data[key] is None else f"a {type(data[key]).__name__}"
            raise CheckpointError(f"checkpoint {path}: field {key!r} is {what}, not a "
                                  f"{kind.__name__}")
    for key in ("model", "world"):
        if not all(isinstance(k, str) for k in data[key]):
            raise CheckpointError(f"checkpoint {path}: field {key!r} has a key that is not a "
                                  "name")
    for key, value in data["state_dict"].items():
        if not isinstance(key, str) or not (hasattr(value, "shape") and hasattr(value, "dtype")):
            raise CheckpointError(f"checkpoint {path}: field 'state_dict' holds {key!r}, which "
                                  "is not a named weight array")
        kind = str(value.dtype).removeprefix("torch.")
        if kind not in WEIGHT_DTYPES:
            raise CheckpointError(f"checkpoint {path}: weight {key} is {kind}, expected a "
                                  f"floating-point tensor ({', '.join(WEIGHT_DTYPES)})")
        # (torch's own test: numpy has no bfloat16 to convert a torch tensor to)
        finite = value.isfinite() if hasattr(value, "isfinite") else np.isfinite(value)
        if not finite.all():
            raise CheckpointError(f"checkpoint {path} has non-finite weights (NaN or inf) in "
                                  f"{key}: the run that wrote it diverged")
    return data
