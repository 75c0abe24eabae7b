"""`swarm experiment FILE`: sweep one fault parameter over policies on the real swarm.

The file is a TOML experiment: `[world]`, `[run]`, a base `[faults]` table, and `[experiment]`:
`parameter` (a `[faults]` key: latency, jitter, loss, bandwidth, partition, ...), `values`,
`policies`, `seeds`, optional `checkpoints = {name = "file"}` and `out`. Every (policy, value,
seed) is one `swarm run` (world + robot processes over Zenoh). After each run the CSV is
rewritten atomically, so a killed sweep keeps every finished point and `--resume` skips them.
Outputs: `<name>.csv` (one row per run), `<name>.md` and `<name>.png` (elratio, collisions,
success and ticks/s against the fault level, one line per policy, error bars = std over seeds).
"""

from __future__ import annotations

import csv
import dataclasses
import io
import math
import shlex
import sys
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from swarm import atomic
from swarm.faults import plan_from_table
from swarm.runconfig import RunConfig
from swarm.supervisor import SuperviseOptions, Supervisor
from world.config import ConfigError, WorldConfig, from_dict, load_toml

COLUMNS = ("policy", "value", "seed", "elratio_mean", "elratio_std", "collisions_mean",
           "success_rate", "reward_mean", "ticks_per_s", "timeouts", "lost", "late", "cut",
           "queued", "dropped_bw", "delivered")


@dataclass(frozen=True)
class ExperimentConfig:
    """The `[experiment]` table."""

    parameter: str = "loss"
    """The `[faults]` key swept."""
    values: tuple[Any, ...] = (0.0, 0.1, 0.2, 0.3)
    """Its values, in the file's units ("50ms", "2kB/s", "0-4/5-9", 0.1, ...)."""
    policies: tuple[str, ...] = ("nearest-frontier",)
    """Policies compared (one line each); `NAME:LABEL` is a variant of NAME with a checkpoint
    of its own (`checkpoints = {"commattn:fault-trained" = "FILE"}`)."""
    seeds: tuple[int, ...] = (0, 1)
    """Seeds per point (error bars)."""
    checkpoints: dict[str, str] = field(default_factory=dict)
    """Checkpoint per learned policy."""
    name: str = "experiment"
    """Output file stem."""
    out: str = "results/experiments"
    """Output directory."""
    label: str = ""
    """x-axis label (default: the parameter)."""

    def __post_init__(self) -> None:
        if not self.values or not self.policies or not self.seeds:
            raise ConfigError("[experiment] needs values, policies and seeds")
        for v in self.values:
            plan_from_table({self.parameter: v})  # a bad value or key fails before any run


def load(path: str) -> tuple[WorldConfig, RunConfig, dict[str, Any], ExperimentConfig]:
    data = load_toml(path)
    unknown = set(data) - {"world", "run", "faults", "experiment"}
    if unknown:
        raise ConfigError(f"{path}: unknown table(s) {', '.join(sorted(unknown))}")
    world = from_dict(WorldConfig, data.get("world", {}), "[world]")
    run_t = dict(data.get("run", {}))
    run_t.setdefault("run_id", "exp")
    try:
        run = from_dict(RunConfig, run_t, "[run]")
    except ValueError as exc:
        raise ConfigError(str(exc)) from None
    exp_t = dict(data.get("experiment", {}))
    for key in ("values", "policies", "seeds"):
        if key in exp_t:
            exp_t[key] = tuple(exp_t[key])
    exp = from_dict(ExperimentConfig, exp_t, "[experiment]")
    return world, run, dict(data.get("faults", {})), exp


def _read_rows(path: Path) -> list[dict[str, Any]]:
    if not path.exists():
        return []
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


def _write_csv(path: Path, rows: list[dict[str, Any]]) -> None:
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=COLUMNS)
    w.writeheader()
    for r in rows:
        w.writerow({k: r.get(k) for k in COLUMNS})
    atomic.write_text(path, buf.getvalue())


def run_experiment(path: str, resume: bool = False, out: str | None = None,
                   on_row: Callable[[dict[str, Any]], None] | None = None) -> dict[str, Any]:
    world, run, base_faults, exp = load(path)
    out_dir = Path(out or exp.out)
    csv_path = out_dir / f"{exp.name}.csv"
    rows = _read_rows(csv_path) if resume else []
    done = {(r["policy"], str(r["value"]), str(r["seed"])) for r in rows}
    for policy in exp.policies:
        for value in exp.values:
            for seed in exp.seeds:
                if (policy, str(value), str(seed)) in done:
                    continue
                faults = {**base_faults, exp.parameter: value}
                rid = f"exp-{exp.name}-{len(rows)}"[:60]
                base = policy.split(":")[0]  # "commattn:fault-trained": a labelled variant
                rc = dataclasses.replace(run, run_id=rid, policy=base, seed=int(seed),
                                         checkpoint=exp.checkpoints.get(
                                             policy, exp.checkpoints.get(base)))
                res = Supervisor(world, rc, SuperviseOptions(headless=True, status_lines=False),
                                 faults=faults).supervise()
                m = res["messages"]
                row = {"policy": policy, "value": value, "seed": seed,
                       **{k: res.get(k) for k in ("elratio_mean", "elratio_std",
                                                  "collisions_mean", "success_rate",
                                                  "reward_mean", "ticks_per_s", "timeouts")},
                       **{k: m.get(k) for k in ("lost", "late", "cut", "queued", "dropped_bw")},
                       "delivered": m.get("traj_delivered")}
                rows.append(row)
                _write_csv(csv_path, rows)
                if on_row:
                    on_row(row)
    files = [str(csv_path), *write_summary(rows, exp, out_dir, path)]
    return {"rows": rows, "files": files}


def _stats(rows: list[dict[str, Any]], policy: str, value: Any, key: str) -> tuple[float, float]:
    xs = [float(r[key]) for r in rows if r["policy"] == policy and str(r["value"]) == str(value)]
    if not xs:
        return math.nan, math.nan
    mean = sum(xs) / len(xs)
    return mean, math.sqrt(sum((x - mean) ** 2 for x in xs) / len(xs))


def write_summary(rows: list[dict[str, Any]], exp: ExperimentConfig, out_dir: Path,
                  source: str) -> list[str]:
    """The Markdown table and the PNG of a finished (or partial) sweep."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    command = shlex.join(["swarm", "experiment", source])
    lines = [f"Made by `{command}` (seeds {', '.join(map(str, exp.seeds))}).", "",
             f"| policy | {exp.parameter} | elratio | collisions | success | ticks/s |",
             "|---|---|---|---|---|---|"]
    keys = ("elratio_mean", "collisions_mean", "success_rate", "ticks_per_s")
    fig, axes = plt.subplots(1, 4, figsize=(16, 3.8))
    xs = list(range(len(exp.values)))
    for policy in exp.policies:
        for key, ax in zip(keys, axes):
            stats = [_stats(rows, policy, v, key) for v in exp.values]
            ax.errorbar(xs, [s[0] for s in stats], yerr=[s[1] for s in stats], marker="o",
                        capsize=3, label=policy)
        for v in exp.values:
            e, c, s, tps = (_stats(rows, policy, v, k) for k in keys)
            lines.append(f"| {policy} | {v} | {e[0]:.3f} ± {e[1]:.3f} | {c[0]:.1f} | "
                         f"{s[0]:.2f} | {tps[0]:.1f} |")
    for key, ax in zip(keys, axes):
        ax.set_xticks(xs, [str(v) for v in exp.values])
        ax.set_xlabel(exp.label or exp.parameter)
        ax.set_ylabel(key.replace("_", " "))
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=8)
    fig.suptitle(f"{exp.name}: real swarm under {exp.parameter} faults")
    fig.tight_layout()
    png = out_dir / f"{exp.name}.png"
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110)
    plt.close(fig)
    atomic.write_bytes(png, buf.getvalue())
    md = out_dir / f"{exp.name}.md"
    atomic.write_text(md, "\n".join(lines) + "\n")
    return [str(md), str(png)]


def main(argv_path: str, resume: bool, out: str | None) -> int:
    res = run_experiment(argv_path, resume, out, on_row=lambda r: print(
        f"  {r['policy']} {r['value']} seed {r['seed']}: elratio {r['elratio_mean']:.3f} "
        f"collisions {r['collisions_mean']:.1f} ticks/s {r['ticks_per_s']:.1f}",
        file=sys.stderr, flush=True))
    for f in res["files"]:
        print(f"wrote {f}")
    return 0
