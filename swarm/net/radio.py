"""The radio layer: owns delivery of robot-to-robot messages and hosts the fault models (SPEC 5).

It knows the true positions, as an emulator's channel model does. For each tick it decides, per
copy (sender -> receiver), whether the copy is out of range, cut by a partition, lost, or
delayed (latency + jitter + the sender's token-bucket queue), and when it arrives. Each
receiver gets its tick's trajectory messages as one bundle at the arrival of its last on-time
copy, so no robot waits on a timer when nothing is lost; a copy that would arrive after the
tick's message deadline is late: counted, never delivered. Hidden-state messages are forwarded
only to the robots whose predecessor (as computed from what they were delivered) sent them; on
a tick with no link fault the bundles name those successors instead, and each sender puts its
message to them itself (the fast lane: every copy would be on time anyway). `TickInbox` is what
the world gathers in a tick for the radio to deliver from.
Range, neighbourhood and predecessor come from world.decentral, like the batched evaluator's;
loss, partition and the latency draw come from swarm.net.faults.delivery_mask/delay_ms.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from swarm.net.channel import FATES, LATE, OK, VirtualChannel
from swarm.net.faults import KIND_HIDDEN, KIND_TRAJ, FaultPlan, delay_ms, delivery_mask, link_arrays
from swarm.net.messages import Action, Bundle, Hidden
from world.config import WorldConfig
from world.decentral import neighbourhood, predecessor


@dataclass
class LinkStats:
    delivered: int = 0
    lost: int = 0
    cut: int = 0  # partition
    late: int = 0
    queued: int = 0  # delayed by the bandwidth cap
    dropped_bw: int = 0  # dropped by the bandwidth cap (overflow = drop or expire)


@dataclass
class RadioCounters:
    """Per-run message counters, reported in the run's result."""

    traj_in: int = 0
    traj_delivered: int = 0  # (sender, receiver) deliveries, own message included
    # (the copies to other robots alone: `totals()["traj_to_others"]`, the sum of `delivered`)
    hidden_in: int = 0
    hidden_delivered: int = 0
    out_of_range: int = 0  # (sender, receiver) pairs the range limit cut
    lost: int = 0
    cut: int = 0
    late: int = 0
    queued: int = 0
    dropped_bw: int = 0
    bytes_in: int = 0
    bytes_out: int = 0
    links: dict[tuple[int, int], LinkStats] = field(default_factory=dict)
    """Per-link misses and queued copies (faulted links only; `delivered` is in `delivered`)."""
    delivered: np.ndarray = field(default_factory=lambda: np.zeros((0, 0), dtype=np.int64))
    """[sender, receiver] copies delivered (own message excluded), counted with numpy: a
    per-link Python loop would cost O(N^2) a tick for a swarm of hundreds."""
    kinds: dict[str, dict[str, int]] = field(default_factory=lambda: {
        k: dict.fromkeys(("lost", "cut", "late", "dropped_bw", "queued"), 0)
        for k in ("traj", "hidden")})
    """The copies that did not arrive (or waited for tokens), per message kind."""

    def link(self, j: int, i: int) -> LinkStats:
        s = self.links.get((j, i))
        if s is None:
            s = self.links[(j, i)] = LinkStats()
        return s

    def count_delivered(self, ok: np.ndarray) -> None:
        """Add one delivery per (receiver i, sender j) of `ok` [N, N], own copies excluded."""
        if self.delivered.shape != ok.shape:
            self.delivered = np.zeros(ok.shape, dtype=np.int64)
        off = ok.copy()
        np.fill_diagonal(off, False)
        self.delivered += off.T

    def faulted_links(self) -> dict[str, list[int]]:
        """"j-i" -> [delivered, lost + cut + dropped, late, queued] of every link that lost,
        delayed or queued a copy: what the world's status and the dashboard show."""
        out = {}
        for (a, b), s in self.links.items():
            if s.lost or s.cut or s.late or s.queued or s.dropped_bw:
                d = int(self.delivered[a, b]) if self.delivered.size else 0
                out[f"{a}-{b}"] = [d, s.lost + s.cut + s.dropped_bw, s.late, s.queued]
        return out

    def totals(self) -> dict[str, Any]:
        out: dict[str, Any] = {k: getattr(self, k) for k in (
            "traj_in", "traj_delivered", "hidden_in", "hidden_delivered", "out_of_range", "lost",
            "cut", "late", "queued", "dropped_bw", "bytes_in", "bytes_out")}
        out["traj_to_others"] = int(self.delivered.sum())  # own copies excluded
        out["by_kind"] = {k: dict(v) for k, v in self.kinds.items()}
        return out

    def count_traj(self, rows: np.ndarray, hears: np.ndarray, fate: np.ndarray,
                   present: np.ndarray, queued: np.ndarray, sizes: np.ndarray) -> np.ndarray:
        """Count the trajectory copies to receivers `rows` [R] of one tick, each in exactly one
        counter (delivered, out of range, lost, cut, late, dropped), and the queued ones apart;
        returns what each receiver hears, `ok` [R, N]. `hears` [R, N] is range (both present),
        `fate` [R, N] the channel's, `present` [N] who sent, `queued` [N] whose message waited
        for tokens, `sizes` [N] bytes. The world's radio counts every receiver of a tick, a
        robot in direct delivery its own row: the sums agree."""
        self.out_of_range += int(len(rows) * present.sum() - hears.sum())
        others = hears & (rows[:, None] != np.arange(hears.shape[1])[None])
        for r, j in zip(*np.nonzero(others & queued[None]), strict=True):
            self.count_queued("traj", True, int(j), int(rows[r]))
        for r, j in zip(*np.nonzero(hears & (fate != OK)), strict=True):
            self.miss("traj", FATES[fate[r, j]], int(j), int(rows[r]))
        ok = hears & (fate == OK)
        self.traj_delivered += int(ok.sum())
        self.bytes_out += int((ok * sizes[None, :]).sum())
        full = np.zeros((hears.shape[1], hears.shape[1]), dtype=bool)
        full[rows] = ok
        self.count_delivered(full)
        return ok

    def count_queued(self, kind: str, waited: bool, j: int, i: int) -> None:
        """One copy j -> i of `kind` whose sender's message waited for tokens (if `waited`)."""
        if waited:
            self.queued += 1
            self.link(j, i).queued += 1
            self.kinds[kind]["queued"] += 1

    def miss(self, kind: str, what: str, j: int, i: int) -> None:
        """One copy j -> i of `kind` that was lost, cut, late or dropped (`what`)."""
        setattr(self, what, getattr(self, what) + 1)
        s = self.link(j, i)
        setattr(s, what, getattr(s, what) + 1)
        self.kinds[kind][what] += 1


class TokenBucket:
    """Bytes/s cap of one sender's transmissions (a broadcast costs once)."""

    def __init__(self, rate: float, depth: float) -> None:
        self.rate, self.depth = rate, depth
        self.tokens = depth
        self.last: float | None = None

    def send(self, size: int, now: float, overflow: str = "queue",
             deadline: float = math.inf) -> float | None:
        """Seconds the message waits for tokens (0 if none), or None if dropped (`drop`: it
        does not fit; `expire`: it would leave the queue after `deadline`); a dropped message
        costs no tokens."""
        if self.last is not None:
            self.tokens = min(self.depth, self.tokens + self.rate * (now - self.last))
        self.last = now
        if self.tokens >= size:
            self.tokens -= size
            return 0.0
        wait = (size - self.tokens) / self.rate
        if overflow == "drop" or (overflow == "expire" and now + wait > deadline):
            return None
        self.tokens -= size  # goes negative: the queue ahead of later messages
        return wait


def wall_queue(buckets: dict[int, TokenBucket], plan: FaultPlan, sender: int, size: int,
               now: float, deadline: float = math.inf) -> float | None:
    """Seconds a message of `sender` sent at wall time `now` waits in its token bucket (kept in
    `buckets`), None if its cap drops it (or, `expire`, if it would leave after `deadline`):
    the real clock's cap, for the radio and for a robot charging its own bucket in direct
    delivery."""
    f = plan.per_robot.get(sender, plan.default)
    if f.bandwidth <= 0:
        return 0.0
    b = buckets.get(sender)
    if b is None or b.rate != f.bandwidth:
        b = buckets[sender] = TokenBucket(f.bandwidth, f.burst or f.bandwidth)
    return b.send(size, now, f.overflow, deadline)


class Radio:
    """Range-limited, faulted delivery, one tick at a time."""

    def __init__(self, cfg: WorldConfig, plan: FaultPlan | None = None) -> None:
        self.cfg = cfg
        self.counters = RadioCounters()
        self.delivered = np.zeros((cfg.n_robots, cfg.n_robots), dtype=bool)
        self.pred = np.full(cfg.n_robots, -1, dtype=np.int64)
        self.buckets: dict[int, TokenBucket] = {}
        self.channel: VirtualChannel | None = None  # set by use_virtual_clock
        self.tick_s = 0.0
        self.set_plan(plan or FaultPlan())

    def set_plan(self, plan: FaultPlan) -> None:
        self.plan = plan
        self._loss, self._lat, self._jit = link_arrays(plan, self.cfg.n_robots)
        self.buckets = {}
        if self.channel is not None:
            self.channel = VirtualChannel(plan, self.cfg.n_robots, self.tick_s)

    def _queue_delay(self, sender: int, size: int, now: float,
                     deadline: float) -> float | None:
        return wall_queue(self.buckets, self.plan, sender, size, now, deadline)

    def bundles(self, ep: int, t: int, positions: np.ndarray,
                senders: dict[int, tuple[bytes, float]], deadline: float
                ) -> dict[int, tuple[float, list[bytes]]]:
        """Receiver -> (delivery time, payloads it hears in sender-id order).

        `positions` [N, 2] are the true (y, x) at this tick; `senders` maps robot id -> (its
        validated trajectory payload, the monotonic time the radio received it); `deadline` is
        the monotonic time after which a copy is late.
        """
        n, c, plan = self.cfg.n_robots, self.counters, self.plan
        present = np.zeros(n, dtype=bool)
        present[list(senders)] = True
        hears = neighbourhood(self.cfg.comm_range, positions[None], present[None])[0]
        c.out_of_range += int(present.sum() ** 2 - hears.sum())
        ok = hears.copy()
        arrival = np.zeros((n, n))
        if not plan.zero:
            eps = np.array([ep])
            fate = delivery_mask(plan, eps, t, n, KIND_TRAJ)[0]
            grp = plan.group_of(n) if plan.partition else np.zeros(n, dtype=np.int64)
            delay = delay_ms(plan, eps, t, n, KIND_TRAJ, self._lat, self._jit)[0] / 1e3
            for j, (payload, t_recv) in senders.items():
                q = self._queue_delay(j, len(payload), t_recv, deadline)
                for i in np.flatnonzero(hears[:, j]):
                    if i == j:
                        continue
                    c.count_queued("traj", q is not None and q > 0, j, int(i))  # (as count_traj)
                    if grp[i] != grp[j]:
                        ok[i, j] = False
                        c.miss("traj", "cut", j, int(i))
                    elif not fate[i, j]:
                        ok[i, j] = False
                        c.miss("traj", "lost", j, int(i))
                    elif q is None:
                        ok[i, j] = False
                        c.miss("traj", "dropped_bw", j, int(i))
                    else:
                        arrival[i, j] = t_recv + q + delay[i, j]
                        if arrival[i, j] > deadline:
                            ok[i, j] = False
                            c.miss("traj", "late", j, int(i))
        self.delivered = ok
        self.pred = predecessor(ok[None])[0]
        out: dict[int, tuple[float, list[bytes]]] = {}
        for i in senders:
            js = np.flatnonzero(ok[i])
            heard = [senders[int(j)][0] for j in js]
            when = max([senders[i][1]] + [float(arrival[i, j]) for j in js if j != i])
            out[i] = (when, heard)
            c.traj_delivered += len(heard)
            c.bytes_out += sum(len(p) for p in heard)
        c.count_delivered(ok)
        return out

    @property
    def pred(self) -> np.ndarray:
        """[N] each robot's predecessor in the last delivery (-1: none)."""
        return self._pred

    @pred.setter
    def pred(self, value: np.ndarray) -> None:
        self._pred, self._succ = value, None

    def successors(self, sender: int) -> list[int]:
        """The robots whose predecessor is `sender` (one pass over `pred` per tick, not per
        hidden-state message: 100 robots send 100 of them a tick)."""
        if self._succ is None:
            self._succ = [[] for _ in range(len(self._pred))]
            for i, p in enumerate(self._pred.tolist()):
                if p >= 0:
                    self._succ[p].append(i)
        return list(self._succ[sender]) if 0 <= sender < len(self._succ) else []

    def heard_links(self) -> int:
        """Robot pairs that heard each other (either way) in the last tick's delivery, faults and
        partitions included: the links the dashboard shows."""
        d = self.delivered
        return int(np.triu(d | d.T, 1).sum())

    def hidden_deliveries(self, ep: int, t: int, sender: int, size: int, now: float,
                          deadline: float) -> list[tuple[int, float]]:
        """(receiver, delivery time) for a hidden-state message of `sender` received at `now`."""
        c, plan, n = self.counters, self.plan, self.cfg.n_robots
        receivers = self.successors(sender)
        if plan.zero or not receivers:
            return [(i, now) for i in receivers]
        eps = np.array([ep])
        fate = delivery_mask(plan, eps, t, n, KIND_HIDDEN)[0]
        delay = delay_ms(plan, eps, t, n, KIND_HIDDEN, self._lat, self._jit)[0] / 1e3
        q = self._queue_delay(sender, size, now, deadline)
        out = []
        for i in receivers:
            if not fate[i, sender]:
                c.miss("hidden", "lost", sender, i)
            elif q is None:
                c.miss("hidden", "dropped_bw", sender, i)
            else:
                c.count_queued("hidden", q > 0, sender, i)
                when = now + q + delay[i, sender]
                if when > deadline:
                    c.miss("hidden", "late", sender, i)
                else:
                    out.append((i, when))
        return out

    # --- virtual clock (swarm.net.channel): fates decided at send time, delivered at once -----
    def use_virtual_clock(self, tick_s: float) -> None:
        self.tick_s = tick_s
        self.channel = VirtualChannel(self.plan, self.cfg.n_robots, tick_s)

    def new_episode(self) -> None:
        """Token buckets start full at every episode (as the batched evaluator's do)."""
        if self.channel is not None:
            self.channel.reset(1)

    def virtual_bundles(self, ep: int, t: int, positions: np.ndarray,
                        senders: dict[int, bytes]) -> dict[int, list[bytes]]:
        """Receiver -> the trajectory payloads it hears (on-time copies only, sender-id order)."""
        assert self.channel is not None
        n, c = self.cfg.n_robots, self.counters
        present = np.zeros(n, dtype=bool)
        present[list(senders)] = True
        sizes = np.zeros(n)
        for j, payload in senders.items():
            sizes[j] = len(payload)
        hears = neighbourhood(self.cfg.comm_range, positions[None], present[None])[0]
        f = self.channel.traj(np.array([ep]), t, present[None], sizes[None])
        rows = np.flatnonzero(present)
        ok = np.zeros((n, n), dtype=bool)
        ok[rows] = c.count_traj(rows, hears[rows], f.fate[0][rows], present, f.queued[0], sizes)
        self.delivered = ok
        self.pred = predecessor(ok[None])[0]
        payloads = [senders.get(j, b"") for j in range(n)]
        return {i: [payloads[j] for j in np.flatnonzero(ok[i]).tolist()] for i in senders}

    def bundle_sends(self, tick: TickInbox, positions: np.ndarray
                     ) -> list[tuple[float, int, bytes]]:
        """(when, receiver, packed Bundle) for the trajectory messages of `tick`: all at once
        (0.0) on the virtual clock, a fast-lane tick's naming each receiver's successors; at
        their wall-clock arrival times on the real one."""
        ep, t = tick.ep, tick.t
        if self.channel is not None:
            heard = self.virtual_bundles(ep, t, positions,
                                         {j: p for j, (p, _) in tick.traj.items()})
            return [(0.0, i, Bundle(ep, t, i, msgs, self.successors(i) if tick.fast_lane
                                    else None).pack()) for i, msgs in heard.items()]
        sends = self.bundles(ep, t, positions, tick.traj, tick.traj_deadline)
        return [(when, i, Bundle(ep, t, i, msgs).pack()) for i, (when, msgs) in sends.items()]

    def hidden_sends(self, msg: Hidden, payload: bytes, now: float, deadline: float
                     ) -> list[tuple[float, int, bytes]]:
        """(when, successor, payload) for a hidden-state message: on the virtual clock all at
        once, a lost or late copy replaced by word that it will not come (`Hidden.miss`)."""
        if self.channel is not None:
            fates = self.virtual_hidden(msg.ep, msg.t, msg.robot, len(payload))
            self.counters.hidden_delivered += sum(ok for _, ok in fates)
            miss = Hidden.miss(msg.ep, msg.t, msg.robot).pack()
            return [(0.0, i, payload if ok else miss) for i, ok in fates]
        sends = self.hidden_deliveries(msg.ep, msg.t, msg.robot, len(payload), now, deadline)
        self.counters.hidden_delivered += len(sends)
        return [(when, i, payload) for i, when in sends]

    def virtual_hidden(self, ep: int, t: int, sender: int, size: int) -> list[tuple[int, bool]]:
        """(successor, on time) for the hidden-state message `sender` sent at tick t; charged
        to its bucket whether or not anyone's predecessor it is."""
        assert self.channel is not None
        successors = self.successors(sender)
        if self.channel.plan.zero:  # no loss, delay, cap or cut: every copy on time
            return [(i, True) for i in successors]
        fates, q = self.channel.hidden_from(ep, t, sender, size)  # O(N): per message
        out = []
        for i in successors:
            fate = int(fates[i])
            self.counters.count_queued("hidden", fate in (OK, LATE) and q > 0, sender, i)
            if fate != OK:
                self.counters.miss("hidden", FATES[fate], sender, i)
            out.append((i, fate == OK))
        return out


@dataclass
class TickInbox:
    """What the world gathered for tick `t` of episode `ep` (the radio delivers from it)."""

    ep: int
    t: int
    traj_deadline: float
    """Monotonic time after which a trajectory copy is late for its receivers."""
    hidden_deadline: float
    """Monotonic time after which a hidden-state copy is late for its successor."""
    traj: dict[int, tuple[bytes, float]] = field(default_factory=dict)
    """Sender -> (its trajectory payload, arrival time)."""
    hidden: dict[int, tuple[Hidden, bytes]] = field(default_factory=dict)
    """Hidden-state messages held until the bundles are out (then forwarded as they come)."""
    action: dict[int, Action] = field(default_factory=dict)
    sent_hidden: set[int] = field(default_factory=set)
    """Robots whose hidden-state message of this tick arrived (chained policies)."""
    delivered: bool = False
    """The bundles of this tick have been handed to the radio."""
    hidden_at: dict[int, float] = field(default_factory=dict)
    """Robot -> perf_counter time its hidden-state message reached the world's loop (in the fast
    lane: its action, sent right after the hidden-state message)."""
    fast_lane: bool = False
    """This tick's bundles named each robot's successors, and the robots send their hidden-state
    messages to them directly (`WorldProcess.fast_lane` with no link fault): nothing to forward."""


def has_all(got: dict[int, Any] | set[int], live: set[int]) -> bool:
    """Every live robot is in `got` (a set, or a dict's keys; the length test first: this runs
    on every message)."""
    return len(got) >= len(live) and live.issubset(got)


def chain_times(chain_ms: list[list[float]], pred: np.ndarray, hidden_at: dict[int, float],
                t_delivered: float) -> None:
    """Add to `chain_ms` ([sum of ms, messages] per position in the chain: 0 no predecessor, k
    k hops down) when this tick's hidden-state messages (`hidden_at`: robot -> monotonic time)
    reached the world after the bundles began to go out (`t_delivered`): where the chain's time
    goes (the world's `chain_ms_by_depth`)."""
    if not hidden_at:
        return
    depth: list[int] = []
    for p in pred.tolist():
        depth.append(0 if p < 0 else depth[p] + 1)  # a predecessor has a lower id
    for i, at in hidden_at.items():
        d = depth[i]
        while len(chain_ms) <= d:
            chain_ms.append([0.0, 0])
        chain_ms[d][0] += 1e3 * (at - t_delivered)
        chain_ms[d][1] += 1
