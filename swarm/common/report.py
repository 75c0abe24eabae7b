"""Writing results a person reads: Markdown tables with provenance, CSV, PNG figures (matplotlib,
Agg), every file atomically. Shared by `swarm repro`, `swarm experiment` and training curves."""

from __future__ import annotations

import csv
import datetime as dt
import functools
import io
import math
import platform
import subprocess
import sys
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from swarm.common import atomic

PROVENANCE_PACKAGES = ("commattn-swarm", "numpy", "torch", "eclipse-zenoh", "msgpack")


@functools.cache
def provenance() -> dict[str, Any]:
    """What made a result, for its JSON: package versions (read from the installed metadata,
    nothing imported), the source tree's git commit (`+dirty` with uncommitted changes to
    tracked files; None outside a checkout), Python and the platform."""
    from importlib import metadata  # (~50 ms a process: only where a result is written)

    versions: dict[str, str | None] = {}
    for name in PROVENANCE_PACKAGES:
        try:
            versions[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            versions[name] = None
    root = Path(__file__).resolve().parents[2]
    commit = None
    if (root / ".git").exists():
        try:
            git = ["git", "-C", str(root)]
            head = subprocess.run([*git, "rev-parse", "HEAD"], capture_output=True, text=True,
                                  timeout=5, check=True).stdout.strip()
            dirty = subprocess.run([*git, "status", "--porcelain", "--untracked-files=no"],
                                   capture_output=True, text=True, timeout=5).stdout.strip()
            commit = head + ("+dirty" if dirty else "")
        except (OSError, subprocess.SubprocessError):
            commit = None
    return {"versions": versions, "git": commit, "python": sys.version.split()[0],
            "platform": platform.platform()}


def header(title: str, command: str, seed: int, note: str,
           checkpoints: Mapping[str, Sequence[str]] | None = None) -> str:
    """The Markdown heading plus the provenance line every item file starts with: the command,
    seed, date and the checkpoints the learned policies ran (`checkpoints_of`)."""
    today = dt.date.today().isoformat()
    ran = "; ".join(f"{name} {', '.join(f'`{c}`' for c in paths)}"
                    for name, paths in (checkpoints or {}).items())
    ran = f" Checkpoints: {ran}." if ran else ""
    return f"# {title}\n\nMade by `{command}` (seed {seed}, {today}).{ran} {note}\n\n"


def checkpoints_of(rows: Sequence[Mapping[str, Any]]) -> dict[str, list[str]]:
    """Per policy, the checkpoints its rows ran (their `checkpoint` column, in the order first
    run; several where a point needs its own, as fig9's visions), policies without weights left
    out: what an item's JSON `checkpoints` and its Made by line name."""
    ran: dict[str, list[str]] = {}
    for r in rows:
        if r.get("checkpoint") and r["checkpoint"] not in ran.get(r["policy"], []):
            ran.setdefault(r["policy"], []).append(r["checkpoint"])
    return ran


def paired(first: np.ndarray, other: np.ndarray) -> tuple[float, float]:
    """Mean of first - other over the same episodes and the standard error of that mean (nan
    from a single episode)."""
    diff = np.asarray(first) - np.asarray(other)
    se = float(diff.std(ddof=1) / np.sqrt(len(diff))) if len(diff) > 1 else float("nan")
    return float(diff.mean()), se


def counted(n: int, noun: str) -> str:
    """`1 episode`, `2 episodes`: a count with its noun in the right number."""
    return f"{n} {noun}" if n == 1 else f"{n} {noun}s"


def paired_cell(mean: float, se: float) -> str:
    """A paired difference as a table cell: `+0.0043 ± 0.0018` (`+0.0043 (1 episode: no se)`
    from a single episode, whose standard error is nan)."""
    if math.isnan(se):
        return f"{mean:+.4f} (1 episode: no se)"
    return f"{mean:+.4f} ± {se:.4f}"


def md_table(columns: Sequence[str], rows: Sequence[Sequence[str]]) -> str:
    """A GitHub Markdown table, first column left-aligned and the rest right-aligned."""
    lines = ["| " + " | ".join(columns) + " |",
             "|" + "|".join([":---"] + ["---:"] * (len(columns) - 1)) + "|"]
    lines += ["| " + " | ".join(r) + " |" for r in rows]
    return "\n".join(lines) + "\n"


def csv_text(rows: Sequence[dict[str, Any]]) -> str:
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=list(rows[0]), lineterminator="\n")
    writer.writeheader()
    writer.writerows(rows)
    return buf.getvalue()


def save_png(path: Path, draw: Callable[[Any], None], ncols: int = 1) -> None:
    """Draw on a fresh Agg figure (one axes, or a row of `ncols`) and write it atomically."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(1, ncols, figsize=(6.4 * ncols ** 0.8, 4.2))
    try:
        draw(ax)
        fig.tight_layout()
        buf = io.BytesIO()
        fig.savefig(buf, format="png", dpi=120)
    finally:
        plt.close(fig)
    atomic.write_bytes(path, buf.getvalue())


def item_files(item: str) -> tuple[str, ...]:
    """The names of the files repro item `item` writes into its output directory (those of
    `write_item`, or fig10's and fig11's own)."""
    if item in ("fig10", "fig11"):
        extra = "scores" if item == "fig10" else "by_neighbours"
        return (f"{item}.png", f"{item}.csv", f"{item}_{extra}.csv", f"{item}_{extra}.md")
    return _table_files(item)


def _table_files(item: str) -> tuple[str, str, str, str]:
    """`write_item`'s files, in its order: ITEM.csv, .md, .png, .json."""
    return f"{item}.csv", f"{item}.md", f"{item}.png", f"{item}.json"


def write_item(out: Path, item: str, rows: list[dict[str, Any]], md: str,
               draw: Callable[[Any], None], meta: dict[str, Any], ncols: int = 1) -> list[str]:
    """Write ITEM.csv/.md/.png/.json; returns the paths written. Rows with a `checkpoint`
    column give the JSON its `checkpoints` (`checkpoints_of`)."""
    paths = [out / name for name in _table_files(item)]
    atomic.write_text(paths[0], csv_text(rows))
    atomic.write_text(paths[1], md)
    save_png(paths[2], draw, ncols)
    ran = {"checkpoints": checkpoints_of(rows)} if any("checkpoint" in r for r in rows) else {}
    atomic.write_json(paths[3], {**meta, **ran, "provenance": provenance(), "rows": rows})
    return [str(p) for p in paths]


class OutputClosed(KeyboardInterrupt):
    """The reader of stdout went away (`swarm run --headless | head`): the command stops as on
    Ctrl-C, and says why (exit status 141, as a shell reports a SIGPIPE)."""


def json_line(obj: Any) -> None:
    """One JSON object on a line of stdout (`--headless`). A reader that went away (`| head`)
    ends the command as Ctrl-C does (OutputClosed, a KeyboardInterrupt), with stdout sent to
    /dev/null so the exit's own flush is quiet, instead of a warning per record."""
    import json
    import os
    import sys

    try:
        print(json.dumps(obj), flush=True)
    except BrokenPipeError:
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        raise OutputClosed from None


def printable(text: str) -> str:
    """`text` with the undecodable bytes of arguments (surrogate escapes) shown as \\xNN: a
    command line that names such a path still writes as UTF-8."""
    return text.encode("utf-8", "surrogateescape").decode("utf-8", "backslashreplace")
