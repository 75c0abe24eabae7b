"""`swarm experiment FILE`: sweep one fault parameter over policies on the real swarm.

The file is a TOML experiment: `[world]`, `[run]`, a base `[faults]` table, and `[experiment]`:
`parameter` (a `[faults]` key: latency, jitter, loss, bandwidth, partition, ...), `values`,
`policies`, `seeds`, optional `checkpoints = {name = "file"}` and `out`. Every (policy, value,
seed) is one `swarm run` (world + robot processes over Zenoh). After each run the CSV is
rewritten atomically, so a killed sweep keeps every finished point and `--resume` skips them.
Outputs: `<name>.csv` (one row per run), `<name>.md` and `<name>.png` (elratio, collisions,
success and ticks/s against the fault level, one line per policy, error bars = std over seeds).
With `kernel = true` every run is `swarm run --netns` and the swept loss or bandwidth is applied
by the kernel (swarm/net/kernel/netns.py) instead of the radio; `compare = "other.csv"` then
also draws `<name>_compare.png` against another sweep of the same parameter (e.g. the radio's).
With
`record = true` every run's traffic is also recorded into `<name>-<k>.mcap` beside the CSV.
"""

from __future__ import annotations

import csv
import dataclasses
import io
import math
import shlex
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from swarm.common import atomic
from swarm.net.faults import parse_rate, plan_from_table
from swarm.net.kernel.netns import NetnsConfig, check_tools
from swarm.procs.runconfig import RunConfig
from swarm.procs.supervisor import SuperviseOptions, Supervisor
from world.config import ConfigError, WorldConfig, from_dict, load_toml

COLUMNS = ("policy", "value", "seed", "elratio_mean", "elratio_std", "collisions_mean",
           "success_rate", "reward_mean", "ticks_per_s", "timeouts", "lost", "late", "cut",
           "queued", "dropped_bw", "delivered", "clock", "twin", "wall_s")
KERNEL_COLUMNS = ("robots_lost", "never_joined", "startup_s", "error")  # kernel = true only


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
    kernel: bool = False
    """Kernel-level realism: each run in network namespaces (root), the swept `loss` or
    `bandwidth` applied by iptables / tc on the robot links and not by the radio."""
    compare: str = ""
    """With `kernel`: a CSV of the same sweep by the radio, drawn in `<name>_compare.png`."""
    record: bool = False
    """Record every run's traffic into `<out>/<name>-<k>.mcap` (`swarm replay`, `swarm trace`);
    the CSV's `recording` column names each run's file."""

    def __post_init__(self) -> None:
        if not self.values or not self.policies or not self.seeds:
            raise ConfigError("[experiment] needs values, policies and seeds")
        for v in self.values:
            plan_from_table({self.parameter: v})  # a bad value or key fails before any run
            if self.kernel:
                self.netns(v)

    def netns(self, value: Any) -> NetnsConfig | None:
        """The kernel faults of one point (None unless `kernel`)."""
        if not self.kernel:
            return None
        if self.parameter == "loss":
            return NetnsConfig(loss=float(value))
        if self.parameter == "bandwidth":
            return NetnsConfig(bandwidth=parse_rate(value))
        raise ConfigError(f"[experiment] kernel = true sweeps loss or bandwidth, "
                          f"not {self.parameter!r}")


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


def _write_csv(path: Path, rows: list[dict[str, Any]],
               columns: tuple[str, ...] = COLUMNS) -> None:
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=columns)
    w.writeheader()
    for r in rows:
        w.writerow({k: r.get(k) for k in columns})
    atomic.write_text(path, buf.getvalue())


def run_experiment(path: str, resume: bool = False, out: str | None = None,
                   on_row: Callable[[dict[str, Any]], None] | None = None) -> dict[str, Any]:
    world, run, base_faults, exp = load(path)
    out_dir = Path(out or exp.out)
    csv_path = out_dir / f"{exp.name}.csv"
    rows = _read_rows(csv_path) if resume else []
    done = {(r["policy"], str(r["value"]), str(r["seed"])) for r in rows}
    columns = COLUMNS + KERNEL_COLUMNS if exp.kernel else COLUMNS
    if exp.record:
        from swarm.net.record.recording import need_mcap

        need_mcap()
        columns = columns + ("recording",)
    if exp.kernel:
        check_tools(NetnsConfig(loss=0.5, bandwidth=1.0))  # one line now, not after a run
    for policy in exp.policies:
        for value in exp.values:
            for seed in exp.seeds:
                if (policy, str(value), str(seed)) in done:
                    continue
                faults = {**base_faults, exp.parameter: value}
                if exp.kernel:  # the kernel does the damage; the radio's fault stays zero
                    faults.pop(exp.parameter)
                rid = f"exp-{exp.name}-{len(rows)}"[:60]
                base = policy.split(":")[0]  # "commattn:fault-trained": a labelled variant
                rc = dataclasses.replace(run, run_id=rid, policy=base, seed=int(seed),
                                         checkpoint=exp.checkpoints.get(
                                             policy, exp.checkpoints.get(base)))
                recording = str(out_dir / f"{exp.name}-{len(rows)}.mcap") if exp.record else None
                if recording:
                    out_dir.mkdir(parents=True, exist_ok=True)
                opts = SuperviseOptions(headless=True, status_lines=False,
                                        netns=exp.netns(value), record=recording)
                if exp.kernel:
                    rc = dataclasses.replace(rc, clock="real")
                t0 = time.monotonic()
                try:
                    res = Supervisor(world, rc, opts, faults=faults).supervise()
                except RuntimeError as exc:  # kernel faults can keep every robot from joining
                    if not exp.kernel:
                        raise
                    print(f"  {policy} {value} seed {seed}: failed: {exc}", file=sys.stderr)
                    rows.append({"policy": policy, "value": value, "seed": seed,
                                 "error": str(exc).split(";")[0]})
                    _write_csv(csv_path, rows, columns)
                    continue
                m = res["messages"]
                row = {"policy": policy, "value": value, "seed": seed,
                       **{k: res.get(k) for k in ("elratio_mean", "elratio_std",
                                                  "collisions_mean", "success_rate",
                                                  "reward_mean", "ticks_per_s", "timeouts")},
                       **{k: m.get(k) for k in ("lost", "late", "cut", "queued", "dropped_bw")},
                       "delivered": m.get("traj_delivered"), "clock": rc.clock,
                       "twin": twin(world, rc, faults, res) if rc.clock == "virtual" else "",
                       "wall_s": round(time.monotonic() - t0, 2), "recording": recording}
                if exp.kernel:
                    row.update(robots_lost=res.get("robots_lost"), startup_s=res.get("startup_s"),
                               never_joined=res["netns"]["never_joined"])
                rows.append(row)
                _write_csv(csv_path, rows, columns)
                if on_row:
                    on_row(row)
    files = [str(csv_path), *write_summary(rows, exp, out_dir, path)]
    if exp.kernel and exp.compare:
        files.append(write_comparison(rows, _read_rows(Path(exp.compare)), exp, out_dir, path))
    return {"rows": rows, "files": files}


def twin(world: WorldConfig, rc: RunConfig, faults: dict[str, Any], res: dict[str, Any]) -> str:
    """The batched evaluator on the run's episodes, seed and fault plan: `identical` when it
    takes every action the swarm took (a virtual-clock run must), else what differs."""
    import numpy as np

    from swarm.common.policy_spec import build_policy
    from swarm.learn.evaluate import evaluate

    policy = build_policy(rc.policy, world, rc.checkpoint)
    ev = evaluate(world, policy, rc.seed, rc.episodes, first_episode=rc.first_episode,
                  greedy=rc.greedy, record_actions=True, tick_s=rc.tick_timeout,
                  faults=plan_from_table(faults, rc.seed, world.n_robots))
    ours = np.array(res.get("actions", []))
    theirs = np.stack(ev.actions, 1) if ev.actions else np.zeros((0,))
    if ours.shape != theirs.shape:
        return f"differs: shapes {ours.shape} vs {theirs.shape}"
    bad = np.argwhere(ours != theirs)
    if len(bad):
        e, t, i = bad[0]
        return f"differs: episode {e} tick {t} robot {i}"
    return "identical"


def _stats(rows: list[dict[str, Any]], policy: str, value: Any, key: str) -> tuple[float, float]:
    xs = [float(r[key]) for r in rows if r["policy"] == policy and str(r["value"]) == str(value)
          and r.get(key) not in (None, "")]  # a kernel run that failed has no metrics
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
    walls = [float(r["wall_s"]) for r in rows if r.get("wall_s") not in (None, "")]
    twins = [r.get("twin") for r in rows if r.get("twin")]
    same = sum(t == "identical" for t in twins)
    clocks = sorted({str(r.get("clock") or "real") for r in rows})
    lines = [f"Made by `{command}` (seeds {', '.join(map(str, exp.seeds))}; clock "
             f"{', '.join(clocks)}; {len(rows)} runs in {sum(walls):.0f} s of wall time"
             + (f"; batched twin identical in {same} of {len(twins)} runs" if twins else "")
             + ").", "",
             f"| policy | {exp.parameter} | elratio | collisions | success | ticks/s |",
             "|---|---|---|---|---|---|"]
    keys = ("elratio_mean", "collisions_mean", "success_rate", "ticks_per_s")
    fig, axes = plt.subplots(1, 4, figsize=(16, 3.8))
    xs = list(range(len(exp.values)))
    for policy in exp.policies:
        for key, ax in zip(keys, axes, strict=True):
            stats = [_stats(rows, policy, v, key) for v in exp.values]
            ax.errorbar(xs, [s[0] for s in stats], yerr=[s[1] for s in stats], marker="o",
                        capsize=3, label=policy)
        for v in exp.values:
            e, c, s, tps = (_stats(rows, policy, v, k) for k in keys)
            lines.append(f"| {policy} | {v} | {e[0]:.3f} ± {e[1]:.3f} | {c[0]:.1f} | "
                         f"{s[0]:.2f} | {tps[0]:.1f} |")
    for key, ax in zip(keys, axes, strict=True):
        ax.set_xticks(xs, [str(v) for v in exp.values])
        ax.set_xlabel(exp.label or exp.parameter)
        ax.set_ylabel(key.replace("_", " "))
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=8)
    fig.suptitle(f"{exp.name}: real swarm under {exp.parameter} faults ({', '.join(clocks)} "
                 "clock)")
    fig.tight_layout()
    png = out_dir / f"{exp.name}.png"
    _save(fig, png)
    md = out_dir / f"{exp.name}.md"
    atomic.write_text(md, "\n".join(lines) + "\n")
    return [str(md), str(png)]


def write_comparison(rows: list[dict[str, Any]], other: list[dict[str, Any]],
                     exp: ExperimentConfig, out_dir: Path, source: str) -> str:
    """`<name>_compare.png`: this kernel sweep (dashed) against `exp.compare` (solid), per
    policy: elratio, ticks/s, timeouts, robots out (lost mid-run or never joined; kernel only,
    the radio's CSV has no such column); failed runs are left out, and counted."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    keys = ("elratio_mean", "ticks_per_s", "timeouts", "robots_out")
    rows = [{**r, "robots_out": int(r["robots_lost"]) + int(r["never_joined"])}
            if r.get("robots_lost") not in (None, "") else r for r in rows]
    fig, axes = plt.subplots(1, 4, figsize=(16, 3.8))
    xs = list(range(len(exp.values)))
    for i, policy in enumerate(exp.policies):
        for data, style, who in ((other, "-", "radio"), (rows, "--", "kernel")):
            for key, ax in zip(keys, axes, strict=True):
                stats = [_stats(data, policy, v, key) for v in exp.values]
                ax.errorbar(xs, [m for m, _ in stats], yerr=[sd for _, sd in stats], marker="o",
                            capsize=3, ls=style, color=f"C{i}", label=f"{policy} ({who})")
    failed = sum(1 for r in rows if r.get("error"))
    for key, ax in zip(keys, axes, strict=True):
        ax.set_xticks(xs, [str(v) for v in exp.values])
        ax.set_xlabel("loss (radio: per message; kernel: per packet and link direction)"
                      if exp.parameter == "loss" else exp.label or exp.parameter, fontsize=8)
        ax.set_ylabel(key.replace("_", " "))
        ax.grid(alpha=0.3)
    axes[1].set_yscale("log")
    axes[0].legend(fontsize=7)
    fig.suptitle(f"{exp.parameter}: radio layer ({exp.compare}, solid) vs kernel "
                 f"(`swarm experiment {source}`, dashed; {failed} failed runs left out)",
                 fontsize=9)
    fig.tight_layout()
    png = out_dir / f"{exp.name}_compare.png"
    _save(fig, png)
    return str(png)


def _save(fig: Any, png: Path) -> None:
    """Write a matplotlib figure as PNG atomically and close it."""
    import matplotlib.pyplot as plt

    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110)
    plt.close(fig)
    atomic.write_bytes(png, buf.getvalue())


def main(argv_path: str, resume: bool, out: str | None) -> int:
    res = run_experiment(argv_path, resume, out, on_row=lambda r: print(
        f"  {r['policy']} {r['value']} seed {r['seed']}: elratio {r['elratio_mean']:.3f} "
        f"collisions {r['collisions_mean']:.1f} ticks/s {r['ticks_per_s']:.1f} "
        f"{r.get('twin') or ''}",
        file=sys.stderr, flush=True))
    for f in res["files"]:
        print(f"wrote {f}")
    return 0
