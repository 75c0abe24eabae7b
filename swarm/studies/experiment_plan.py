"""The experiment file of `swarm experiment` and the sweep it asks for, checked whole before the
first process is spawned: every (policy, value, seed) run's config, fault plan and policy (its
checkpoint loaded as a robot loads it), so a bad file is one line and exit 2, not a failed run.
"""

from __future__ import annotations

import dataclasses
import os
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from swarm.common.policy_spec import build_inference
from swarm.net.faults import LINK_KEYS, parse_rate, plan_from_table
from swarm.net.kernel.netns import NetnsConfig, check_tools
from swarm.procs.runconfig import (
    RunConfig,
    check_fault_ticks,
    check_new_run,
    check_real_clock,
)
from world.config import (
    ConfigError,
    WorldConfig,
    from_dict,
    load_toml,
    toml_bools,
    with_scaled_blocks,
)

TABLES = ("world", "run", "faults", "experiment")
REQUIRED = ("parameter", "values", "policies")  # what a sweep is; the rest has defaults
_NAME = re.compile(r"[A-Za-z0-9_-]{1,64}")


SWEEPABLE = (*LINK_KEYS, "partition")
"""The `[faults]` keys an experiment may sweep (README, "Sweeps on the real swarm")."""


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
    """Seeds per point (error bars); `--seeds A,B` overrides them."""
    checkpoints: dict[str, str] = field(default_factory=dict)
    """Checkpoint per learned policy."""
    name: str = "experiment"
    """Output file stem (and part of every run id)."""
    out: str = "results/experiments"
    """Output directory (`--out DIR` overrides it)."""
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
        if not _NAME.fullmatch(self.name):
            raise ConfigError(f"[experiment] name must be 1-64 letters, digits, '-' or '_' (it "
                              f"names the output files and the runs), got {self.name!r}")
        if not all(isinstance(p, str) and p for p in self.policies):
            raise ConfigError(f"[experiment] policies must be names, got {list(self.policies)!r}")
        if not all(isinstance(s, int) and not isinstance(s, bool) for s in self.seeds):
            raise ConfigError(f"[experiment] seeds must be integers, got {list(self.seeds)!r}")
        for key in ("values", "policies", "seeds"):
            seen = [str(x) for x in getattr(self, key)]
            twice = sorted({x for x in seen if seen.count(x) > 1})
            if twice:
                raise ConfigError(f"[experiment] {key} repeat {', '.join(twice)}")
        stray = sorted(set(self.checkpoints) - set(self.policies)
                       - {p.split(":")[0] for p in self.policies})
        if stray:  # a misspelt key would leave its policy on the shipped checkpoint
            raise ConfigError(f"[experiment] checkpoints names {', '.join(stray)}, not in "
                              f"policies {', '.join(self.policies)}")
        if self.compare and not self.kernel:
            raise ConfigError("[experiment] compare needs kernel = true")
        if self.parameter not in SWEEPABLE:
            raise ConfigError(f"[experiment] parameter must be a [faults] key: "
                              f"{', '.join(SWEEPABLE)}; got {self.parameter!r}"
                              + (" (a world setting: `swarm repro comm` sweeps the comm range)"
                                 if self.parameter == "comm_range" else ""))
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

    def checkpoint(self, policy: str) -> str | None:
        """The checkpoint a policy (or `NAME:LABEL` variant) of the sweep is given, if any."""
        return self.checkpoints.get(policy, self.checkpoints.get(policy.split(":")[0]))


@dataclass(frozen=True)
class Point:
    """One run of the sweep."""

    policy: str
    """As the file names it (a `NAME:LABEL` variant included)."""
    value: Any
    """The swept parameter's value."""
    seed: int
    """The run's seed."""
    run: RunConfig
    """The run's config (its run id is set when it starts)."""
    faults: dict[str, Any]
    """The run's `[faults]` table (without the swept key when the kernel applies it)."""


@dataclass(frozen=True)
class Sweep:
    """An experiment file with the command line's overrides, every run of it checked."""

    source: str
    """The experiment file as given."""
    world: WorldConfig
    """`[world]`, the same for every run."""
    run: RunConfig
    """`[run]` with `--episodes` applied."""
    exp: ExperimentConfig
    """`[experiment]` with `--seeds` applied."""
    points: tuple[Point, ...]
    """Every run, in order: policies x values x seeds."""
    overrides: tuple[str, ...] = ()
    """The flags that changed the file's sweep (`--episodes 1 --seeds 0`), for the record."""


RUN_PER_POINT = {"policy": "[experiment] policies", "checkpoint": "[experiment] checkpoints",
                 "seed": "[experiment] seeds", "run_id": "[experiment] name (exp-NAME-PID-K)"}
"""`[run]` fields each point sets itself, and where the experiment file sets them: refused in
`[run]`, left out of the record's `run` (compared per row or per policy, not as `[run]`)."""


def parse_seeds(text: str) -> tuple[int, ...]:
    """`--seeds A,B,..` -> the seeds; anything but comma-separated integers is a ConfigError."""
    items = [s.strip() for s in str(text).split(",")]
    if not all(re.fullmatch(r"\d+", s) for s in items):
        raise ConfigError(f"--seeds must be integers >= 0 separated by commas, got {text!r}")
    return tuple(int(s) for s in items)


def read_file(path: str) -> dict[str, Any]:
    """The experiment file's tables; a missing, unreadable or non-TOML file is one line."""
    p = Path(path)
    if p.is_dir():
        raise ConfigError(f"experiment file {path} is a directory; give a TOML file such as "
                          "deploy/experiments/tiny.toml")
    if not p.is_file():
        raise ConfigError(f"experiment file not found: {path}")
    try:
        data = load_toml(p)
    except OSError as exc:
        raise ConfigError(f"experiment file {path}: {exc.strerror or exc}") from None
    unknown = sorted(set(data) - set(TABLES))
    if unknown:
        raise ConfigError(f"{path}: unknown table(s) {', '.join(unknown)}; "
                          f"known: {', '.join(TABLES)}")
    for key, value in data.items():
        if not isinstance(value, dict):
            raise ConfigError(f"{path}: '{key}' must be a table ([{key}])")
    if "experiment" not in data:
        raise ConfigError(f"{path}: no [experiment] table (it names the parameter swept, its "
                          f"values and the policies; see deploy/experiments/tiny.toml)")
    missing = [k for k in REQUIRED if k not in data["experiment"]]
    if missing:
        raise ConfigError(f"{path}: [experiment] needs {', '.join(missing)}")
    return data


def load(path: str, episodes: int | None = None, seeds: tuple[int, ...] | None = None
         ) -> tuple[WorldConfig, RunConfig, dict[str, Any], ExperimentConfig]:
    """The file's tables as configs, `--episodes` and `--seeds` applied over `[run] episodes`
    and `[experiment] seeds` (and checked as the file's values are)."""
    data = read_file(path)
    for cls, name in ((WorldConfig, "world"), (RunConfig, "run"), (ExperimentConfig, "experiment")):
        toml_bools(cls, data.get(name, {}), f"{path}: [{name}]")
    world = from_dict(WorldConfig, with_scaled_blocks(data.get("world", {})), "[world]")
    run_t = dict(data.get("run", {}))
    ours = [k for k in RUN_PER_POINT if k in run_t]
    if ours:  # (each was ignored, and the record claimed it: a policy the sweep never ran)
        raise ConfigError(f"{path}: [run] {ours[0]}: a sweep sets it per run from "
                          f"{RUN_PER_POINT[ours[0]]}; remove it from [run]")
    run_t["run_id"] = "exp"
    if episodes is not None:
        if episodes < 1:
            raise ConfigError(f"--episodes must be >= 1, got {episodes}")
        run_t["episodes"] = episodes
    try:
        run = check_new_run(from_dict(RunConfig, run_t, "[run]"))
    except ValueError as exc:
        raise ConfigError(str(exc)) from None
    if run.train:  # (its world waited a minute for a learner no sweep starts, then failed)
        raise ConfigError(f"{path}: [run] train: a sweep evaluates, it does not train (train "
                          "with `swarm run --train` or `swarm train`, then sweep the checkpoint)")
    exp_t = dict(data["experiment"])
    if seeds is not None:
        exp_t["seeds"] = seeds
    for key in ("values", "policies", "seeds"):
        if key in exp_t:
            if not isinstance(exp_t[key], (list, tuple)):
                raise ConfigError(f"[experiment] {key} must be an array, got {exp_t[key]!r}")
            exp_t[key] = tuple(exp_t[key])
    ckpts = exp_t.get("checkpoints", {})
    if not isinstance(ckpts, dict) or not all(isinstance(v, str) for v in ckpts.values()):
        raise ConfigError(f"[experiment] checkpoints must be a table of files, got {ckpts!r}")
    exp = from_dict(ExperimentConfig, exp_t, "[experiment]")
    return world, run, dict(data.get("faults", {})), exp


def plan(path: str, episodes: int | None = None, seeds: tuple[int, ...] | None = None) -> Sweep:
    """The sweep of experiment file `path`, every run checked as `swarm run` checks one before
    it spawns anything: its config, its fault plan on this team, its policy and checkpoint."""
    world, run, base_faults, exp = load(path, episodes, seeds)
    plan_from_table(base_faults, n_robots=world.n_robots)
    real = ("[experiment] kernel (the real clock)" if exp.kernel
            else '[run] clock = "real"' if run.clock == "real" else None)
    watchdog = "watchdog" in read_file(path).get("run", {})
    for policy in exp.policies:  # unknown, unreadable or the wrong shapes: one line now
        try:
            build_inference(policy.split(":")[0], world, exp.checkpoint(policy))
        except ConfigError as exc:
            raise ConfigError(f"[experiment] policy {policy!r}: {exc}") from None
    if exp.parameter != "partition" and "partition" in base_faults and \
            not str(base_faults["partition"]).strip():  # (as `swarm run --config` says it)
        raise ConfigError("[faults] partition is empty: give the groups (e.g. 0-4/5-9), or "
                          "leave it out for no partition")
    faults_of: dict[str, dict[str, Any]] = {}
    points_of: dict[str, Any] = {}  # each value's plan: two values of one plan are one point
    for value in exp.values:
        faults = {**base_faults, exp.parameter: value}
        try:  # as `swarm run` checks a run: its team, ticks and clock
            plan = plan_from_table(faults, n_robots=world.n_robots)
            check_fault_ticks(faults, run, world, flags=())
            if real is not None:
                check_real_clock(real, watchdog, faults, run.seed, "[run] watchdog")
            if exp.parameter in ("overflow", "burst") and not plan.capped:
                raise ConfigError("it says what a bandwidth cap does; the sweep has no cap "
                                  "(every point would be the same run): give a bandwidth in "
                                  "[faults]")
            same = points_of.setdefault(repr(plan.to_record()), value)
            if same is not value:  # (0 and 0.0, "50ms" and "0.05s": one run twice)
                raise ConfigError(f"it is the point of {same!r} (the same faults): each value "
                                  "is one point")
        except ConfigError as exc:
            raise ConfigError(f"[experiment] {exp.parameter} = {value!r}: {exc}") from None
        if exp.kernel:  # the kernel does the damage; the radio's fault stays zero
            faults.pop(exp.parameter)
        faults_of[str(value)] = faults
    if exp.compare and not Path(exp.compare).is_file():
        raise ConfigError(f"[experiment] compare: no such file {exp.compare}")
    if exp.kernel:
        check_tools(NetnsConfig(loss=0.5, bandwidth=1.0))  # root and the tools, before a run
    if exp.record:
        from swarm.net.record.recording import need_mcap

        need_mcap()
    points = []
    for policy in exp.policies:
        rc = dataclasses.replace(run, run_id=point_run_id(exp.name, 0),
                                 policy=policy.split(":")[0],
                                 checkpoint=exp.checkpoint(policy),
                                 clock="real" if exp.kernel else run.clock)
        for value in exp.values:
            for seed in exp.seeds:
                points.append(Point(policy, value, seed, dataclasses.replace(rc, seed=seed),
                                    faults_of[str(value)]))
    overrides = (*(("--episodes", str(episodes)) if episodes is not None else ()),
                 *(("--seeds", ",".join(map(str, seeds))) if seeds is not None else ()))
    return Sweep(path, world, run, exp, tuple(points), overrides)


def point_run_id(name: str, k: int) -> str:
    """The run id of a sweep's k-th run, `exp-NAME-PID-K`: the sweep's pid keeps it apart from
    every other sweep running on this machine (two sweeps of one file at once took each other's
    ids and one aborted part-way); NAME is cut to keep PID and K within a run id's 64 characters.
    The CSV rows, the kept log folders and the recordings are named by K, not by it."""
    tail = f"-{os.getpid()}-{k}"
    return f"exp-{name[:64 - len('exp-') - len(tail)]}{tail}"


def checkpoints_of(sweep: Sweep, digest: bool = False) -> dict[str, str | None]:
    """The checkpoint each policy of the sweep ran with (a shipped one named as such), or with
    `digest` the SHA-256 of its bytes (None: a policy without weights)."""
    from swarm.common.policy_spec import effective_checkpoint, file_sha256, shown

    files = {pt.policy: effective_checkpoint(pt.run.policy, pt.run.checkpoint)
             for pt in sweep.points}
    return {p: (f and file_sha256(f)) if digest else shown(f) for p, f in files.items()}


def sweep_record(sweep: Sweep) -> dict[str, Any]:
    """What makes a row of the sweep, as `<name>.json` holds it (`write_record`) and
    `check_resume` compares it: the world, `[run]`, the parameter, the kernel switch, each
    value's `[faults]` table and each policy's checkpoint (its path and its bytes' SHA-256)."""
    from world.config import to_dict

    run = {k: v for k, v in to_dict(sweep.run).items() if k not in RUN_PER_POINT}
    return {"world": to_dict(sweep.world), "run": run,
            "experiment": to_dict(sweep.exp),
            "faults": {str(pt.value): pt.faults for pt in sweep.points},
            "checkpoints": checkpoints_of(sweep),
            "checkpoint_sha256": checkpoints_of(sweep, digest=True)}


def _differs(old: dict[str, Any], new: dict[str, Any], where: str,
             keys: Any = None) -> str | None:
    """`where.KEY: A there, B here` for the first key of `keys` (default: all) whose value
    differs between two records (compared as JSON, the way the record was stored)."""
    import json

    from swarm.common.atomic import json_safe

    old, new = (json.loads(json.dumps(json_safe(d))) for d in (old, new))
    for key in sorted(set(old) | set(new)) if keys is None else keys:
        if old.get(key) != new.get(key):
            there, here = (repr(d[key]) if key in d else "unset" for d in (old, new))
            return f"{where}{key} is {there} there, {here} here"
    return None


def check_resume(rows: list[dict[str, Any]], sweep: Sweep, csv_path: Path) -> None:
    """`--resume` adds runs to a CSV of the same sweep only: the sweep record beside it
    (`<name>.json`) must hold this sweep's world, `[run]` (episodes, tick_timeout, delivery,
    ...), parameter and kernel switch, the `[faults]` table of every value in the CSV and the
    checkpoint of every policy in it; the CSV's policies, values and seeds must be among this
    sweep's (more of each may be added: they are new rows, keyed by them). Anything else is
    one line naming the first field that differs."""
    if not rows:
        return
    if not {"policy", "value", "seed"} <= set(rows[0]):
        raise ConfigError(f"--resume: {csv_path} is not a CSV of `swarm experiment`")
    made = sorted({str(r.get("episodes")) for r in rows} - {"None", ""})
    if made and made != [str(sweep.run.episodes)]:
        raise ConfigError(f"--resume: {csv_path} holds runs of {', '.join(made)} episode(s) "
                          f"each, this sweep's runs have {sweep.run.episodes}; give another "
                          f"--out or the same --episodes")
    seeds = [str(s) for s in sweep.exp.seeds]
    other = sorted({str(r["seed"]) for r in rows} - set(seeds), key=lambda s: (len(s), s))
    if other:
        raise ConfigError(f"--resume: {csv_path} holds runs of seed(s) {', '.join(other)}, not "
                          f"in this sweep's seeds {', '.join(seeds)}; give another --out or "
                          f"the same --seeds")
    for key, ours in (("policy", sweep.exp.policies), ("value", sweep.exp.values)):
        theirs = sorted({str(r[key]) for r in rows} - {str(x) for x in ours})
        if theirs:
            raise ConfigError(f"--resume: {csv_path} holds runs of {key} {', '.join(theirs)}, "
                              f"not in this sweep's {', '.join(map(str, ours))}; give another "
                              f"--out")
    old = _read_record(csv_path.with_suffix(".json"), csv_path)
    new = sweep_record(sweep)
    for k in RUN_PER_POINT:  # (a record made before they were left out holds them)
        old["run"].pop(k, None)
    values = sorted({str(r["value"]) for r in rows})
    policies = sorted({str(r["policy"]) for r in rows})
    diff = (_differs(old["world"], new["world"], "world.")
            or _differs(old["run"], new["run"], "[run] ")
            or _differs(old["experiment"], new["experiment"], "[experiment] ",
                        ("parameter", "kernel"))
            or next((d for v in values if (d := _differs(
                old["faults"].get(v, {}), new["faults"][v], f"[faults] at {v}: "))), None)
            or _differs(old["checkpoints"], new["checkpoints"], "checkpoint of ", policies)
            or ("checkpoint_sha256" in old  # (a record made before it was kept: paths only)
                and _differs(old["checkpoint_sha256"], new["checkpoint_sha256"],
                             "SHA-256 of the checkpoint of ", policies)))
    if diff:
        raise ConfigError(f"--resume: {csv_path} was made by another sweep ({diff}); give "
                          f"another --out, or the sweep that made it")


def _read_record(path: Path, csv_path: Path) -> dict[str, Any]:
    """The sweep record beside a CSV to resume; missing or unreadable: one line."""
    import json

    try:
        rec = json.loads(path.read_text())
    except (OSError, ValueError) as exc:
        raise ConfigError(f"--resume: {csv_path} has no readable sweep record {path} ("
                          f"{getattr(exc, 'strerror', None) or exc}): nothing tells whether it "
                          f"is this sweep; give another --out") from None
    keys = ("world", "run", "experiment", "faults", "checkpoints")
    if not isinstance(rec, dict) or not all(isinstance(rec.get(k), dict) for k in keys):
        raise ConfigError(f"--resume: {path} is not the record of a `swarm experiment` sweep; "
                          f"give another --out")
    return rec
