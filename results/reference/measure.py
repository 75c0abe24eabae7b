"""Measure the reference planners (issue 17) on held-out episodes of seed 0; writes JSON here.

Run from the project root: nice -n 19 .venv/bin/python results/reference/measure.py oracle|central N
(the file's "provenance" says which commit, command and libraries made it).
"""

from __future__ import annotations

import importlib
import json
import platform
import subprocess
import sys
import time

import numpy as np

from policies import make_policy
from policies.oracle import OracleConfig, certify, plan_episode
from world.config import WorldConfig, to_dict

OUT = "results/reference"


def _evaluate():
    for mod in ("swarm.learn.evaluate", "swarm.evaluate"):
        try:
            return importlib.import_module(mod).evaluate
        except ImportError:
            continue
    raise ImportError("batched evaluator not found")


def provenance() -> dict:
    """What made the file: the commit (and whether tracked files differed from it), the command,
    the numeric libraries and the CPU features numpy dispatches on."""
    def git(*args: str) -> str:
        return subprocess.run(["git", *args], capture_output=True, text=True).stdout.strip()

    try:
        import scipy
    except ImportError:
        scipy = None
    try:
        from numpy._core._multiarray_umath import __cpu_features__ as cpu
    except ImportError:  # numpy 1.x
        from numpy.core._multiarray_umath import __cpu_features__ as cpu
    return {"commit": git("rev-parse", "HEAD"),
            "tracked_changes": bool(git("status", "--porcelain", "--untracked-files=no")),
            "command": " ".join(["python", *sys.argv]), "python": platform.python_version(),
            "numpy": np.__version__, "scipy": scipy and scipy.__version__,
            "machine": platform.machine(),
            "numpy_cpu_features": sorted(k for k, v in cpu.items() if v)}


def oracle(cfg: WorldConfig, n: int, cert_limit: float = 20.0) -> dict:
    search = OracleConfig()
    rows = []
    for ep in range(n):
        p = plan_episode(cfg, 0, ep, search)
        c = certify(cfg, 0, ep, p, time_limit=cert_limit)
        rows.append({"episode": ep, "elratio": p.elratio, "planned_elratio": p.planned_elratio,
                     "covered": p.covered, "reach_bound": p.upper_bound,
                     "block_collisions": p.block_collisions, "robot_collisions": p.robot_collisions,
                     "success": p.elratio >= cfg.success_elratio and p.block_collisions == 0,
                     "plan_s": p.seconds, "rounds": p.rounds, "cert_bound": c.bound,
                     "cert_elratio_bound": c.elratio_bound, "proven": c.proven,
                     "cert_method": c.method, "cert_s": c.seconds})
        print(json.dumps(rows[-1]), flush=True)
    a = lambda k: np.array([r[k] for r in rows], dtype=float)  # noqa: E731
    # the evaluator's own figures for the same plans
    ev = _evaluate()(cfg, make_policy("oracle", cfg, search=search), 0, n, batch=n)
    knobs = {k: None if v == float("inf") else v for k, v in search.__dict__.items()}  # (JSON)
    return {"policy": "oracle", "episodes": n, "seed": 0, "search": knobs,
            "elratio_mean": a("elratio").mean(), "elratio_std": a("elratio").std(),
            "evaluator_elratio_mean": float(ev.elratio.mean()),
            "success_rate": a("success").mean(),
            "block_collisions_mean": a("block_collisions").mean(),
            "robot_collisions_mean": a("robot_collisions").mean(),
            "plan_s_mean": a("plan_s").mean(), "plan_s_median": float(np.median(a("plan_s"))),
            "proven_optimal": int(a("proven").sum()),
            "proven_by": {m: sum(r["cert_method"] == m and r["proven"] for r in rows)
                          for m in ("reachability", "milp")},
            "cert_bound_mean": a("cert_bound").mean(),
            "cert_elratio_bound_mean": a("cert_elratio_bound").mean(),
            "cert_s_mean": a("cert_s").mean(), "cert_time_limit_s": cert_limit,
            "per_episode": rows, "world": to_dict(cfg)}


def compare(cfg: WorldConfig, n: int, names: list[str]) -> dict:
    out = {}
    ev = _evaluate()
    for name in names:
        t0 = time.perf_counter()
        r = ev(cfg, make_policy(name, cfg), 0, n, batch=250)
        s = r.summary(cfg)
        s["elratio"] = r.elratio.tolist()
        s["total_s"] = time.perf_counter() - t0
        out[name] = s
        print(name, {k: s[k] for k in ("elratio_mean", "elratio_std", "success_rate",
                                       "block_collisions_mean", "robot_collisions_mean",
                                       "planning_ms_per_decision", "wall_s")}, flush=True)
    return out


if __name__ == "__main__":
    cfg = WorldConfig()
    what, n = sys.argv[1], int(sys.argv[2])
    if what == "oracle":
        res = oracle(cfg, n)
        res.update(compare(cfg, n, ["coordinated-frontier"]))
    else:
        res = compare(cfg, n, ["central", "coordinated-frontier", "nearest-frontier"])
    res["provenance"] = provenance()
    with open(f"{OUT}/{what}_{n}.json", "w") as fh:
        json.dump(res, fh, indent=1, default=float)
