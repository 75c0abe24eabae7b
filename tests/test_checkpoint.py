"""Checkpoint files as every command reads them (policies.checkpoint): a checkpoint that is cut
short, holds fields of the wrong type, or weights that are not floating-point or not finite is
refused in one line naming the file, by the torch reader and the torch-free one alike (real
files, a tiny real network)."""

from __future__ import annotations

import zipfile
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch
from conftest import ROOT, swarm_here

from policies import make_policy
from policies.checkpoint import CheckpointError, load_checkpoint, read_checkpoint, save_checkpoint
from policies.infer.nets import CommAttnConfig
from policies.infer.policy import inference_class
from world.config import WorldConfig

TINY_NET = CommAttnConfig(embed=4, hidden=4, state=4, match=4, action_embed=4)


def tiny_checkpoint(path: Path, dtype: torch.dtype | None = None, **changes: Any) -> Path:
    """A commattn checkpoint of a tiny network for the default world, with `changes` to its
    top-level fields (`nan`/`inf`: the first weight's first entry set to that; `dtype`: every
    weight's dtype)."""
    torch.manual_seed(0)
    payload = make_policy("commattn", WorldConfig(), model=TINY_NET).payload({"command": "test"})
    if dtype is not None:
        payload["state_dict"] = {k: v.to(dtype) for k, v in payload["state_dict"].items()}
    for bad in ("nan", "inf"):
        if changes.pop(bad, False):
            key = next(iter(payload["state_dict"]))
            weight = payload["state_dict"][key].detach().clone()
            weight.view(-1)[0] = float(bad)
            payload["state_dict"][key] = weight
    save_checkpoint(path, {**payload, **changes})
    return path


BROKEN = {
    "nan": ({"nan": True}, "non-finite weights"),
    "inf": ({"inf": True}, "non-finite weights"),
    "model-str": ({"model": "garbage"}, "field 'model' is a str, not a dict"),
    "model-none": ({"model": None}, "field 'model' is None, not a dict"),
    "state-dict-list": ({"state_dict": [1, 2]}, "field 'state_dict' is a list, not a dict"),
    "weight-not-array": ({"state_dict": {"w": 3}}, "'w', which is not a named weight array"),
    "world-str": ({"world": "x"}, "field 'world' is a str, not a dict"),
    "meta-str": ({"meta": "x"}, "field 'meta' is a str, not a dict"),
    "train-list": ({"train": [1]}, "field 'train' is a list, not a dict"),
    "int64": ({"dtype": torch.int64}, "weight s0 is int64, expected a floating-point tensor"),
    "bool": ({"dtype": torch.bool}, "weight s0 is bool, expected a floating-point tensor"),
    "complex64": ({"dtype": torch.complex64},
                  "weight s0 is complex64, expected a floating-point tensor"),
}


@pytest.mark.parametrize("case", BROKEN)
def test_both_readers_refuse_a_checkpoint_of_wrong_types_or_non_finite_weights(
        tmp_path: Path, case: str) -> None:
    changes, words = BROKEN[case]
    path = tiny_checkpoint(tmp_path / "bad.pt", **changes)
    messages = []
    for reader in (load_checkpoint, read_checkpoint):
        with pytest.raises(CheckpointError) as err:
            reader(path)
        messages.append(str(err.value))
    assert messages[0] == messages[1]
    assert words in messages[0] and str(path) in messages[0] and "\n" not in messages[0]
    good = tiny_checkpoint(tmp_path / "good.pt")
    assert read_checkpoint(good)["meta"] == {"command": "test"}
    assert set(load_checkpoint(good)["state_dict"]) == set(read_checkpoint(good)["state_dict"])


@pytest.mark.parametrize("dtype", [torch.float16, torch.float64, torch.bfloat16], ids=str)
def test_both_readers_read_weights_of_every_float_dtype_alike(tmp_path: Path,
                                                               dtype: torch.dtype) -> None:
    """float16, float64 and bfloat16 weights load (the networks compute in float32); the
    torch-free reader widens bfloat16, which numpy lacks, to the same float32 values."""
    path = tiny_checkpoint(tmp_path / "w.pt", dtype=dtype)
    theirs, ours = load_checkpoint(path)["state_dict"], read_checkpoint(path)["state_dict"]
    for key, tensor in theirs.items():
        assert tensor.dtype == dtype
        np.testing.assert_array_equal(ours[key], tensor.float().numpy())
    a, b = make_policy("commattn", WorldConfig(), checkpoint=str(path)), \
        inference_class("commattn")(WorldConfig(), checkpoint=path)
    for key, weight in a.weights.items():
        np.testing.assert_array_equal(b.weights[key], weight)


def test_both_readers_call_a_truncated_checkpoint_not_a_torch_file(tmp_path: Path) -> None:
    raw = tiny_checkpoint(tmp_path / "good.pt").read_bytes()
    cut = tmp_path / "cut.pt"
    cut.write_bytes(raw[:len(raw) // 2])
    for reader in (load_checkpoint, read_checkpoint):
        with pytest.raises(CheckpointError, match="unreadable: not a torch checkpoint file"):
            reader(cut)


def test_both_readers_call_a_foreign_zip_not_a_torch_file(tmp_path: Path) -> None:
    """A zip archive torch.save did not write (no version record) is refused in the readers'
    own words: torch.load said `Expected hasRecord("version") to be true` and asked for a
    bug report, the numpy reader "pickle data was truncated"."""
    foreign = tmp_path / "foreign.pt"
    with zipfile.ZipFile(foreign, "w") as z:
        z.writestr("archive/data.pkl", b"garbage")
    for reader in (load_checkpoint, read_checkpoint):
        with pytest.raises(CheckpointError, match="not a torch checkpoint file .a zip archive "
                                                  "without torch.save's version record"):
            reader(foreign)


def test_both_readers_refuse_a_checkpoint_with_flipped_bytes(tmp_path: Path) -> None:
    """torch.load does not check the zip's CRCs: a checkpoint with bytes flipped inside a
    tensor loaded, and `swarm eval` ran other weights (0.912 for 0.920), while the numpy
    reader (`swarm run`) refused it."""
    raw = bytearray(tiny_checkpoint(tmp_path / "good.pt").read_bytes())
    with zipfile.ZipFile(tmp_path / "good.pt") as z:
        member = next(i for i in z.infolist() if "/data/" in i.filename and i.file_size >= 16)
    head = member.header_offset  # (the local header's own name and extra lengths)
    start = head + 30 + int.from_bytes(raw[head + 26:head + 28], "little") + \
        int.from_bytes(raw[head + 28:head + 30], "little")
    raw[start:start + 8] = bytes(b ^ 0xFF for b in raw[start:start + 8])
    bad = tmp_path / "flipped.pt"
    bad.write_bytes(raw)
    messages = []
    for reader in (load_checkpoint, read_checkpoint):
        with pytest.raises(CheckpointError) as err:
            reader(bad)
        messages.append(str(err.value))
    assert messages[0] == messages[1]
    assert f"unreadable: Bad CRC-32 for file {member.filename!r}" in messages[0], messages[0]


def one_line_error(r: Any, words: str) -> None:
    assert r.returncode == 2, (r.returncode, r.stderr)
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("swarm: error: ") and words in lines[0], \
        r.stderr


@pytest.mark.procs
def test_every_command_refuses_a_bad_checkpoint_in_one_line(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    nan = str(tiny_checkpoint(tmp_path / "nan.pt", nan=True))
    garbage = str(tiny_checkpoint(tmp_path / "garbage.pt", model="garbage"))
    whole = str(tiny_checkpoint(tmp_path / "int.pt", dtype=torch.int64))
    complex_ = str(tiny_checkpoint(tmp_path / "complex.pt", dtype=torch.complex64))
    # (each reader's refusal of every dtype: the test above; here, that each command reaches
    # them: complex64 stops the torch-free reader of `run` at its storage, int64 after it)
    # (`eval` reads with torch, as `train --init` and `bench policy` do: one of each suffices)

    def swarm_(*args: str) -> Any:
        return swarm_here(*args, capsys=capsys)

    one_line_error(swarm_("eval", "--policy", "commattn", "--checkpoint", nan, "--episodes",
                          "1", "--robots", "2", "--horizon", "5"), "non-finite weights")
    for bad, words in ((nan, "non-finite weights"), (whole, "weight s0 is int64"),
                       (complex_, "weight s0 is complex64")):
        one_line_error(swarm_("run", "--headless", "--policy", "commattn", "--checkpoint", bad,
                              "--robots", "2", "--episodes", "1", "--horizon", "5",
                              "--log-dir", str(tmp_path / "logs")), words)
    one_line_error(swarm_("bench", "policy", "--policies", "commattn", "--checkpoint",
                          f"commattn={whole}"), "weight s0 is int64")
    one_line_error(swarm_("train", "--init", garbage, "--out", str(tmp_path / "t"),
                          "--epochs", "1"), "field 'model' is a str")
    run = tmp_path / "run"
    run.mkdir()
    raw = tiny_checkpoint(tmp_path / "good.pt").read_bytes()
    (run / "checkpoint.pt").write_bytes(raw[:len(raw) // 2])
    one_line_error(swarm_("train", "--resume", "--out", str(run)), "not a torch checkpoint file")


def test_a_checkpoint_for_a_hand_written_policy_is_one_line() -> None:
    """`make_policy("nearest-frontier", cfg, checkpoint=...)` was the class's bare TypeError
    (an unexpected keyword argument)."""
    with pytest.raises(ValueError, match="a checkpoint applies to learned policies only, not "
                                         "'nearest-frontier'"):
        make_policy("nearest-frontier", WorldConfig(), checkpoint="checkpoints/commattn.pt")


def test_a_relative_path_a_result_names_is_found_in_the_repository_hint(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """UA pass 73: a result JSON names the shipped checkpoint `checkpoints/commattn.pt`
    (relative to the repository); given back from another folder it was only "not found"."""
    from policies.checkpoint import CheckpointError, check_exists

    monkeypatch.chdir(tmp_path)
    with pytest.raises(CheckpointError) as err:
        check_exists(Path("checkpoints/commattn.pt"))
    assert f"relative to {tmp_path}" in str(err.value)
    assert f"results name the repository's {ROOT / 'checkpoints' / 'commattn.pt'}" in str(err.value)
    with pytest.raises(CheckpointError) as err:  # (no hint for a file the repository lacks)
        check_exists(Path("checkpoints/none.pt"))
    assert "repository" not in str(err.value)


def test_a_special_file_is_no_checkpoint_and_is_not_called_missing() -> None:
    """`--checkpoint /dev/null` said "checkpoint not found" (review helper 95)."""
    from policies.checkpoint import check_exists

    with pytest.raises(CheckpointError, match="/dev/null is a special file"):
        check_exists(Path("/dev/null"))
