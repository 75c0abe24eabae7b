"""`swarm repro comm`: where communication matters. The best learned policy, coordinated frontier
and the `central` planner (a perfect radio: every robot's observations pooled) as communication
gets scarce: shorter range, message loss, a bandwidth cap (virtual time, the radio's own model).

`central` ignores the radio by construction, so its line is the ceiling of what communication
can buy on this task; the gap between a decentralized policy and it, per condition, is what a
researcher reads off the figure. Two more conditions make the task harder instead: a 40 x 40
map (blocks scaled by area) with 20 and 50 robots, the horizon keeping the default's robot-steps
per cell (10 x 30 / 400); there CommAttn runs the checkpoint fine-tuned on 40 x 40
(`checkpoints/scale/`) when it is present.
"""

from __future__ import annotations

import math
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from policies.base import Policy
from swarm.common.policy_spec import SHIPPED, build_policy, effective_checkpoint, shown
from swarm.common.report import (
    checkpoints_of,
    header,
    md_table,
    paired,
    paired_cell,
    write_item,
)
from swarm.learn.evaluate import EvalResult, evaluate
from swarm.net.faults import plan_from_table
from world.config import ConfigError, WorldConfig, replace, scaled_blocks, to_dict

# (label, world changes, [faults] table): the conditions; tables and the figure show the 20 x 20
# ones first (`shown_order`), then the harder tasks
CONDITIONS: tuple[tuple[str, dict[str, Any], dict[str, Any]], ...] = (
    ("range 10 (default)", {}, {}),
    ("range 5", {"comm_range": 5.0}, {}),
    ("range 3", {"comm_range": 3.0}, {}),
    ("range 2", {"comm_range": 2.0}, {}),
    ("loss 30%", {}, {"loss": 0.3}),
    ("loss 50%", {}, {"loss": 0.5}),
    ("cap 60 B/s", {}, {"bandwidth": "60B/s", "burst": 240}),
    ("cap 250 B/s", {}, {"bandwidth": "250B/s", "burst": 1000}),
    ("range 3 + loss 50%", {"comm_range": 3.0}, {"loss": 0.5}),
    ("40 x 40, 20 robots", {"height": 40, "width": 40, "n_robots": 20, "horizon": 60,
                            **scaled_blocks(40, 40)}, {}),
    ("40 x 40, 50 robots", {"height": 40, "width": 40, "n_robots": 50, "horizon": 24,
                            **scaled_blocks(40, 40)}, {}),
    # added later, so the indices the results scripts were run with stay; shown after the cap
    ("cap 60 B/s, expire", {}, {"bandwidth": "60B/s", "burst": 240, "overflow": "expire"}),
)
SET = ("height", "width", "n_static", "n_dynamic", "n_robots", "horizon", "comm_range")
"""The world settings the conditions' labels name (the default's, or their own): a world's own
values of them are not used (`repro comm --comm-range 3` ran "range 10 (default)" at 3)."""
POLICIES = ("commattn", "coordinated-frontier", "central")
# checkpoints fine-tuned on a map size (the shipped ones were trained on 20 x 20)
MAP_CHECKPOINTS = {("commattn", 40, 40): SHIPPED / "scale" / "commattn_40x40_n20.pt"}


def shown_order() -> list[str]:
    """The conditions' labels as tables and the figure show them: the default-size map's
    (communication scarcer and scarcer, a cap next to its `expire` twin) before the harder
    tasks."""
    small = [c[0] for c in CONDITIONS if c[1].get("height") is None]
    at = small.index("cap 60 B/s") + 1
    small = [c for c in small if c != "cap 60 B/s, expire"]
    return small[:at] + ["cap 60 B/s, expire"] + small[at:] + [
        c[0] for c in CONDITIONS if c[1].get("height") is not None]


def checkpoint_for(name: str, wc: WorldConfig, given: str | None) -> str | None:
    """`given` if any, on every map size; else the checkpoint fine-tuned on the condition's
    map size if one is shipped, else the shipped default (None for a policy without weights;
    a checkpoint runs unchanged on another size, the features are egocentric)."""
    if given is not None:
        return given
    tuned = MAP_CHECKPOINTS.get((name, wc.height, wc.width))
    return str(tuned) if tuned is not None and tuned.is_file() else effective_checkpoint(name, None)


def under(wc: WorldConfig, faults: dict[str, Any], policy: Policy, seed: int, episodes: int,
          batch: int = 250, tick_s: float = 2.0) -> EvalResult:
    """Episodes 0..episodes-1 of `seed` under one condition's world and `[faults]` table (the
    radio's virtual-time model, seeded by `seed`)."""
    plan = plan_from_table({**faults, "seed": seed}, seed) if faults else None
    return evaluate(wc, policy, seed, episodes, batch=batch, faults=plan, tick_s=tick_s)


def paired_conditions(picks: Sequence[int], specs: dict[str, tuple[str, str | None]], seed: int,
                      episodes: int, batch: int = 100,
                      on_row: Callable[[list[dict[str, Any]]], None] | None = None
                      ) -> list[dict[str, Any]]:
    """One row per condition index in `picks`: each spec (label -> policy name, checkpoint) on
    the same episodes, its elratio and success, and the first spec's paired lead over each
    other (`FIRST_minus_OTHER`: mean, standard error). A spec without a checkpoint runs the one
    `repro comm` would (`checkpoint_for`: fine-tuned on the condition's map size if shipped);
    each row names the checkpoints it ran. `on_row(rows so far)` after each condition. The
    results scripts that put one more policy beside `repro comm`'s
    (results/planners/team_beam_comm.py, results/hint_tb/comm.py)."""
    first, *others = specs
    rows: list[dict[str, Any]] = []
    for k in picks:
        label, changes, faults = CONDITIONS[k]
        wc = replace(WorldConfig(), **changes)
        t0 = time.time()
        ckpts = {name: checkpoint_for(policy, wc, ckpt) for name, (policy, ckpt) in specs.items()}
        el = {name: under(wc, faults, build_policy(policy, wc, ckpts[name]), seed, episodes,
                          batch) for name, (policy, _) in specs.items()}
        row: dict[str, Any] = {"condition": label, "episodes": episodes,
                               "seconds": time.time() - t0,
                               "checkpoints": {n: shown(c) for n, c in ckpts.items() if c}}
        for name, res in el.items():
            row[name] = {"elratio": float(res.elratio.mean()),
                         "success": float(res.success.mean())}
        for other in others:
            row[f"{first.replace('-', '_')}_minus_{other}"] = paired(el[first].elratio,
                                                                     el[other].elratio)
        rows.append(row)
        if on_row is not None:
            on_row(rows)
    return rows


def paired_script(argv: Sequence[str], script: str, specs: dict[str, tuple[str, str | None]],
                  seed: int, episodes: int, **meta: Any) -> None:
    """The command line of those results scripts: `SCRIPT OUT.json I [I ...] [--episodes K]`
    (condition indices; K episodes of `seed` each, default `episodes`), each row printed and
    OUT.json rewritten (atomically, with `meta`) as each condition finishes."""
    import json

    import torch

    from swarm.common.atomic import write_json

    args = list(argv)
    if "--episodes" in args:
        at = args.index("--episodes")
        value = args[at + 1] if at + 1 < len(args) else ""
        if not value.isdigit() or int(value) < 2:
            sys.exit(f"{script}: --episodes must be an integer >= 2, got {value!r}")
        episodes = int(value)
        del args[at:at + 2]
    if len(args) < 2 or not all(a.isdigit() and int(a) < len(CONDITIONS) for a in args[1:]):
        sys.exit(f"usage: {script} OUT.json I [I ...] [--episodes K] "
                 f"(I: condition indices 0-{len(CONDITIONS) - 1})")
    torch.set_num_threads(1)
    path, picks = args[0], [int(a) for a in args[1:]]
    command = f"{script} {' '.join(argv)}"

    def on_row(rows: list[dict[str, Any]]) -> None:
        print(json.dumps(rows[-1]), flush=True)
        write_json(path, {"rows": rows, **meta, "command": command})

    paired_conditions(picks, specs, seed, episodes, on_row=on_row)


def comm_title(policies: Sequence[str]) -> str:
    """comm.png's title: the policies it compares (it said "learned vs frontier vs perfect
    radio" whichever they were)."""
    return (f"Where communication matters: {', '.join(policies)}"
            + (" (central: a perfect radio)" if "central" in policies else ""))


SUMMARY = ("elratio_mean", "elratio_std", "success_rate")  # what a row takes of a cell's
PARTIAL = "comm.partial.json"
"""The cells (condition, policy) an unfinished `comm` has made, rewritten after each and
removed with the item's files written: `swarm repro comm --resume` goes on from them."""


def comm_base(world: WorldConfig) -> WorldConfig:
    """The world every condition changes: `world`'s, with the settings they name at default."""
    return replace(world, dynamic=True, **{k: getattr(WorldConfig, k) for k in SET})


def comm_key(world: WorldConfig, seed: int, episodes: int, policies: Sequence[str],
             checkpoints: dict[str, str | None], batch: int, tick_s: float = 2.0
             ) -> dict[str, Any]:
    """What makes a `comm` study's cells: a resumed one must have the same (the checkpoints it
    runs by their bytes' SHA-256, so a file retrained in place is not taken for the old)."""
    from swarm.common.atomic import json_safe
    from swarm.common.policy_spec import file_sha256

    base = comm_base(world)
    files = sorted({c for _, changes, _ in CONDITIONS for name in policies
                    if (c := checkpoint_for(name, replace(base, **changes),
                                            checkpoints.get(name)))})
    return json_safe({"seed": seed, "episodes": episodes, "policies": list(policies),
                      "batch": batch, "tick_s": tick_s, "world": to_dict(base),
                      "checkpoints": {shown(f): file_sha256(f) for f in files}})


def repro_key(world: WorldConfig, cfg: Any) -> dict[str, Any]:
    """`comm_key` of `swarm repro comm` with `cfg` (a swarm.studies.repro.ReproConfig)."""
    return comm_key(world, cfg.seed, cfg.comm_episodes, cfg.comm_policies, cfg.checkpoints,
                    cfg.batch)


def resumed_cells(out: Path, key: dict[str, Any]) -> dict[str, Any]:
    """The cells an interrupted `comm` in `out` made with the same `key` (a one-line ConfigError
    naming what differs, or that there is none to resume)."""
    import json

    path = out / PARTIAL
    try:
        held = json.loads(path.read_text())
        cells, old = held["cells"], held["key"]
        assert isinstance(cells, dict) and isinstance(old, dict)
    except FileNotFoundError:
        raise ConfigError(f"--resume: no interrupted comm in {out} ({PARTIAL} not found)"
                          ) from None
    except OSError as exc:
        raise ConfigError(f"--resume: {path} cannot be read ({exc.strerror or exc})") from None
    except (ValueError, KeyError, TypeError, AssertionError):
        raise ConfigError(f"--resume: {path} is not a comm study's cells") from None
    if differ := [k for k in sorted(set(key) | set(old)) if key.get(k) != old.get(k)]:
        raise ConfigError(f"--resume: the interrupted comm in {out} was made with other "
                          f"{', '.join(differ)}; give its settings, or drop --resume to start "
                          "again")
    try:  # each cell whole and in range, or refused here (not read part way through a table)
        for cell in cells.values():
            summary, elratio = cell["summary"], cell["elratio"]
            assert isinstance(summary, dict) and len(elratio) == key["episodes"]
            assert all(isinstance(x, float) and 0.0 <= x <= 1.0 for x in elratio)
            assert all(isinstance(summary[k], float) and 0.0 <= summary[k] <= 1.0
                       for k in SUMMARY)
    except (KeyError, TypeError, AssertionError):
        raise ConfigError(f"--resume: {path} is not a comm study's cells") from None
    return cells


def comm(world: WorldConfig, out: Path, command: str, seed: int, episodes: int,
         policies: Sequence[str] = POLICIES, checkpoints: dict[str, str | None] | None = None,
         batch: int = 250, tick_s: float = 2.0, resume: bool = False) -> dict[str, Any]:
    """Rows per (policy, condition): elratio, success, the gap to `central`, and the first
    policy's paired lead over each (mean and standard error over the same episodes). Each
    cell's episodes go into `PARTIAL` as it ends; `resume` takes the cells found there."""
    from swarm.common.atomic import write_json

    checkpoints = checkpoints or {}
    unused = [f"{k} {getattr(world, k):g}" for k in SET
              if getattr(world, k) != getattr(WorldConfig, k)]
    base = comm_base(world)
    key = comm_key(world, seed, episodes, policies, checkpoints, batch, tick_s)
    cells = resumed_cells(out, key) if resume else {}
    if resume:
        print(f"swarm: repro comm resumes with {len(cells)} of {len(CONDITIONS) * len(policies)} "
              f"cells made ({out / PARTIAL})", file=sys.stderr, flush=True)
    rows: list[dict[str, Any]] = []
    for label, changes, faults in CONDITIONS:
        wc = replace(base, **changes)
        size = f"{wc.height}x{wc.width}"
        first: np.ndarray | None = None  # the first policy's per-episode elratio (paired ref.)
        for name in policies:
            ckpt = checkpoint_for(name, wc, checkpoints.get(name))
            cell = cells.get(f"{label} | {name}")
            if cell is None:
                res = under(wc, faults, build_policy(name, wc, ckpt), seed, episodes, batch,
                            tick_s)
                cell = {"elratio": res.elratio.tolist(), "summary": res.summary(wc)}
                cells[f"{label} | {name}"] = cell
                write_json(out / PARTIAL, {"key": key, "command": command, "cells": cells})
            s, elratio = cell["summary"], np.asarray(cell["elratio"], dtype=np.float64)
            first = elratio if first is None else first
            lead, se = paired(first, elratio)  # the same episodes
            rows.append({"condition": label, "policy": name, "episodes": episodes,
                         "size": size, "robots": wc.n_robots, "horizon": wc.horizon,
                         "checkpoint": shown(ckpt) if ckpt else "",
                         "comm_range": "inf" if math.isinf(wc.comm_range) else wc.comm_range,
                         "faults": ";".join(f"{k}={v}" for k, v in faults.items()),
                         "elratio_mean": s["elratio_mean"], "elratio_std": s["elratio_std"],
                         "success_rate": s["success_rate"],
                         "first_minus_elratio": lead,
                         "first_minus_elratio_se": se})
    tuned = sorted({r["policy"] for r in rows if r["checkpoint"] and Path(r["checkpoint"]).name
                    in {p.name for p in MAP_CHECKPOINTS.values()}})
    ran = (f"{', '.join(tuned)} runs its 40 x 40 fine-tuned checkpoint there" if tuned else
           "every learned policy runs its one checkpoint on both sizes")
    ref = {r["condition"]: r["elratio_mean"] for r in rows if r["policy"] == "central"}
    for r in rows:
        r["gap_to_central"] = ref[r["condition"]] - r["elratio_mean"] if ref else None
    md = header("Where communication matters", command, seed,
                f"Elratio on {episodes} held-out dynamic-map episodes per point (batched, the "
                "radio's virtual-time model for loss and the bandwidth cap, ticks of "
                f"{tick_s:g} s; a capped sender queues what exceeds its cap, or with "
                "`expire` never sends a message that would leave its queue after the tick's "
                "deadline); `central` pools every robot's observations (a perfect radio), "
                "so it is the same under every fault. The 40 x 40 conditions scale the blocks "
                "by area and keep the robot-steps per cell (20 robots x 60 steps, 50 x 24); "
                f"{ran} (column `checkpoint` of the CSV). The last columns: {policies[0]}'s "
                "elratio minus the other's, "
                "episode by episode, with the standard error of that paired mean."
                + (f" The world's {', '.join(unused)} are not used: each condition sets its "
                   "own." if unused else ""), checkpoints_of(rows))
    conds = shown_order()
    cell = {(r["policy"], r["condition"]): r for r in rows}
    def fmt(r: dict[str, Any]) -> str:
        return f"{r['elratio_mean']:.3f} ({100 * r['success_rate']:.0f}%)"

    others = list(policies[1:])
    md += md_table(["condition", *policies, *(f"{policies[0]} - {p} (paired)" for p in others)],
                   [[c, *(fmt(cell[p, c]) for p in policies),
                     *(paired_cell(cell[p, c]["first_minus_elratio"],
                                   cell[p, c]["first_minus_elratio_se"]) for p in others)]
                    for c in conds])

    def draw(ax: Any) -> None:
        ax.figure.set_size_inches(9.5, 4.8)
        xs = range(len(conds))
        width = 0.8 / max(len(policies), 1)
        values = [r["elratio_mean"] for r in rows]
        for k, p in enumerate(policies):
            ax.bar([x + (k - (len(policies) - 1) / 2) * width for x in xs],
                   [cell[p, c]["elratio_mean"] for c in conds], width, label=p)
        scarce = sum(1 for c in CONDITIONS if c[1].get("height") is None)
        if 0 < scarce < len(conds):  # fault conditions | harder tasks
            ax.axvline(scarce - 0.5, color="0.4", lw=0.8, ls="--")
        ax.set_xticks(list(xs), conds, rotation=25, ha="right")
        ax.set_ylim(max(0.0, min(values) - 0.02), min(1.0, max(values) + 0.03))  # every bar
        ax.set_ylabel("elratio at the last step")
        ax.set_title(comm_title(policies))
        ax.grid(alpha=0.3, axis="y")
        ax.legend(fontsize=8, loc="upper center", ncol=len(policies))

    meta = {"item": "comm", "command": command, "seed": seed, "world": to_dict(base)}
    files = write_item(out, "comm", rows, md, draw, meta)
    (out / PARTIAL).unlink(missing_ok=True)  # (the item's files hold every cell now)
    return {"item": "comm", "rows": rows, "files": files}
