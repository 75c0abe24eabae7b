"""Direct delivery re-run from a recording (`swarm replay --verify` of a `--delivery direct`
run in virtual time).

Each robot decided the fate of every copy it received itself (`swarm.net.direct.DirectLink`);
the recording holds every stamped message the robots put and every observation the world sent.
So one `DirectLink` per robot is fed, tick by tick, what that robot was fed: its observation
(with any live fault change it carried), its own messages (whose stamps are recomputed from its
own token bucket and must equal the queue delays it claimed), every other robot's trajectory
message, and, for a chained policy, its predecessor's hidden-state message (the predecessor
being the highest lower id among the trajectories it heard). The counters those links end with
must be the ones the robots reported and the world summed into the result, less what a crashed
robot counted after its last report (the result names each such incarnation and the tick it
reported to; the audit keeps each robot's last few ticks of counts to take that off).
"""

from __future__ import annotations

import contextlib
import hashlib
from collections import deque
from collections.abc import Callable
from typing import Any

import numpy as np

from policies import is_chained
from swarm.net.direct import COUNT_KEYS, KIND_KEYS, DirectLink, DirectTally, live_plan
from swarm.net.faults import plan_from_table
from swarm.net.messages import K_HIDDEN, K_TRAJ, BadMessage, Hidden, Obs, Stamped, Traj
from world.config import ConfigError, WorldConfig
from world.decentral import predecessor_of


class DirectAudit:
    """The robots' direct delivery, re-run on recorded messages."""

    def __init__(self, cfg: WorldConfig, run: Any, table: dict[str, Any]) -> None:
        self.cfg, self.run = cfg, run
        self.chained = is_chained(run.policy)
        plan = plan_from_table(table, run.seed, cfg.n_robots)
        self.links = [DirectLink(cfg, i, plan, run.tick_timeout) for i in range(cfg.n_robots)]
        # each robot's counts at the end of its last ticks, and where it vanished from the
        # observations: [(those ticks' counts, its counts then)] (a crash loses what it
        # counted after its last report: `DirectTally.retired`)
        self.recent = [deque[tuple[tuple[int, int], dict[str, Any]]](maxlen=KEEP)
                       for _ in range(cfg.n_robots)]
        self.gaps: list[list[tuple[list[Any], dict[str, Any]]]] = [[] for _ in self.links]
        self.present: set[int] = set()
        self.heard: dict[int, list[int]] = {}  # the last tick's senders each robot heard

    def tick(self, obs: dict[int, Obs], stamped: list[tuple[str, Stamped, bytes]],
             same: Callable[[str, Any, Any], None]) -> int:
        """Re-run one tick (observations by robot, stamped messages as (key, envelope, raw
        payload)); `same` reports a divergence. Returns the copies decided."""
        self.faults(obs)
        self.heard = {}
        for i in self.present - set(obs):
            self.gaps[i].append((list(self.recent[i]), self.links[i].record()))
        self.present = set(obs)
        for _, o in sorted(obs.items()):
            self.links[o.robot].begin(o)
        mine = {(st.kind, st.robot): (key, st, raw) for key, st, raw in stamped}
        for (kind, j), (_, st, _) in sorted(mine.items(), key=lambda kv: (kv[0][1], kv[0][0])):
            if j in obs:  # its own stamp: the queue delay its bucket gives, as it claimed
                again = Stamped.unpack(self.links[j].stamp(kind, st.payload), self.cfg)
                what = "trajectory" if kind == K_TRAJ else "hidden-state"
                same(f"robot {j}'s {what} stamp (queue ms)", st.queue_ms, again.queue_ms)
        decided = 0
        for i in sorted(obs):
            for (kind, j), (key, _, raw) in mine.items():
                if kind == K_TRAJ and j != i:
                    self.links[i].offer(key, raw)
            heard = self.links[i].heard()
            decided += len(heard)
            self.heard[i] = [Traj.unpack(p, self.cfg).robot for p in heard]
            if not self.chained:
                continue
            row = np.zeros((1, self.cfg.n_robots), dtype=bool)  # the robot's own predecessor
            row[0, self.heard[i]] = True
            pred = int(predecessor_of(row, np.array([i]))[0])
            if pred >= 0:
                got = mine.get((K_HIDDEN, pred))
                if got is not None:
                    self.links[i].offer(got[0], got[2])
                self.links[i].hidden(pred)
                decided += 1
        for _, o in obs.items():
            self.recent[o.robot].append(((o.ep, o.t), self.links[o.robot].record()))
        return decided

    def faults(self, obs: dict[int, Obs]) -> None:
        """Live fault changes the observations carry (an episode's last one may), as each robot
        applied them; one a robot dropped as bad, the audit drops too."""
        for i, o in obs.items():
            if o.faults:
                try:
                    self.links[i].set_plan(live_plan(o.faults, self.run.seed, self.cfg.n_robots))
                except ConfigError:
                    pass

    def lost_in_crashes(self, restarted: Any) -> list[dict[str, Any]]:
        """The counts each crashed incarnation of the result's `restarted` list made after the
        tick it last reported: its counts when it vanished less its counts at that tick.
        BadMessage when an entry has no such tick among the last ones before a vanishing."""
        out = []
        for entry in restarted if isinstance(restarted, list) else []:
            robot = entry.get("robot") if isinstance(entry, dict) else None
            at = entry.get("reported_to") if isinstance(entry, dict) else None
            gaps = self.gaps[robot] if isinstance(robot, int) and 0 <= robot < len(self.gaps) \
                else []
            for g, (ring, then) in enumerate(gaps):
                base = next((rec for k, rec in ring if list(k) == at), None)
                if base is not None:
                    out.append(_minus(then, base))
                    del gaps[g]
                    break
            else:
                raise BadMessage(f"robot {robot}'s crash after reporting to {at} is not where "
                                 "the recording has it vanish")
        return out

    def totals(self, restarted: Any = None, reported: dict[int, Any] | None = None
               ) -> dict[str, Any]:
        """The counters the links end with, summed as the world sums the robots' reports, less
        what crashed incarnations counted after their last report (`lost_in_crashes`); a robot
        whose last report (`reported`: robot -> the [ep, t] it reports to) came before its
        last tick (crashed for good, hung to the end) counts to that report, as in the world."""
        tally = DirectTally(self.cfg.n_robots)
        for i, link in enumerate(self.links):
            at = (reported or {}).get(i)
            mine = next((rec for k, rec in self.recent[i] if list(k) == at), link.record())
            tally.offer({"robot": i, "direct": mine})
        tot = tally.totals()
        out = {k: tot[k] for k in COUNT_KEYS} | {
            "by_kind": {kind: {k: tot["by_kind"][kind][k] for k in KIND_KEYS}
                        for kind in ("traj", "hidden")}}
        for lost in self.lost_in_crashes(restarted):
            out = _minus({"counts": out}, {"counts": lost})
        return out


KEEP = 8  # ticks of counts kept per robot: a robot reports at least every 5 ticks


def reported(rec: Any) -> dict[int, Any]:
    """Each robot's last recorded direct-delivery report in recording `rec`: the [ep, t] it
    counts to (what the world summed of that robot)."""
    from swarm.net.messages import K_RSTATUS, unpack_record
    from swarm.net.records import check_robot_status

    cfg, tally = rec.record.world, DirectTally(rec.record.world.n_robots)
    for m in rec.of("rstatus"):
        with contextlib.suppress(BadMessage, ValueError, TypeError, KeyError):
            tally.offer(check_robot_status(unpack_record(m.payload, K_RSTATUS), cfg.n_robots,
                                           cfg.horizon))
    return {r: rec_["at"] for r, rec_ in tally.latest.items()}


def _minus(a: dict[str, Any], b: dict[str, Any]) -> dict[str, Any]:
    """The counters of record `a` less those of record `b` (the radio's keys, `by_kind` too)."""
    ca, cb = a["counts"], b["counts"]
    out = {k: ca[k] - cb[k] for k in COUNT_KEYS}
    out["by_kind"] = {kind: {k: ca["by_kind"][kind][k] - cb["by_kind"][kind][k]
                             for k in KIND_KEYS} for kind in ("traj", "hidden")}
    return out


def stamped_of(key: str, payload: bytes, robot: int | None, cfg: WorldConfig) -> Stamped:
    """A recorded stamped message, checked (BadMessage: skipped, as its receivers dropped it)."""
    st = Stamped.unpack(payload, cfg)
    if robot != st.robot or key.endswith("/dhidden") != (st.kind == K_HIDDEN):
        raise BadMessage("a stamped message that does not fit its key")
    return st


def senders_of(payloads: list[bytes] | None, cfg: Any) -> list[int] | None:
    """The sender of each trajectory payload of a bundle (-1: unreadable)."""
    if payloads is None:
        return None
    out = []
    for p in payloads:
        try:
            out.append(Traj.unpack(p, cfg).robot)
        except BadMessage:
            out.append(-1)
    return out


def hidden_label(payload: bytes, cfg: Any) -> str:
    """A hidden-state payload as a short label: `sender:miss` or `sender:<digest of all of it>`."""
    try:
        h = Hidden.unpack(payload, cfg)
    except BadMessage:
        return "bad:" + hashlib.sha1(payload).hexdigest()[:10]
    return f"{h.robot}:" + ("miss" if h.is_miss else hashlib.sha1(payload).hexdigest()[:10])
