"""`swarm trace FILE --out DIR`: what a recording says about the network and the robots, as CSV
and PNG.

- `links.csv`, `links.png`: per (sender, receiver), from the recorded bundles and forwards:
  `delivered_traj`, the trajectory copies delivered (a robot's own message is no link), and the
  hidden-state forwards: `delivered_hidden` with a state, `hidden_miss_sender` the sender's own
  word that it had none (a copy delivered: in the result's `hidden_delivered`), and
  `hidden_miss_radio` the radio's word in place of a copy lost, cut, dropped or late (virtual
  clock only: on the real clock a missed copy is just not sent; these copies are also in the
  next columns). Then, from the radio's cumulative per-link counters (the last world status),
  which do not tell the kinds apart: `dropped_both_kinds` (lost, cut or over the bandwidth cap),
  `late_both_kinds` and `queued_both_kinds` copies of either kind. `delivery_ratio`: delivered
  copies of both kinds over those plus the dropped and late ones. The heatmaps are the
  trajectory copies delivered and that ratio.
- `robots.csv`, `latency.png`: per robot, the wall time from its observation to its action as
  the recorder heard them (its decision latency, waits included) and the compute time it
  reported per decision (`planning_ms`), as quantiles and histograms.
- `kinds.csv`: messages and bytes per message kind (direct delivery's stamped messages as
  `direct_traj` and `direct_hidden`), and `miss_markers`: the hidden-state messages among them
  that carry no state (`hidden`: robots that had none to send; `radio_hidden`: every forward
  that is a miss marker, the radio's and the senders' alike, so `radio_hidden` messages are the
  result's `hidden_delivered` plus the radio's markers).
- `elratio.csv`, `elratio.png`: elratio after every tick, one line per episode.
- `attention.csv`, `attention.png` (CommAttn robots that report attention): mean attention
  weight per (receiver, distance to the sender in cells, rounded), over the members it heard,
  from the ticks a robot reported it: every 5th tick of an episode (with its counters), every
  tick of a paced run (someone watches); each (episode, tick, robot) once.

A `--delivery direct` recording holds no bundle and no forward: each receiver decides its copies
itself. Whom each robot heard comes with its action (`Action.heard`), which gives the trajectory
copies per link and the members attention is over; the dropped, late and queued copies per link
are the robots' own counters, from their last status records (`DirectTally`, as the world sums
them). Which hidden-state copies each link delivered is nowhere in such a recording: those cells
are left empty and the notes (`notes.txt`, printed) say so, with the robots' totals.
"""

from __future__ import annotations

import math
from collections import defaultdict
from pathlib import Path
from typing import Any

import numpy as np

from swarm.common import atomic
from swarm.common.report import csv_text, provenance, save_png
from swarm.net.direct import DirectTally
from swarm.net.messages import (
    K_RSTATUS,
    K_STATUS,
    Action,
    BadMessage,
    Bundle,
    Hidden,
    Obs,
    Traj,
    unpack_record,
)
from swarm.net.records import check_robot_status, check_world_status
from swarm.studies.replay import Recording

WRITES = ("links.csv", "robots.csv", "kinds.csv", "elratio.csv", "attention.csv", "links.png",
          "latency.png", "elratio.png", "attention.png", "notes.txt", "trace.json")
"""Every file `trace` may write into its folder (what it writes is in `files` of its result);
one of them left by an earlier trace into the same folder is removed, never left to pass as
this recording's."""

ATTN_FLOOR = 1e-6  # attention weights are drawn on a log scale down to this


def _q(xs: list[float], q: float) -> float:
    return float(np.quantile(xs, q)) if xs else math.nan


class Trace:
    """Everything `swarm trace` draws, gathered in one pass over the recording."""

    def __init__(self, rec: Recording) -> None:
        self.rec, self.cfg = rec, rec.record.world
        n = self.cfg.n_robots
        self.delivered = np.zeros((2, n, n), dtype=np.int64)  # [traj|hidden, sender, receiver]
        self.hidden_miss = np.zeros((2, n, n), dtype=np.int64)  # [sender's|radio's, j, i]
        self.sender_missed: set[tuple[int, int, int]] = set()  # (ep, t, robot) sent no state
        self.miss_forwards: list[tuple[int, int, int, int]] = []  # (ep, t, sender, receiver)
        self.links: dict[str, list[int]] = {}
        self.kinds: dict[str, list[int]] = defaultdict(lambda: [0, 0, 0])  # messages, bytes,
        # miss markers
        self.obs_at: dict[tuple[int, int, int], int] = {}  # (ep, t, robot) -> wall ns
        self.pos: dict[tuple[int, int, int], tuple[int, int]] = {}
        self.heard: dict[tuple[int, int, int], list[int]] = {}
        self.latency: dict[int, list[float]] = defaultdict(list)
        self.compute: dict[int, list[float]] = defaultdict(list)
        self.elratio: list[tuple[int, int, int, float]] = []
        self.attn: list[tuple[int, int, int, list[float]]] = []  # (ep, t, robot, weights)
        self._attn_seen: set[tuple[int, int, int]] = set()
        self.bad = 0
        self.direct = rec.record.run.delivery == "direct"
        self.tally = DirectTally(n) if self.direct else None  # the robots' own link counters
        self.heard_actions = 0  # direct: actions that said whom their robot heard
        for m in rec.messages:
            kind = m.kind
            if kind == "direct":  # a stamped trajectory or hidden-state message, by its key
                kind = "direct_hidden" if m.key.endswith("/dhidden") else "direct_traj"
            self.kinds[kind][0] += 1
            self.kinds[kind][1] += len(m.payload)
            try:
                self.kinds[kind][2] += bool(self._take(m))
            except (BadMessage, KeyError, TypeError, ValueError, IndexError, OverflowError):
                self.bad += 1
        for ep, t, j, i in self.miss_forwards:  # whose word: the sender's own, else the radio's
            self.hidden_miss[0 if (ep, t, j) in self.sender_missed else 1, j, i] += 1
        if self.tally is not None and self.tally.latest:
            self.links = self.tally.faulted_links()  # fresher than the world's last status

    def _take(self, m: Any) -> bool:
        """Take one message; True for a hidden-state miss marker."""
        cfg = self.cfg
        if m.kind == "obs":
            o = Obs.unpack(m.payload, cfg)
            self.obs_at.setdefault((o.ep, o.t, o.robot), m.wall_ns)
            self.pos[(o.ep, o.t, o.robot)] = (o.y, o.x)
        elif m.kind == "action":
            a = Action.unpack(m.payload, cfg)
            self.compute[a.robot].append(a.planning_ms)
            t0 = self.obs_at.get((a.ep, a.t, a.robot))
            if t0 is not None:
                self.latency[a.robot].append((m.wall_ns - t0) / 1e6)
            if self.direct and a.heard:  # whom it heard: direct delivery's bundle
                bits = np.unpackbits(np.frombuffer(a.heard, dtype=np.uint8),
                                     count=cfg.n_robots)
                senders = np.flatnonzero(bits).tolist()
                self.heard[(a.ep, a.t, a.robot)] = senders
                self.heard_actions += 1
                for j in senders:
                    if j != a.robot:
                        self.delivered[0, j, a.robot] += 1
        elif m.kind == "bundle":
            b = Bundle.unpack(m.payload, cfg)
            senders = [Traj.unpack(p, cfg).robot for p in b.trajs]
            self.heard[(b.ep, b.t, b.robot)] = senders
            for j in senders:
                if j != b.robot:
                    self.delivered[0, j, b.robot] += 1
        elif m.kind == "hidden":
            h = Hidden.unpack(m.payload, cfg)
            if h.is_miss:
                self.sender_missed.add((h.ep, h.t, h.robot))
            return h.is_miss
        elif m.kind == "radio_hidden" and m.robot is not None:
            h = Hidden.unpack(m.payload, cfg)
            if h.is_miss:  # (sorted out once every robot's own message is in)
                self.miss_forwards.append((h.ep, h.t, h.robot, m.robot))
            else:
                self.delivered[1, h.robot, m.robot] += 1
            return h.is_miss
        elif m.kind == "status":
            run = self.rec.record.run  # (checked as the supervisor checks it: a malformed
            st = check_world_status(unpack_record(m.payload, K_STATUS), cfg,  # one is skipped)
                                    run.first_episode, run.episodes)
            self.elratio.append((int(st["run_tick"]), int(st["ep"]), int(st["t"]),
                                 float(st["elratio"])))
            if isinstance(st.get("links"), dict):
                self.links = {str(k): [int(x) for x in v][:4] for k, v in st["links"].items()}
        elif m.kind == "rstatus":
            rs = check_robot_status(unpack_record(m.payload, K_RSTATUS), cfg.n_robots,
                                    cfg.horizon)
            key = (int(rs["ep"]), int(rs.get("attn_t", -1)), int(rs["robot"]))
            if "attn" in rs and key not in self._attn_seen:  # (a later status repeats the
                self._attn_seen.add(key)                      # last tick's: counted once)
                self.attn.append((*key, [float(x) for x in rs["attn"]]))
            if self.tally is not None and "direct" in rs:
                self.tally.offer(rs)
        return False

    # ------------------------------------------------------------------------------- tables
    def link_rows(self) -> list[dict[str, Any]]:
        rows, n = [], self.cfg.n_robots
        for j in range(n):
            for i in range(n):
                faults = self.links.get(f"{j}-{i}", [0, 0, 0, 0])
                dt, dh = int(self.delivered[0, j, i]), int(self.delivered[1, j, i])
                if i == j or not (dt or dh or self.hidden_miss[:, j, i].any() or any(faults)):
                    continue
                unknown = self.direct  # no forward in the file: each receiver decided them
                ms, mr = (int(x) for x in self.hidden_miss[:, j, i])
                ratio = self.ratio(j, i, faults)
                rows.append({"sender": j, "receiver": i, "delivered_traj": dt,
                             **{k: "" if unknown else v for k, v in (
                                 ("delivered_hidden", dh), ("hidden_miss_sender", ms),
                                 ("hidden_miss_radio", mr))},
                             "dropped_both_kinds": faults[1], "late_both_kinds": faults[2],
                             "queued_both_kinds": faults[3],
                             "delivery_ratio": "" if math.isnan(ratio) else round(ratio, 4)})
        return rows

    def ratio(self, j: int, i: int, faults: list[int]) -> float:
        """Copies of both kinds delivered j -> i over those plus the dropped and late ones; nan
        when nothing was tried, or in a direct recording with hidden-state messages (which of
        them each link delivered is not in it)."""
        if self.direct and self.kinds.get("direct_hidden", [0])[0]:
            return math.nan
        done = int(self.delivered[0, j, i] + self.delivered[1, j, i] + self.hidden_miss[0, j, i])
        tried = done + faults[1] + faults[2]
        return done / tried if tried else math.nan

    def notes(self) -> list[str]:
        """What this recording cannot say (left empty in the CSVs rather than drawn as zeros)."""
        if not self.direct:
            return []
        out = ["direct delivery: which hidden-state copies each link delivered is not in the "
               "recording (each receiver decides its copies and reports only totals), so "
               "links.csv leaves delivered_hidden, hidden_miss_* and (with hidden-state messages) "
               "delivery_ratio empty; dropped_, late_ and queued_both_kinds count both kinds, "
               "from the robots' own per-link counters"]
        if self.tally is not None and self.tally.latest:
            tot = self.tally.totals()
            missed = sum(tot["by_kind"]["hidden"][k] for k in ("lost", "cut", "late",
                                                                "dropped_bw"))
            out.append(f"the robots reported {tot['hidden_delivered']} hidden-state copies "
                       f"delivered and {missed} missed in all (robots {tot['reported']})")
        else:
            out.append("no robot status record with direct counters: dropped, late and queued "
                       "per link are unknown")
        if not self.heard_actions:
            out.append("no action says whom its robot heard: trajectory copies per link and "
                       "attention per sender distance are unknown")
        return out

    def robot_rows(self) -> list[dict[str, Any]]:
        rows = []
        for i in range(self.cfg.n_robots):
            lat, comp = self.latency.get(i, []), self.compute.get(i, [])
            rows.append({"robot": i, "decisions": len(comp),
                         **{f"latency_ms_{k}": round(f(lat), 3) for k, f in _STATS.items()},
                         **{f"compute_ms_{k}": round(f(comp), 3) for k, f in _STATS.items()}})
        return rows

    def kind_rows(self) -> list[dict[str, Any]]:
        return [{"kind": k, "messages": c, "bytes": b, "mean_bytes": round(b / max(c, 1), 1),
                 "miss_markers": x}
                for k, (c, b, x) in sorted(self.kinds.items(), key=lambda kv: -kv[1][1])]

    def attention_rows(self) -> list[dict[str, Any]]:
        acc: dict[tuple[int, int], list[float]] = defaultdict(list)
        for ep, t, i, w in self.attn:
            heard, me = self.heard.get((ep, t, i)), self.pos.get((ep, t, i))
            if heard is None or me is None:
                continue
            for j in heard:
                pj = self.pos.get((ep, t, j))
                if pj is not None and 0 <= j < len(w):
                    d = round(math.hypot(pj[0] - me[0], pj[1] - me[1]))
                    acc[(i, d)].append(w[j])
        return [{"receiver": i, "distance": d, "mean_attention": round(float(np.mean(v)), 5),
                 "samples": len(v)} for (i, d), v in sorted(acc.items())]


_STATS = {"p50": lambda x: _q(x, 0.5), "p90": lambda x: _q(x, 0.9),
          "mean": lambda x: float(np.mean(x)) if x else math.nan,
          "max": lambda x: max(x) if x else math.nan}


def _write_csv(path: Path, rows: list[dict[str, Any]], empty: str) -> None:
    atomic.write_text(path, csv_text(rows) if rows else empty + "\n")


def trace(rec: Recording, out: str | Path, command: str | None = None) -> dict[str, Any]:
    """Write the CSVs and PNGs of the module docstring into `out`, and `trace.json`: what was
    written and what it was made from (the recording, its run's id, policy, checkpoint and seed,
    `command`, provenance); returns that record."""
    out = Path(out)
    tr = Trace(rec)
    n = tr.cfg.n_robots
    files: list[Path] = []
    links, robots, kinds = tr.link_rows(), tr.robot_rows(), tr.kind_rows()
    elr = [{"run_tick": r, "ep": e, "t": t, "elratio": x} for r, e, t, x in tr.elratio]
    attn = tr.attention_rows()
    for name, rows, empty in (("links", links, "sender,receiver"), ("robots", robots, "robot"),
                              ("kinds", kinds, "kind"), ("elratio", elr, "run_tick"),
                              ("attention", attn, "receiver,distance,mean_attention,samples")):
        _write_csv(out / f"{name}.csv", rows, empty)
        files.append(out / f"{name}.csv")

    def draw_links(axes: Any) -> None:
        ratio = np.array([[tr.ratio(j, i, tr.links.get(f"{j}-{i}", [0, 0, 0, 0]))
                           if i != j else np.nan for i in range(n)] for j in range(n)])
        for ax, mat, title, cmap in ((axes[0], tr.delivered[0], "trajectory copies delivered",
                                      "viridis"),
                                     (axes[1], ratio, "share of copies (both kinds) delivered",
                                      "RdYlGn")):
            im = ax.imshow(mat, cmap=cmap, vmin=0 if cmap != "RdYlGn" else 0.0,
                           vmax=None if cmap != "RdYlGn" else 1.0)
            ax.set_xlabel("receiver")
            ax.set_ylabel("sender")
            ax.set_title(title, fontsize=9)
            ax.set_xticks(range(n))
            ax.set_yticks(range(n))
            ax.figure.colorbar(im, ax=ax, fraction=0.046)

    def draw_latency(axes: Any) -> None:
        for ax, data, what in ((axes[0], tr.latency, "observation -> action (ms, wall)"),
                               (axes[1], tr.compute, "compute per decision (ms)")):
            series = [(i, v) for i, v in sorted(data.items()) if v]
            if series:
                ax.hist([v for _, v in series], bins=30, histtype="step",
                        label=[f"robot {i}" for i, _ in series])
                ax.legend(fontsize=6, ncol=2)
            ax.set_xlabel(what)
            ax.set_ylabel("decisions")

    def draw_elratio(ax: Any) -> None:
        for ep in sorted({e for _, e, _, _ in tr.elratio}):
            pts = sorted((t, x) for _, e, t, x in tr.elratio if e == ep)
            ax.plot([p[0] for p in pts], [p[1] for p in pts], marker=".", label=f"episode {ep}")
        ax.set_xlabel("tick")
        ax.set_ylabel("elratio")
        ax.grid(alpha=0.3)
        if tr.elratio:  # (no status recorded: no line, and no empty legend to warn of)
            ax.legend(fontsize=7)

    save_png(out / "links.png", draw_links, ncols=2)
    save_png(out / "latency.png", draw_latency, ncols=2)
    save_png(out / "elratio.png", draw_elratio)
    files += [out / "links.png", out / "latency.png", out / "elratio.png"]
    if attn:
        def draw_attention(axes: Any) -> None:
            from matplotlib import colormaps
            from matplotlib.colors import LogNorm

            dmax = max(r["distance"] for r in attn)
            mat = np.full((n, dmax + 1), np.nan)
            for r in attn:
                mat[r["receiver"], r["distance"]] = max(r["mean_attention"], ATTN_FLOOR)
            cmap = colormaps["magma"].with_extremes(bad="lightgrey")  # (none heard there)
            im = axes[0].imshow(mat, aspect="auto", cmap=cmap, norm=LogNorm(ATTN_FLOOR, 1.0))
            axes[0].set_xlabel("distance to the sender (cells; 0: itself)")
            axes[0].set_ylabel("receiver")
            axes[0].set_title("mean attention per (receiver, distance); grey: none heard",
                              fontsize=9)
            axes[0].figure.colorbar(im, ax=axes[0], fraction=0.046)
            by_d: dict[int, list[float]] = defaultdict(list)
            for r in attn:
                by_d[r["distance"]] += [r["mean_attention"]] * r["samples"]
            ds = sorted(by_d)
            axes[1].plot(ds, [max(float(np.mean(by_d[d])), ATTN_FLOOR) for d in ds], marker="o")
            axes[1].set_yscale("log")
            axes[1].set_ylim(ATTN_FLOOR / 2, 2.0)
            axes[1].set_xlabel("distance to the sender (cells; 0: itself)")
            axes[1].set_ylabel(f"mean attention weight (floor {ATTN_FLOOR:g})")
            axes[1].set_title(f"{len(tr.attn)} robot-ticks", fontsize=9)
            axes[1].grid(alpha=0.3)

        save_png(out / "attention.png", draw_attention, ncols=2)
        files.append(out / "attention.png")
    notes = tr.notes()
    if notes:
        atomic.write_text(out / "notes.txt", "\n".join(notes) + "\n")
        files.append(out / "notes.txt")
    files.append(out / "trace.json")
    for name in WRITES:  # (an earlier trace's, e.g. attention.png of another policy's run)
        if out / name not in files:
            (out / name).unlink(missing_ok=True)
    run = rec.record.run
    res = {"files": [str(f) for f in files], "links": len(links), "robots": n,
           "kinds": {r["kind"]: r["bytes"] for r in kinds}, "attention_samples": len(tr.attn),
           "bad": tr.bad, "messages": len(rec.messages), "notes": notes,
           "source": {"recording": str(rec.raw.path), "run_id": run.run_id,
                      "policy": run.policy, "checkpoint": run.checkpoint, "seed": run.seed,
                      "episodes": run.episodes, "partial": not rec.raw.complete,
                      "damaged": rec.raw.where_bad() if rec.raw.damaged else None},
           "command": command, "provenance": provenance()}
    atomic.write_json(out / "trace.json", res)
    return res
