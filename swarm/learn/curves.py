"""Training curves: the one writer of `curve.csv` + `log.jsonl` used by the batched trainer and the
learner process (truncated to the checkpoint on resume), and the curve's reader and figure."""

from __future__ import annotations

import csv
import io
import json
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from swarm.common.atomic import remove_stale, write_text
from swarm.common.policy_spec import shown
from swarm.common.report import header, md_table, save_png, write_item
from world.config import ConfigError

CURVE_FIELDS = ["update", "epoch", "episodes", "n_dynamic", "elratio", "success", "reward",
                "collisions", "block_collisions", "entropy", "loss", "pg", "baseline", "grad_norm",
                "episodes_per_s", "elapsed_s"]


RUN_FILES = ("checkpoint.pt", "curve.csv", "log.jsonl", "curve.png")
"""The files of a training run's folder written atomically (a temp file, then a rename): a
kill mid-write leaves `.NAME.XXXX.tmp`, removed when the run starts or resumes."""


class CurveLog:
    """`DIR/curve.csv` (one row of CURVE_FIELDS per update) and `DIR/log.jsonl` (every row)."""

    def __init__(self, out: Path) -> None:
        self.csv, self.jsonl = Path(out) / "curve.csv", Path(out) / "log.jsonl"

    def start(self) -> None:
        """A fresh run: the header only."""
        remove_stale(self.csv.parent, RUN_FILES)
        self.csv.write_text(",".join(CURVE_FIELDS) + "\n")
        self.jsonl.write_text("")

    def resume(self, update: int) -> None:
        """Drop rows past update `update` (written after the checkpoint a run resumes from) and
        any row a kill cut short. The files are replaced atomically (a kill here leaves the old
        rows), and only if rows go. Temp files a killed run left (RUN_FILES) are removed."""
        remove_stale(self.csv.parent, RUN_FILES)
        for path, is_csv in ((self.csv, True), (self.jsonl, False)):
            if not path.exists():
                continue
            with path.open(newline="") as fh:
                lines = fh.read().splitlines(keepends=True)
            out = lines[:1] if is_csv else []
            for line in lines[1:] if is_csv else lines:
                try:
                    upd = int(next(csv.reader([line]))[0]) if is_csv else int(json.loads(line).get(
                        "update", 0))
                except (ValueError, IndexError, AttributeError, TypeError):  # (a torn write)
                    continue
                if upd <= update and line.endswith("\n"):
                    out.append(line)
            if len(out) < len(lines):
                write_text(path, "".join(out))

    def last_elapsed(self) -> float:
        """The last row's `elapsed_s` (0 for none): where a resumed run's clock goes on from when
        its checkpoint predates the trainer state's `elapsed_s`."""
        try:
            return read_curve(self.csv)["elapsed_s"][-1]
        except (ConfigError, KeyError, IndexError):
            return 0.0

    def append(self, row: dict[str, Any], **extra: Any) -> None:
        """One update's row: CURVE_FIELDS to the CSV, everything (plus `extra`) to the log."""
        with self.jsonl.open("a") as fh:
            fh.write(json.dumps({"kind": "update", **extra, **row}) + "\n")
        buf = io.StringIO()
        csv.writer(buf, lineterminator="\n").writerow(
            [f"{row[k]:.6g}" if isinstance(row[k], float) else row[k] for k in CURVE_FIELDS])
        with self.csv.open("a") as fh:
            fh.write(buf.getvalue())

    def note(self, record: dict[str, Any]) -> None:
        """A non-update line of the log (e.g. an epoch's validation)."""
        with self.jsonl.open("a") as fh:
            fh.write(json.dumps(record) + "\n")


def read_curve(path: Path) -> dict[str, list[float]]:
    """Columns of a trainer curve CSV (CURVE_FIELDS) as floats; a file that is not one (another
    CSV, text, a binary or a folder) is a one-line ConfigError."""
    not_curve = f"{path} is not a training curve"
    try:
        with path.open(newline="") as fh:
            reader = csv.DictReader(fh)
            cols: dict[str, list[float]] = {k: [] for k in reader.fieldnames or []}
            for row in reader:
                if None in row or None in row.values():  # (more or fewer cells than the header)
                    raise ConfigError(f"{not_curve} (line {reader.line_num}: not one cell per "
                                      "column)")
                for k, v in row.items():
                    cols[k].append(float(v))
    except ConfigError:  # (a ValueError too: said as raised above)
        raise
    except UnicodeDecodeError:  # (before ValueError, of which it is one)
        raise ConfigError(f"{not_curve} (not a text file)") from None
    except ValueError:  # float() of a word
        raise ConfigError(f"{not_curve} (line {reader.line_num}: a cell that is not a "
                          "number)") from None
    except csv.Error as exc:
        raise ConfigError(f"{not_curve} ({exc})") from None
    except OSError as exc:
        raise ConfigError(f"cannot read training curve {path}: {exc.strerror or exc}") from None
    for key in ("update", "episodes", "elratio", "reward"):
        if not cols.get(key):
            raise ConfigError(f"{path} is not a training curve (no {key!r} column or no rows)")
    return cols


def moving_mean(xs: Sequence[float], window: int) -> list[float]:
    out, acc = [], 0.0
    for k, x in enumerate(xs):
        acc += x
        if k >= window:
            acc -= xs[k - window]
        out.append(acc / min(k + 1, window))
    return out


def plot_curve(csv_path: Path, png_path: Path, title: str, smooth: int = 25) -> None:
    """One run's training curve (`swarm train` writes OUT/curve.png with it every epoch):
    smoothed elratio and reward per robot, and the curriculum's dynamic blocks."""
    c = read_curve(Path(csv_path))
    ep = [e / 1000 for e in c["episodes"]]

    def draw(axes: Any) -> None:
        axes[0].plot(ep, moving_mean(c["elratio"], smooth), label="elratio (sampled)")
        if c.get("block_collisions"):
            twin = axes[0].twinx()
            twin.plot(ep, moving_mean(c["block_collisions"], smooth), color="C3", alpha=0.6,
                      label="block collisions")
            twin.set_ylabel("block collisions per episode", color="C3")
        axes[0].set_ylabel(f"training elratio (moving mean of {smooth} updates)")
        axes[1].plot(ep, moving_mean(c["reward"], smooth), color="C2")
        axes[1].set_ylabel("training reward per robot")
        if c.get("n_dynamic"):
            twin = axes[1].twinx()
            twin.plot(ep, c["n_dynamic"], color="C1", alpha=0.6)
            twin.set_ylabel("dynamic blocks (curriculum)", color="C1")
        for ax in axes:
            ax.set_xlabel("training episodes (thousands)")
            ax.grid(alpha=0.3)
        import textwrap

        axes[0].figure.suptitle("\n".join(textwrap.wrap(title, 170)), fontsize=8, x=0.01,
                                ha="left")

    save_png(Path(png_path), draw, ncols=2)


def run_world(curve: Path) -> dict[str, Any] | None:
    """The world a training curve was trained on, from the checkpoint beside it (a run folder's
    `checkpoint.pt`, or `NAME.pt` beside a shipped `NAME_curve.csv`); None where none reads."""
    from policies.checkpoint import read_checkpoint

    stem = curve.name.removesuffix("_curve.csv")
    beside = curve.with_name(f"{stem}.pt" if stem != curve.name else "checkpoint.pt")
    try:
        return read_checkpoint(beside)["world"] if beside.is_file() else None
    except ConfigError:
        return None


def world_note(paths: dict[str, Path]) -> str:
    """A sentence when the curves were trained on different worlds (their checkpoints'), naming
    each curve's differing fields; "" when they agree or are unknown."""
    worlds = {n: w for n, p in paths.items() if (w := run_world(Path(p))) is not None}
    keys = sorted(k for k in {k for w in worlds.values() for k in w}
                  if len({repr(w.get(k)) for w in worlds.values()}) > 1)
    if not keys:
        return ""
    return ("Not comparable: these curves were trained on different worlds (" + "; ".join(
        f"{n}: " + ", ".join(f"{k} {w.get(k)}" for k in keys) for n, w in worlds.items()) + ").")


def fig8(paths: dict[str, Path], smooth_over: int, out: Path, command: str,
         seed: int) -> dict[str, Any]:
    """Fig. 8 (`swarm repro fig8`): training curves (score = mean reward per robot, and
    elratio) of the policies whose `curve.csv` files `paths` names, against training
    episodes, smoothed over `smooth_over` updates; written into `out`."""
    names = list(paths)
    curves = {n: read_curve(paths[n]) for n in names}
    rows: list[dict[str, Any]] = []
    smooth = {}
    for n, c in curves.items():
        el, rw = moving_mean(c["elratio"], smooth_over), moving_mean(c["reward"], smooth_over)
        smooth[n] = (el, rw)
        for k in range(len(el)):
            if (k + 1) % 10 == 0 or k == len(el) - 1:
                rows.append({"policy": n, "update": int(c["update"][k]),
                             "episodes": int(c["episodes"][k]), "elratio": round(el[k], 5),
                             "reward": round(rw[k], 3)})
    last = {n: (smooth[n][0][-1], smooth[n][1][-1], int(curves[n]["episodes"][-1]))
            for n in names}
    md = header("Fig. 8: training curves of the learned policies", command, seed,
                f"Training elratio and reward per robot (sampled actions, curriculum on), "
                f"moving mean over {smooth_over} updates. Paper: CommAttn's score ~150% of the "
                "others'.")
    if note := world_note(paths):
        print(f"fig8: {note}", file=sys.stderr, flush=True)
        md += note + "\n\n"
    md += md_table(["policy", "training episodes", "final elratio", "final reward / robot"],
                   [[n, f"{e:,}", f"{el:.3f}", f"{rw:.1f}"] for n, (el, rw, e) in last.items()])

    def draw(axes: Any) -> None:
        for n in names:
            ep = [e / 1000 for e in curves[n]["episodes"]]
            axes[0].plot(ep, smooth[n][0], label=n)
            axes[1].plot(ep, smooth[n][1], label=n)
        axes[0].set_ylabel("training elratio (sampled)")
        axes[1].set_ylabel("training reward per robot (score)")
        for ax in axes:
            ax.set_xlabel("training episodes (thousands)")
            ax.grid(alpha=0.3)
            ax.legend()
        axes[0].set_title("Fig. 8: training curves")

    meta = {"item": "fig8", "command": command, "seed": seed, "smooth": smooth_over,
            "curves": {n: shown(str(paths[n])) for n in names}}
    return {"item": "fig8", "rows": rows,
            "files": write_item(out, "fig8", rows, md, draw, meta, ncols=2)}
