"""Read a checkpoint written by `torch.save` without torch: numpy arrays in place of tensors.

A torch file is a zip archive: `<prefix>/data.pkl` pickles the object, with every tensor a call
to `torch._utils._rebuild_tensor_v2(storage, offset, size, stride, ...)` whose storage is a
persistent id naming a raw little-endian file `<prefix>/data/<key>`. The unpickler here accepts
only those globals (and `collections.OrderedDict`), as `torch.load(weights_only=True)` does, so a
file that would run code when unpickled is refused, not executed.
"""

from __future__ import annotations

import collections
import io
import pickle
import zipfile
from pathlib import Path
from typing import Any

import numpy as np

DTYPES = {
    "FloatStorage": np.float32, "DoubleStorage": np.float64, "HalfStorage": np.float16,
    "LongStorage": np.int64, "IntStorage": np.int32, "ShortStorage": np.int16,
    "CharStorage": np.int8, "ByteStorage": np.uint8, "BoolStorage": np.bool_,
    "ComplexFloatStorage": np.complex64, "ComplexDoubleStorage": np.complex128,
    "BFloat16Storage": np.uint16,  # widened to float32 when read (numpy has no bfloat16)
}
"""The numpy dtype of each torch storage this reader reads (what the data holds is the
caller's to check: policies.checkpoint refuses weights that are not floating-point)."""


class PtFileError(ValueError):
    """Not a torch file this reader accepts; the message is one line."""


class _Storage:
    def __init__(self, name: str) -> None:
        self.dtype = np.dtype(DTYPES[name]).newbyteorder("<")
        self.bfloat16 = name == "BFloat16Storage"

    def read(self, raw: bytes) -> np.ndarray:
        """The storage's elements from its raw little-endian bytes."""
        data = np.frombuffer(raw, dtype=self.dtype)
        if self.bfloat16:  # a bfloat16 is the upper 16 bits of the float32 it stands for
            return (data.astype("<u4") << 16).view("<f4")
        return data


def _rebuild_tensor(storage: np.ndarray, offset: int, size: tuple[int, ...],
                    stride: tuple[int, ...], *_: Any) -> np.ndarray:
    if not (isinstance(offset, int) and offset >= 0 and all(
            isinstance(n, int) and n >= 0 for n in (*size, *stride))):
        raise PtFileError("a tensor has a negative or non-integer offset, size or stride")
    if not size:
        if offset >= len(storage):
            raise PtFileError("a tensor reaches past its storage")
        return storage[offset:offset + 1].reshape(()).copy()
    item = storage.itemsize
    need = offset + 1 + sum((n - 1) * s for n, s in zip(size, stride, strict=True) if n > 0)
    if any(n == 0 for n in size):
        return np.zeros(size, dtype=storage.dtype)
    if need > len(storage):
        raise PtFileError("a tensor reaches past its storage")
    view = np.lib.stride_tricks.as_strided(storage[offset:], shape=size,
                                           strides=tuple(s * item for s in stride))
    return np.array(view, dtype=storage.dtype.newbyteorder("="))


class _Unpickler(pickle.Unpickler):
    def __init__(self, data: bytes, archive: zipfile.ZipFile, prefix: str) -> None:
        super().__init__(io.BytesIO(data))
        self.archive, self.prefix = archive, prefix
        self.storages: dict[str, np.ndarray] = {}

    def find_class(self, module: str, name: str) -> Any:
        if (module, name) == ("collections", "OrderedDict"):
            return collections.OrderedDict
        if (module, name) == ("torch._utils", "_rebuild_tensor_v2"):
            return _rebuild_tensor
        if module == "torch" and name in DTYPES:
            return _Storage(name)
        raise PtFileError(f"refuses to load {module}.{name} (only weights are read)")

    def persistent_load(self, pid: Any) -> np.ndarray:
        if not (isinstance(pid, tuple) and len(pid) >= 5 and pid[0] == "storage"
                and isinstance(pid[1], _Storage)):
            raise PtFileError("unknown persistent id")
        kind, key = pid[1], str(pid[2])
        if key not in self.storages:
            try:
                raw = self.archive.read(f"{self.prefix}/data/{key}")
            except KeyError:
                raise PtFileError(f"storage {key} is missing") from None
            self.storages[key] = kind.read(raw)
        return self.storages[key]


def load_pt(path: str | Path) -> Any:
    """The object in the torch file at `path`, tensors as numpy arrays; PtFileError if it is not
    a readable zip-format torch file of plain containers and tensors."""
    try:
        with zipfile.ZipFile(path) as archive:
            pkl = [n for n in archive.namelist() if n.endswith("/data.pkl")]
            if len(pkl) != 1:
                raise PtFileError("not a torch zip file (no single data.pkl)")
            prefix = pkl[0][:-len("/data.pkl")]
            order = f"{prefix}/byteorder"
            if order in archive.namelist() and archive.read(order).strip() != b"little":
                raise PtFileError("big-endian torch files are not supported")
            return _Unpickler(archive.read(pkl[0]), archive, prefix).load()
    except PtFileError:
        raise
    except (zipfile.BadZipFile, OSError, pickle.UnpicklingError, EOFError, ValueError,
            TypeError, KeyError, AttributeError, IndexError) as exc:
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise PtFileError(first) from None
