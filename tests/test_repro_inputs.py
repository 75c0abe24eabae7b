"""`swarm repro`'s inputs checked in one line before any work (in-process: `swarm.cli.main`)."""

from __future__ import annotations

from pathlib import Path

import pytest
from conftest import ROOT

from swarm.cli import main


def refused(args: list[str], capsys: pytest.CaptureFixture[str]) -> str:
    """The one `swarm: error:` line of `swarm ARGS`, which must exit 2."""
    code = main(args)
    err = capsys.readouterr().err
    lines = err.rstrip("\n").splitlines()
    assert code == 2 and len(lines) == 1 and lines[0].startswith("swarm: error: "), err
    return lines[0]


@pytest.mark.parametrize(("curve", "says"), [
    (ROOT / "README.md", "is not a training curve"),
    (ROOT / "results" / "repro" / "comm.csv", "is not a training curve"),
    (ROOT / "checkpoints" / "commattn.pt", "is not a training curve (not a text file)"),
    (ROOT / "checkpoints", "Is a directory"),
], ids=["text", "other-csv", "binary", "folder"])
def test_repro_fig8_refuses_a_file_that_is_no_training_curve(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], curve: Path, says: str) -> None:
    """UA 64: another CSV or a text file was a ValueError traceback, a binary one a
    UnicodeDecodeError, a folder "not found"."""
    line = refused(["repro", "fig8", "--out", str(tmp_path / "o"), "--curve",
                    f"commattn={curve}"], capsys)
    assert says in line, line
    assert not (tmp_path / "o" / "fig8.csv").exists()


def test_repro_fig8_refuses_a_curve_of_no_policy_or_one_not_drawn(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """UA 64: `--curve bogus=FILE` was accepted, and the figure drawn without it."""
    shipped = ROOT / "checkpoints" / "vain_curve.csv"
    out = str(tmp_path / "o")
    line = refused(["repro", "fig8", "--out", out, "--curve", f"bogus={shipped}"], capsys)
    assert "--curve bogus=...: not a learned policy" in line, line
    line = refused(["repro", "fig8", "--out", out, "--policies", "commattn", "--curve",
                    f"vain={shipped}"], capsys)
    assert "vain is not among --policies commattn" in line, line


@pytest.mark.parametrize("flag", ["--curve", "--checkpoint"])
def test_repro_refuses_a_name_given_twice(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                          flag: str) -> None:
    """UA 64: `--curve commattn=A --curve commattn=B` kept B without a word."""
    given = ROOT / "checkpoints" / ("commattn_curve.csv" if flag == "--curve" else "commattn.pt")
    line = refused(["repro", "fig8", "--policies", "commattn", "--out", str(tmp_path / "o"),
                    flag, f"commattn={given}", flag, f"commattn={given}"], capsys)
    assert f"{flag} commattn=... given 2 times" in line, line
