"""`swarm experiment FILE`: sweep one fault parameter over policies on the real swarm.

The file is a TOML experiment: `[world]`, `[run]`, a base `[faults]` table, and `[experiment]`:
`parameter` (a `[faults]` key: latency, jitter, loss, bandwidth, partition, ...), `values`,
`policies`, `seeds`, optional `checkpoints = {name = "file"}` and `out`. Every (policy, value,
seed) is one `swarm run` (world + robot processes over Zenoh). After each run the CSV is
rewritten atomically, so a killed sweep keeps every finished point and `--resume` skips them;
a folder already holding the sweep's rows is refused unless `--resume` or `--overwrite`.
Outputs: `<name>.csv` (one row per run), `<name>.md` and `<name>.png` (elratio, collisions,
success and ticks/s against the fault level, one line per policy, error bars = std over seeds).
With `kernel = true` every run is `swarm run --netns` and the swept loss or bandwidth is applied
by the kernel (swarm/net/kernel/netns.py) instead of the radio; `compare = "other.csv"` then
also draws `<name>_compare.png` against another sweep of the same parameter (e.g. the radio's).
With `record = true` every run's traffic is also recorded into `<name>-<k>.mcap` beside the CSV;
a recorder that failed left its file cut short: `recording_partial` in the CSV, named in the
Markdown and in a warning line, and the sweep exits 1 (its files still written), as `swarm run`.
A run that keeps its logs (process faults, or something went wrong) keeps them in `<name>-<k>-logs`
beside the CSV, named on its line, never in a temp folder nothing names.
`--episodes K` and `--seeds A,B` override `[run] episodes` and `[experiment] seeds` (a quick try
of a shipped file, with `--out DIR`); the CSV's `episodes` column and the Markdown record them.
The whole sweep is checked before the first run (swarm/studies/experiment_plan.py).
"""

from __future__ import annotations

import csv
import dataclasses
import glob
import io
import math
import re
import shlex
import shutil
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from swarm.common import atomic
from swarm.net.faults import plan_from_table
from swarm.procs.runconfig import RunConfig
from swarm.procs.supervisor import SuperviseOptions, Supervisor
from swarm.studies.experiment_plan import (
    ExperimentConfig,
    Sweep,
    check_resume,
    checkpoints_of,
    load,
    parse_seeds,
    plan,
    point_run_id,
    sweep_record,
)
from world.config import ConfigError, WorldConfig

__all__ = ["ExperimentConfig", "Sweep", "load", "main", "parse_seeds", "plan", "run_experiment"]

COLUMNS = ("policy", "value", "seed", "elratio_mean", "elratio_std", "collisions_mean",
           "success_rate", "reward_mean", "ticks_per_s", "timeouts", "lost", "late", "cut",
           "queued", "dropped_bw", "stale", "delivered", "clock", "twin", "wall_s", "episodes")
KERNEL_COLUMNS = ("robots_lost", "never_joined", "startup_s", "error")  # kernel = true only
SWEEP_FILES = (".csv", ".md", ".png", "_compare.png", ".json")  # `<name>` + each, beside the CSV


def _read_rows(path: Path) -> list[dict[str, Any]]:
    """A sweep's CSV rows (none without the file); one that cannot be read is one line."""
    if not path.exists():
        return []
    try:
        with open(path, newline="") as fh:
            return list(csv.DictReader(fh))
    except (OSError, UnicodeDecodeError, csv.Error) as exc:
        raise ConfigError(f"{path} is not a readable CSV ({exc}); give another --out, or "
                          "--overwrite to replace it") from None


def _write_csv(path: Path, rows: list[dict[str, Any]],
               columns: tuple[str, ...] = COLUMNS) -> None:
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=columns)
    w.writeheader()
    for r in rows:
        w.writerow({k: r.get(k) for k in columns})
    atomic.write_text(path, buf.getvalue())


def run_experiment(sweep: Sweep, out: str | Path, resume: bool = False, overwrite: bool = False,
                   on_row: Callable[[dict[str, Any]], None] | None = None) -> dict[str, Any]:
    """Run every point of a checked sweep not yet in `<out>/<name>.csv` (with `resume`),
    rewriting the CSV after each; then the summary files. A CSV with rows there is refused
    unless `resume` (add to it) or `overwrite` (replace it)."""
    world, exp = sweep.world, sweep.exp
    out_dir = Path(out)
    csv_path = out_dir / f"{exp.name}.csv"
    if resume and overwrite:
        raise ConfigError("--resume adds to the sweep in the folder, --overwrite replaces it; "
                          "give one")
    rows = [] if overwrite else _read_rows(csv_path)
    if resume and not rows and not (out_dir / f"{exp.name}.json").exists():  # (a mistyped --out
        raise ConfigError(f"--resume: {out_dir} holds no sweep {exp.name}, nothing to resume "
                          "(without --resume a new sweep starts there)")  # started afresh)
    if rows and not resume:
        raise ConfigError(f"{out_dir} holds the results of sweep {exp.name} ({len(rows)} runs "
                          f"in {csv_path}): resume it (--resume), replace them (--overwrite) "
                          f"or choose another output folder")
    check_resume(rows, sweep, csv_path)  # a CSV of another sweep: one line, no run
    # the temp files of a sweep killed mid-write (atomic.write_*: nothing else removes them)
    atomic.remove_stale(out_dir, tuple(f"{exp.name}{ext}" for ext in SWEEP_FILES))
    # Killed between these steps or after them, the folder never pairs the record with
    # another sweep's rows, nor the CSV with a Markdown or PNG of other rows (they are
    # written at the end): the old files go before the new record comes.
    for stale in (*(() if resume else (".csv",)), ".md", ".png", "_compare.png"):  # (not the
        # record, `.json`: it is rewritten next)
        (out_dir / f"{exp.name}{stale}").unlink(missing_ok=True)
    if overwrite:  # and the old runs' recordings and kept logs (`<name>-<k>.mcap`, `-logs`):
        _remove_point_files(out_dir, exp.name)  # asked for (a fresh sweep leaves what it finds)
    write_record(sweep, out_dir)  # before the first run: a killed sweep's CSV has its record
    done = {(r["policy"], str(r["value"]), str(r["seed"])) for r in rows}
    columns = COLUMNS + KERNEL_COLUMNS if exp.kernel else COLUMNS
    if exp.record:
        columns = columns + ("recording", "recording_partial")
    for pt in sweep.points:
        policy, value, seed, faults = pt.policy, pt.value, pt.seed, pt.faults
        if (policy, str(value), str(seed)) in done:
            continue
        rc = dataclasses.replace(pt.run, run_id=point_run_id(exp.name, len(rows)))
        recording = str(out_dir / f"{exp.name}-{len(rows)}.mcap") if exp.record else None
        if recording:
            out_dir.mkdir(parents=True, exist_ok=True)
        opts = SuperviseOptions(headless=True, status_lines=False, netns=exp.netns(value),
                                record=recording)
        t0 = time.monotonic()
        sup = Supervisor(world, rc, opts, faults=faults)
        try:
            res = sup.supervise()
        except RuntimeError as exc:  # kernel faults can keep every robot from joining
            if not exp.kernel:
                raise
            kept = _keep_logs({"logs": sup.log_dir} if sup.log_dir.is_dir() else {},
                              point_logs(out_dir, exp.name, len(rows)))  # (beside the CSV, as
            print(f"  {policy} {value} seed {seed}: failed: {str(exc).split(';')[0]}"  # a run's
                  + (f"; logs in {kept}" if kept else ""), file=sys.stderr)  # that played)
            rows.append({"policy": policy, "value": value, "seed": seed,
                         "episodes": rc.episodes, "error": str(exc).split(";")[0]})
            _write_csv(csv_path, rows, columns)
            continue
        logs = _keep_logs(res, point_logs(out_dir, exp.name, len(rows)))
        m = res["messages"]
        row = {"policy": policy, "value": value, "seed": seed,
               **{k: res.get(k) for k in ("elratio_mean", "elratio_std", "collisions_mean",
                                          "success_rate", "reward_mean", "ticks_per_s",
                                          "timeouts")},
               **{k: m.get(k) for k in ("lost", "late", "cut", "queued", "dropped_bw",
                                        "stale")},  # (stale: whole messages after their tick)
               "delivered": m.get("traj_to_others"), "clock": rc.clock,
               "twin": twin(world, rc, faults, res) if rc.clock == "virtual" else "",
               "wall_s": round(time.monotonic() - t0, 2), "episodes": rc.episodes,
               "recording": recording, "logs": logs,
               "recording_partial": res.get("recording", {}).get("partial") if recording else None}
        if exp.kernel:
            row.update(robots_lost=res.get("robots_lost"), startup_s=res.get("startup_s"),
                       never_joined=res["netns"]["never_joined"])
        rows.append(row)
        _write_csv(csv_path, rows, columns)
        if on_row:
            on_row(row)
    files = [str(csv_path), *write_summary(rows, sweep, out_dir), write_record(sweep, out_dir)]
    if exp.kernel and exp.compare:
        files.append(write_comparison(rows, _read_rows(Path(exp.compare)), exp, out_dir,
                                      sweep.source))
    return {"rows": rows, "files": files, "partial": [
        (r["recording"], str(point_logs(out_dir, exp.name, k)))
        for k, r in enumerate(rows) if partial(r)]}


def partial(row: dict[str, Any]) -> bool:
    """Whether a row's recording was cut short by a failed recorder (True from a run, "True"
    read back from the CSV)."""
    return str(row.get("recording_partial")) == "True"


def point_logs(out_dir: Path, name: str, k: int) -> Path:
    """Where run k of sweep `name` keeps its logs: `<name>-<k>-logs` beside the CSV."""
    return out_dir / f"{name}-{k}-logs"


def _remove_point_files(out_dir: Path, name: str) -> None:
    """A replaced sweep's per-run files: `<name>-<k>.mcap` and `<name>-<k>-logs/` of each
    run k (a new sweep with fewer runs left the old sweep's last ones beside its CSV)."""
    pattern = re.compile(rf"{re.escape(name)}-\d+(\.mcap|-logs)")
    for path in out_dir.glob(f"{glob.escape(name)}-*") if out_dir.is_dir() else ():
        if pattern.fullmatch(path.name):
            if path.is_dir() and not path.is_symlink():
                shutil.rmtree(path, ignore_errors=True)
            else:
                path.unlink(missing_ok=True)


def _keep_logs(res: dict[str, Any], dest: Path) -> str | None:
    """A run's temp log folder that it kept (`res["logs"]`: process faults, or trouble) moved
    to `dest` beside the sweep's CSV, where a user finds it (in /tmp nothing named it); None
    when the run removed its folder (a clean run)."""
    if not res.get("logs"):
        return None
    shutil.rmtree(dest, ignore_errors=True)  # (a rerun's point of the same number)
    dest.parent.mkdir(parents=True, exist_ok=True)
    shutil.move(res["logs"], dest)
    return str(dest)


def write_record(sweep: Sweep, out_dir: Path) -> str:
    """`<name>.json`: everything that made the sweep, beside its CSV: the command, the
    experiment file's text, the world, the run and fault settings, every policy's
    checkpoint and the software's provenance (the CSV holds only the figures)."""
    from swarm.common.report import provenance

    exp = sweep.exp
    try:
        text: str | None = Path(sweep.source).read_text()
    except OSError:
        text = None
    path = out_dir / f"{exp.name}.json"
    atomic.write_json(path, {
        "command": shlex.join(["swarm", "experiment", sweep.source, *sweep.overrides]),
        "experiment_file": text, **sweep_record(sweep), "provenance": provenance()})
    return str(path)


def twin(world: WorldConfig, rc: RunConfig, faults: dict[str, Any], res: dict[str, Any]) -> str:
    """The batched evaluator on the run's episodes, seed and fault plan: `identical` when it
    takes every action the swarm took (a virtual-clock run must), else what differs; `n/a`
    for a run with process faults (crash, hang, restart) or a robot that died: the batched
    evaluator has no processes to stop, so it has no twin of those."""
    import numpy as np

    from swarm.common.policy_spec import build_policy
    from swarm.learn.evaluate import evaluate

    plan = plan_from_table(faults, rc.seed, world.n_robots)
    if plan.process or res.get("robot_crashes") or res.get("robots_lost"):
        return "n/a"
    policy = build_policy(rc.policy, world, rc.checkpoint)
    ev = evaluate(world, policy, rc.seed, rc.episodes, first_episode=rc.first_episode,
                  greedy=rc.greedy, record_actions=True, tick_s=rc.tick_timeout,
                  faults=plan)
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
    mean = sum(xs) / len(xs)  # sd: the sample sd (n - 1) over seeds; none from one seed
    sd = math.sqrt(sum((x - mean) ** 2 for x in xs) / (len(xs) - 1)) if len(xs) > 1 else math.nan
    return mean, sd


def base_faults(sweep: Sweep) -> str:
    """The file's `[faults]` table (every point's faults but the swept key), as the Markdown
    says it: `jitter 50ms, crash ['1@5']`, or `none`."""
    base = {k: v for k, v in sweep.points[0].faults.items() if k != sweep.exp.parameter}
    return ", ".join(f"{k} {v}" for k, v in base.items()) or "none"


def write_summary(rows: list[dict[str, Any]], sweep: Sweep, out_dir: Path) -> list[str]:
    """The Markdown table and the PNG of a finished (or partial) sweep; the Markdown names the
    command (with any `--episodes`/`--seeds` override), the seeds and the episodes per run."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    exp = sweep.exp
    command = shlex.join(["swarm", "experiment", sweep.source, *sweep.overrides])
    walls = [float(r["wall_s"]) for r in rows if r.get("wall_s") not in (None, "")]
    twins = [r.get("twin") for r in rows if r.get("twin") not in (None, "", "n/a")]
    same = sum(t == "identical" for t in twins)
    clocks = sorted({str(r.get("clock") or "real") for r in rows})
    w = sweep.world
    ckpts = "; ".join(f"{p} {c}" for p, c in checkpoints_of(sweep).items() if c)
    lines = [f"Made by `{command}` (seeds {', '.join(map(str, exp.seeds))}; "
             f"{sweep.run.episodes} episode{'s' * (sweep.run.episodes != 1)} per run; clock "
             f"{', '.join(clocks)}; {len(rows)} runs in {sum(walls):.0f} s of wall time"
             + (f"; batched twin identical in {same} of {len(twins)} runs" if twins else "")
             + f"). World: {w.n_robots} robots, {w.height} x {w.width}, "
             + (f"dynamic (m={w.add_every})" if w.dynamic else "static")
             + f", vision {w.vision}, comm range {w.comm_range}, horizon {w.horizon}"
             + f". Run: tick {sweep.run.tick_timeout:g} s, delivery {sweep.run.delivery}"
             + f". Faults at every point besides the swept {exp.parameter}: {base_faults(sweep)}"
             + (f". Checkpoints: {ckpts}" if ckpts else "")
             + f". Everything that made it: `{exp.name}.json`. ± sd: the sample standard "
             "deviation (n - 1) of the runs' means over the seeds (- with one seed).", "",
             f"| policy | {exp.parameter} | elratio (± sd over seeds) | collisions | success "
             "| ticks/s |",
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
            if math.isnan(e[0]):  # every run of the point failed (kernel faults): not "nan"
                n = sum(r["policy"] == policy and str(r["value"]) == str(v) for r in rows)
                lines.append(f"| {policy} | {v} | no run played ({n} failed: `error` in the CSV)"
                             " | - | - | - |")
                continue
            sd = "-" if math.isnan(e[1]) else f"{e[1]:.3f}"
            lines.append(f"| {policy} | {v} | {e[0]:.3f} ± {sd} | {c[0]:.1f} | "
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
    lines += ["", f"`{exp.name}.csv`, one row per run, counts message copies (sender -> "
              "receiver): `delivered` trajectory copies that reached another robot in time (a "
              "robot's own message is not counted); `lost`, `cut`, `late`, `dropped_bw` copies "
              "of either kind (trajectory or hidden state) that did not; `queued` copies that "
              "waited for bandwidth tokens (a hidden-state copy then delivered or late, a "
              "trajectory copy whatever became of it); `stale` whole messages "
              "that reached the world after their tick."]
    cut = [f"`{Path(r['recording']).name}` (logs in `{point_logs(out_dir, exp.name, k).name}/`)"
           for k, r in enumerate(rows) if partial(r)]
    if cut:  # data lost: said where the figures are, not only in the CSV
        lines += ["", "Recordings cut short, their recorder failed (`swarm replay --partial` "
                  f"reads each up to the cut): {', '.join(cut)}."]
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


def _f(x: Any, fmt: str) -> str:
    return "-" if x in (None, "") else f"{float(x):{fmt}}"  # (a run that completed nothing)


def main(sweep: Sweep, out: str, resume: bool, overwrite: bool = False) -> int:
    """`swarm experiment`: run a checked sweep into directory `out`, one line per run on stderr,
    the files written on stdout."""
    res = run_experiment(sweep, out, resume, overwrite, on_row=lambda r: print(
        f"  {r['policy']} {r['value']} seed {r['seed']}: elratio {_f(r['elratio_mean'], '.3f')} "
        f"collisions {_f(r['collisions_mean'], '.1f')} ticks/s {_f(r['ticks_per_s'], '.1f')} "
        f"{r.get('twin') or ''}{'  logs in ' + r['logs'] if r.get('logs') else ''}",
        file=sys.stderr, flush=True))
    for f in res["files"]:
        print(f"wrote {f}")
    for recording, logs in res["partial"]:  # (the supervisor's warning named the temp folder)
        print(f"swarm: warning: the recording {recording} is partial (its recorder failed); "
              f"the run's logs are in {logs}", file=sys.stderr, flush=True)
    return 1 if res["partial"] else 0  # a recording asked for is lost in part, as `swarm run`
