"""Direct delivery (SPEC 5, `--delivery direct`): no radio in the message path.

Every robot puts its trajectory and hidden-state messages on its own keys
(`Keys.direct(i)`, `Keys.direct(i, hidden=True)`), each wrapped in a `Stamped` envelope that
carries the one fate only its sender can know, the wait in its own token bucket (or that the cap
dropped it); every robot subscribes to every other's trajectory key and to the hidden-state keys
of the robots that can be its predecessor (the lower ids). A receiver then decides each copy
itself, with the same code the world's radio runs (`swarm.net.channel.VirtualChannel`): range
from the sender's true cell in its trajectory message (`world.decentral.neighbourhood`), loss,
partition, latency and jitter from the counter-based draws keyed by (seed, episode, tick,
sender, receiver, kind), lateness against the tick's virtual deadline. Counting goes through
the radio's own `RadioCounters.count_traj`, so the counters robots report sum to the radio's.

`DirectLink` is a robot's side, one tick at a time: `begin` (the observation names the robots
whose trajectory messages to wait for), `stamp` (its own sends), `offer` (what arrives),
`heard` once `traj_complete`, `hidden` for its predecessor. `DirectTally` is the world's side:
it sums the counters robots report in their status records.
"""

from __future__ import annotations

import math
import secrets
import time
from typing import Any

import msgpack
import numpy as np

from swarm.net.channel import CUT, FATES, HIDDEN_FRAC, LATE, LOST, OK, TRAJ_FRAC, VirtualChannel
from swarm.net.faults import KIND_HIDDEN, KIND_TRAJ, FaultPlan, plan_from_table
from swarm.net.keys import Keys
from swarm.net.messages import (
    DROPPED_Q,
    K_HIDDEN,
    K_TRAJ,
    BadMessage,
    Hidden,
    Obs,
    Stamped,
    Traj,
)
from swarm.net.radio import RadioCounters, TokenBucket, wall_queue
from world.config import ConfigError, WorldConfig
from world.decentral import neighbourhood

WAIT_FRAC = 0.5  # a robot waits for the tick's trajectory messages up to this part of its budget
BIG = 2**53  # counters a status record may report
MAX_RESTARTS = 64  # incarnations per robot (on average) the world's tally keeps


def live_plan(packed: bytes, seed: int, n: int) -> FaultPlan:
    """The plan of a live fault change an observation carries (`Obs.faults`: the run's
    `[faults]` table, msgpack); a ConfigError names what is wrong with it."""
    try:
        table = msgpack.unpackb(packed)
    except (ValueError, TypeError, msgpack.UnpackException) as exc:
        raise ConfigError(f"the faults table does not decode: {exc}") from None
    if not isinstance(table, dict):
        raise ConfigError("the faults table is not a map")
    try:
        return plan_from_table(table, seed, n)
    except ConfigError:
        raise
    except (TypeError, ValueError, AttributeError) as exc:
        raise ConfigError(f"bad faults table: {exc}") from None


def carried(st: Stamped, cfg: WorldConfig) -> Traj | Hidden:
    """The message a stamped envelope carries, checked against it (kind, episode, tick, sender);
    BadMessage otherwise."""
    msg: Traj | Hidden = (Traj if st.kind == K_TRAJ else Hidden).unpack(st.payload, cfg)
    if (msg.ep, msg.t, msg.robot) != (st.ep, st.t, st.robot):
        raise BadMessage("the carried message does not match its envelope")
    return msg  # (an empty hidden state: its sender could not decide; decoded without)


class DirectLink:
    """Robot `robot`'s direct delivery (see the module docstring); `real`: on the wall clock
    (`--clock real`), where a copy arrives when it came plus its sender's queue and its drawn
    delay, and is late after this robot's own deadline (the radio's fractions of its budget)."""

    def __init__(self, cfg: WorldConfig, robot: int, plan: FaultPlan, tick_s: float,
                 real: bool = False) -> None:
        self.cfg, self.robot, self.n = cfg, robot, cfg.n_robots
        self.channel = VirtualChannel(plan, cfg.n_robots, tick_s)
        self.real = real
        self.t0 = 0.0  # real clock: when this tick's observation came (monotonic seconds)
        self.budget_s = 0.0
        self.arrived: dict[tuple[int, int, int, int], float] = {}  # real: when each came
        self.wall_buckets: dict[int, TokenBucket] = {}  # real: its own bucket, wall time
        self.due = 0.0  # real: when the last on-time copy it heard this tick arrives
        self.wake_at = math.inf  # real: when the predecessor's held hidden state is due
        self.counters = RadioCounters()
        self.ep, self.t = -1, -1
        self.done_ep = -1  # the last episode whose end this robot saw (the world's tally waits)
        self.expected = np.zeros(self.n, dtype=bool)
        # peers whose liveliness token vanished -> the tick (a count of `begin`s) it did
        self.gone: dict[int, int] = {}
        self.begins = 0
        self.seen: set[int] = {robot}  # peers whose liveliness token it sees now
        self.store: dict[tuple[int, int, int, int], tuple[Stamped, Traj | Hidden]] = {}
        self.decided: set[tuple[int, int, int]] = set()  # hidden copies decided before arrival
        self.early: dict[tuple[int, int, int], int] = {}  # their fate as far as draws tell
        self.stale = 0  # messages of a tick this robot had already left
        self.used: set[tuple[int, int, int, int]] = set()  # trajectory copies `heard` took
        self.took: tuple[int, int] | None = None  # the (episode, tick) `heard` took last
        self.overflow = 0  # messages refused because too many were held
        self.boot = secrets.randbits(62)  # this incarnation: a restarted robot counts anew

    def set_plan(self, plan: FaultPlan) -> None:
        """A live fault change, from the tick whose observation carried it (as the radio's
        `Radio.set_plan`: a new channel, token buckets full again)."""
        self.channel = VirtualChannel(plan, self.n, self.channel.tick_ms / 1e3)
        self.wall_buckets = {}

    # --- a tick ------------------------------------------------------------------------------
    def begin(self, obs: Obs, now: float | None = None) -> None:
        """A new tick (a new episode starts with full token buckets; a robot that comes in
        mid-episode, restarted, takes up its own bucket where its last action left it, unless
        the plan changes at this tick: a change fills every bucket)."""
        if obs.ep != self.ep or obs.t == 0:
            self.channel.reset(1)
            if obs.t > 0 and obs.bucket is not None and not obs.faults and not self.real:
                self.channel.tokens[0, self.robot], self.channel.last[0, self.robot] = obs.bucket
        self.ep, self.t = obs.ep, obs.t
        self.t0 = time.monotonic() if now is None else now
        self.budget_s = obs.budget_ms / 1e3
        self.expected = np.ones(self.n, dtype=bool) if not obs.live else np.unpackbits(
            np.frombuffer(obs.live, dtype=np.uint8), count=self.n).astype(bool)
        self.expected[self.robot] = True
        self.begins += 1
        for j in [j for j, at in self.gone.items() if self.expected[j] and at < self.begins - 1]:
            # it vanished before the last tick began and the world lists it again: it came
            # back (restarted), so it is waited for, its new token first (`sees_peers`), even
            # where that token has not reached this robot yet (a loaded machine)
            del self.gone[j]
            self.seen.discard(j)
        for key in [k for k in self.store if (k[1], k[2]) < (self.ep, self.t)]:
            del self.store[key]  # others' hidden states, copies that came after it decided
            self.arrived.pop(key, None)
            # a peer's trajectory copy that came after `heard` took the tick's (its wait ran
            # out on the wall clock): stale, as one of an older tick is (a tick it never took,
            # missed or before a restart, counts its copies nowhere, as before)
            self.stale += key[0] == K_TRAJ and key[3] != self.robot and \
                (key[1], key[2]) == self.took and key not in self.used
        self.decided, self.early, self.used = set(), {}, set()

    def own_deadline(self, kind: int) -> float:
        """Real clock: when a message of `kind` (K_TRAJ or K_HIDDEN) of this tick is late, in
        monotonic seconds (the radio's fractions of this robot's budget from its observation)."""
        return self.t0 + (TRAJ_FRAC if kind == K_TRAJ else HIDDEN_FRAC) * self.budget_s

    def stamp(self, kind: int, payload: bytes, now: float | None = None) -> bytes:
        """This robot's message of the current tick in its envelope, charged to its bucket (a
        trajectory first, then the hidden state: the radio's order; on the real clock at the
        wall time it leaves, as the radio charged it when it came)."""
        if self.real:
            now = time.monotonic() if now is None else now
            self.arrived[(kind, self.ep, self.t, self.robot)] = now
            w = wall_queue(self.wall_buckets, self.channel.plan, self.robot, len(payload), now,
                           self.own_deadline(kind))
            q = math.nan if w is None else 1e3 * w
        else:
            q = self.channel.charge(self.t, self.robot, len(payload),
                                    KIND_TRAJ if kind == K_TRAJ else KIND_HIDDEN)
        st = Stamped(kind, self.ep, self.t, self.robot, DROPPED_Q if math.isnan(q) else q,
                     payload)
        msg: Traj | Hidden = (Traj if kind == K_TRAJ else Hidden).unpack(payload, self.cfg)
        self.store[(kind, self.ep, self.t, self.robot)] = (st, msg)  # its own copy, kept
        c = self.counters  # what it sent, as the radio counted what it received
        if kind == K_TRAJ:
            c.traj_in += 1
            c.bytes_in += len(payload)
        else:
            c.hidden_in += 1
        return st.pack()

    def bucket(self) -> tuple[float, float] | None:
        """Its own token bucket (tokens, ms of the last charge) for its action to carry; None
        when it has no cap or has not sent this episode."""
        ch, r = self.channel, self.robot
        if self.real or ch.rate[r] <= 0 or math.isnan(ch.last[0, r]):
            return None
        return float(ch.tokens[0, r]), float(ch.last[0, r])

    def peer(self, key: str, live: bool) -> None:
        """A robot's liveliness token came or went: a gone robot is not waited for."""
        try:
            j = Keys.robot_of(key)
        except ValueError:
            return
        if 0 <= j < self.n and j != self.robot:
            (self.seen.add if live else self.seen.discard)(j)
            if live:
                self.gone.pop(j, None)
            else:
                self.gone[j] = self.begins

    def sees_peers(self) -> bool:
        """It sees the token of every robot the world sent this tick's observation to, except
        those whose token it saw vanish (a robot that crashed after the world sent it this
        observation: waiting for it would spend the tick's wait on a robot that never comes).
        A peer's token comes after its subscriptions on the same links, so from then on this
        robot's messages reach it: a robot sends only once this holds (or a wait ran out), or a
        subscription still on its way across routers could miss its first messages."""
        want = set(np.flatnonzero(self.expected).tolist()) - self.gone.keys()
        return bool(self.seen.issuperset(want))

    def offer(self, key: str, payload: bytes, now: float | None = None) -> None:
        """A stamped message from the network (that came at `now`, real clock); BadMessage (to
        drop and count) unless it fits its key and schema."""
        st = Stamped.unpack(payload, self.cfg)
        if Keys.robot_of(key) != st.robot:
            raise BadMessage(f"robot id {st.robot} does not match key")
        if key.endswith("/dhidden") != (st.kind == K_HIDDEN):
            raise BadMessage("message kind does not match key")
        msg = carried(st, self.cfg)
        if st.robot == self.robot or (st.kind == K_HIDDEN and st.robot > self.robot):
            return  # its own copy is kept when it is sent; a later id is never its predecessor
        if (st.ep, st.t) < (self.ep, self.t):
            self.stale += st.kind == K_TRAJ  # a hidden state it decided without, or not its own
            return
        k = (st.kind, st.ep, st.t, st.robot)
        if k in self.store:
            raise BadMessage(f"a second {'trajectory' if st.kind == K_TRAJ else 'hidden-state'}"
                             f" message of robot {st.robot} for tick {st.t}")
        if len(self.store) >= 8 * self.n:  # a peer far ahead (or a flood): bounded
            self.overflow += 1
            return
        self.store[k] = (st, msg)
        if self.real:
            self.arrived[k] = time.monotonic() if now is None else now

    def traj_complete(self) -> bool:
        """Every robot the world sent this tick's observation to (and that is still alive) has
        sent its trajectory message."""
        for j in np.flatnonzero(self.expected):
            if (K_TRAJ, self.ep, self.t, int(j)) not in self.store and int(j) not in self.gone:
                return False
        return True

    def heard(self) -> list[bytes]:
        """The trajectory payloads this robot hears this tick, in sender-id order (its own
        included): range at the senders' true cells, then each copy's fate; every copy
        counted once."""
        n, c = self.n, self.counters
        self.took = (self.ep, self.t)
        present = np.zeros(n, dtype=bool)
        pos = np.zeros((n, 2), dtype=np.int64)
        q = np.zeros(n)
        sizes = np.zeros(n)
        payloads: list[bytes] = [b""] * n
        for j in range(n):
            got = self.store.get((K_TRAJ, self.ep, self.t, j))
            if got is None:
                continue
            st, msg = got
            assert isinstance(msg, Traj)
            self.used.add((K_TRAJ, self.ep, self.t, j))
            present[j] = True
            pos[j] = (msg.y, msg.x)
            q[j] = math.nan if st.queue_ms == DROPPED_Q else st.queue_ms
            sizes[j] = len(st.payload)
            payloads[j] = st.payload
        if not present[self.robot]:
            return []
        hears = neighbourhood(self.cfg.comm_range, pos[None], present[None])[0][self.robot]
        if self.real:  # each copy from when it came, against this robot's own deadline
            sent = np.array([1e3 * self.arrived.get((K_TRAJ, self.ep, self.t, j), self.t0)
                             for j in range(n)])
            fate, arrival = self.channel.row_at(KIND_TRAJ, self.ep, self.t, self.robot, sent, q,
                                                1e3 * self.own_deadline(K_TRAJ))
        else:
            fate = self.channel.row(KIND_TRAJ, self.ep, self.t, self.robot, q)
        rows = np.array([self.robot])
        ok = c.count_traj(rows, hears[None], fate[None], present, present & (q > 0), sizes)[0]
        if self.real:  # the robot has them once the last one arrives
            self.due = max([self.t0] + [arrival[j] / 1e3 for j in np.flatnonzero(ok).tolist()
                                        if j != self.robot])
        return [payloads[j] for j in np.flatnonzero(ok).tolist()]

    def hidden(self, pred: int, now: float | None = None) -> Hidden | None:
        """Predecessor `pred`'s hidden-state message of this tick: the message, a miss marker
        (lost, cut, dropped or late: decode without it), or None while it has not come and its
        fate depends on it (its queue delay), or, on the real clock, until it is due (then
        `wake_at` says when)."""
        c, key = self.counters, (self.ep, self.t, pred)
        if key in self.decided:
            return Hidden.miss(*key)
        got = self.store.get((K_HIDDEN, self.ep, self.t, pred))
        msg: Traj | Hidden | None = None
        if got is None:  # loss and partition are known without it: nobody waits for those
            if key not in self.early:
                self.early[key] = OK if self.channel.plan.zero else int(
                    self.channel.column(KIND_HIDDEN, self.ep, self.t, pred, 0.0)[self.robot])
            fate = self.early[key]
            if fate not in (LOST, CUT):
                return None
        else:
            st, msg = got
            q = math.nan if st.queue_ms == DROPPED_Q else st.queue_ms
            if self.real:
                k = (K_HIDDEN, self.ep, self.t, pred)
                f, arrival = self.channel.row_at(
                    KIND_HIDDEN, self.ep, self.t, self.robot,
                    np.full(self.n, 1e3 * self.arrived.get(k, self.t0)), np.full(self.n, q),
                    1e3 * self.own_deadline(K_HIDDEN))
                fate = int(f[pred])
                now = time.monotonic() if now is None else now
                if fate == OK and arrival[pred] / 1e3 > now:
                    self.wake_at = arrival[pred] / 1e3
                    return None
            else:
                fate = int(self.channel.column(KIND_HIDDEN, self.ep, self.t, pred, q)[self.robot])
        self.decided.add(key)
        if got is not None:  # (a copy lost or cut is decided without it: never counted queued)
            c.count_queued("hidden", fate in (OK, LATE) and q > 0, pred, self.robot)
        if fate != OK or not isinstance(msg, Hidden):
            c.miss("hidden", FATES[fate], pred, self.robot)
            return Hidden.miss(*key)
        c.hidden_delivered += 1
        return msg

    def record(self) -> dict[str, Any]:
        """The counters for the robot's status record (`DirectTally` sums them)."""
        return {"done_ep": self.done_ep, "stale": self.stale, "overflow": self.overflow,
                "counts": self.counters.totals(), "links": self.counters.faulted_links(),
                "boot": self.boot, "at": [self.ep, self.t]}


COUNT_KEYS = ("traj_in", "traj_delivered", "hidden_in", "hidden_delivered", "out_of_range", "lost",
              "cut", "late", "queued", "dropped_bw", "bytes_in", "bytes_out")
KIND_KEYS = ("lost", "cut", "late", "dropped_bw", "queued")


def _count(v: Any, name: str) -> int:
    if not isinstance(v, int) or isinstance(v, bool) or not 0 <= v <= BIG:
        raise BadMessage(f"{name}={v!r} is not a count")
    return v


def check_direct(rec: Any, n: int) -> tuple[int, dict[str, Any]]:
    """(robot, its `direct` counters) of a robot status record, every field range-checked
    (BadMessage otherwise)."""
    if not isinstance(rec, dict):
        raise BadMessage("status must be a map")
    robot = rec.get("robot")
    if not isinstance(robot, int) or isinstance(robot, bool) or not 0 <= robot < n:
        raise BadMessage(f"robot={robot!r} not in the team")
    d = rec.get("direct")
    if not isinstance(d, dict) or not isinstance(d.get("counts"), dict):
        raise BadMessage("no direct counters")
    done = d.get("done_ep")
    if not isinstance(done, int) or isinstance(done, bool) or not -1 <= done < 2**31:
        raise BadMessage(f"done_ep={done!r} out of range")
    counts, by_kind = d["counts"], d["counts"].get("by_kind")
    out: dict[str, Any] = {k: _count(counts.get(k), k) for k in COUNT_KEYS}
    others = counts.get("traj_to_others")  # (absent from the records of older recordings)
    out["traj_to_others"] = None if others is None else _count(others, "traj_to_others")
    if not isinstance(by_kind, dict) or set(by_kind) != {"traj", "hidden"}:
        raise BadMessage("by_kind must hold traj and hidden")
    out["by_kind"] = {kind: {k: _count((by_kind[kind] or {}).get(k) if isinstance(
        by_kind[kind], dict) else None, f"{kind}.{k}") for k in KIND_KEYS} for kind in by_kind}
    links = d.get("links", {})
    if not isinstance(links, dict) or len(links) > n:
        raise BadMessage("links must be a map of at most one entry per sender")
    for key, v in links.items():
        a, _, b = key.partition("-") if isinstance(key, str) else ("", "", "")
        if not (a.isdigit() and b.isdigit() and int(a) < n and int(b) == robot) or \
                not isinstance(v, list) or len(v) != 4:
            raise BadMessage(f"link {key!r} is not one of robot {robot}'s incoming links")
        links[key] = [_count(x, f"links.{key}") for x in v]
    boot, at = d.get("boot", 0), d.get("at", [-1, -1])
    if not isinstance(boot, int) or isinstance(boot, bool) or not 0 <= boot < 2**62:
        raise BadMessage(f"boot={boot!r} out of range")
    if not isinstance(at, list) or len(at) != 2 or not all(
            isinstance(x, int) and not isinstance(x, bool) and -1 <= x < 2**31 for x in at):
        raise BadMessage(f"at={at!r} is not [episode, tick]")
    return robot, {"done_ep": done, "stale": _count(d.get("stale", 0), "stale"),
                   "counts": out, "links": links, "boot": boot, "at": at}


class DirectTally:
    """The world's sum of the counters its robots report (direct delivery): the latest record of
    each robot's incarnation, whose counters are cumulative over its life, plus the last record
    of each incarnation before it (a robot restarted after a crash counts from zero again; what
    its predecessor counted after its last report died with it, and `retired` says from when)."""

    def __init__(self, n: int) -> None:
        self.n = n
        self.latest: dict[int, dict[str, Any]] = {}
        self.retired: list[tuple[int, dict[str, Any]]] = []  # (robot, its last record)
        self.boots: set[tuple[int, int]] = set()  # (robot, boot) of every retired incarnation
        self.buckets: dict[int, tuple[int, tuple[float, float]]] = {}  # robot: (ep, bucket)

    def offer(self, payload_record: Any) -> None:
        robot, rec = check_direct(payload_record, self.n)
        if (robot, rec["boot"]) in self.boots:
            raise BadMessage(f"a record of robot {robot}'s earlier incarnation, after its restart")
        old = self.latest.get(robot)
        if old is not None and old["boot"] != rec["boot"]:
            if len(self.retired) >= MAX_RESTARTS * self.n:  # a robot inventing incarnations
                raise BadMessage(f"robot {robot}: more incarnations than a run can restart")
            self.retired.append((robot, old))
            self.boots.add((robot, old["boot"]))
        self.latest[robot] = rec

    def took(self, action: Any, delivered: np.ndarray) -> None:
        """A robot's checked `Action` of the tick: keep its token bucket (handed back in its
        observations, `Obs.bucket`) and write whom it heard into `delivered` [N, N] (the
        dashboard's links, as the radio's bundles would)."""
        if action.bucket is not None:
            self.buckets[action.robot] = (action.ep, action.bucket)
        if action.heard:
            delivered[action.robot] = np.unpackbits(np.frombuffer(
                action.heard, dtype=np.uint8), count=self.n).astype(bool)

    def bucket_of(self, robot: int, ep: int) -> tuple[float, float] | None:
        """Robot `robot`'s bucket as its last action of episode `ep` reported it, if any."""
        held = self.buckets.get(robot)
        return held[1] if held is not None and held[0] == ep else None

    def _records(self) -> list[dict[str, Any]]:
        return [rec for _, rec in self.retired] + list(self.latest.values())

    def complete(self, robots: np.ndarray, ep: int) -> bool:
        """Each robot of `robots` [N] bool has reported after the end of episode `ep`."""
        return all(self.latest.get(int(i), {}).get("done_ep", -1) >= ep
                   for i in np.flatnonzero(robots))

    def totals(self) -> dict[str, Any]:
        """The run's message counters, the radio's keys (`RadioCounters.totals`), summed."""
        out: dict[str, Any] = dict.fromkeys(COUNT_KEYS, 0)
        out["by_kind"] = {k: dict.fromkeys(KIND_KEYS, 0) for k in ("traj", "hidden")}
        for rec in self._records():
            c = rec["counts"]
            for k in COUNT_KEYS:
                out[k] += c[k]
            for kind in ("traj", "hidden"):
                for k in KIND_KEYS:
                    out["by_kind"][kind][k] += c["by_kind"][kind][k]
        others = [rec["counts"].get("traj_to_others") for rec in self._records()]
        if None not in others:  # (every record has it but an older recording's)
            out["traj_to_others"] = sum(others)
        out["robot_stale"] = sum(rec["stale"] for rec in self._records())
        out["reported"] = sorted(self.latest)
        if self.retired:  # each crashed incarnation: counted up to its last report
            out["restarted"] = [{"robot": r, "reported_to": rec["at"]} for r, rec in self.retired]
        return out

    def faulted_links(self) -> dict[str, list[int]]:
        """The robots' own incoming faulted links, together: the radio's `faulted_links`."""
        out: dict[str, list[int]] = {}
        for rec in self._records():
            for k, v in rec["links"].items():
                out[k] = [a + b for a, b in zip(out.get(k, [0, 0, 0, 0]), v, strict=True)]
        return out
