"""The radio channel in virtual time: the fate of every copy of a tick's messages, decided when
it is sent, as a pure function of the fault plan, the seed and the message sizes.

Times are milliseconds from the episode's start. Tick t starts at `t * tick_ms`; robot j sends
its trajectory message, then (chained policies) its hidden-state message, at
`t * tick_ms + compute_ms[j]` (its modelled compute time, `LinkFault.compute_ms`). A copy
j -> i arrives at send + queue + latency + jitter, where the queue is the sender's token bucket
(`bandwidth` bytes/s, `burst` deep, full at every episode's start; `expire`: a message that
would leave it after its deadline is discarded unsent) in virtual time, and the
latency and jitter draws are those of `swarm.net.faults.delay_ms`. It is on time when it
arrives by the tick's deadline: `traj_frac * tick_ms` after the tick's start for trajectory
messages, `hidden_frac * tick_ms` for hidden-state messages. Loss and partitions are
`swarm.net.faults.delivery_mask`'s draws.

One class serves both sides of SPEC 3's identity: the world's radio runs it with one group (the
run's current episode), the batched evaluator with one group per episode of the batch, and they
decide the same for every copy, so a virtual-clock swarm run equals `swarm eval` with the same
seed and plan.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from swarm.net.faults import KIND_HIDDEN, KIND_TRAJ, FaultPlan, delay_ms, delivery_mask, link_arrays

OK, LOST, CUT, LATE, DROPPED = 0, 1, 2, 3, 4  # fate of one copy
FATES = ("delivered", "lost", "cut", "late", "dropped_bw")
TRAJ_FRAC, HIDDEN_FRAC = 0.8, 0.9


@dataclass
class Fates:
    """The copies of one kind at one tick, [G, N(receiver), N(sender)]; self copies are OK."""

    fate: np.ndarray  # int8, one of OK, LOST, CUT, LATE, DROPPED
    arrival_ms: np.ndarray  # float64, when a copy that is not lost or cut arrives
    queued: np.ndarray  # bool [G, N(sender)]: the sender's message waited for tokens

    @property
    def ok(self) -> np.ndarray:
        return self.fate == OK


class VirtualChannel:
    """Fates of the copies of G episodes' ticks in virtual time (see the module docstring)."""

    def __init__(self, plan: FaultPlan, n: int, tick_s: float, groups: int = 1) -> None:
        self.plan, self.n, self.tick_ms = plan, n, 1e3 * tick_s
        self._loss, self._lat, self._jit = link_arrays(plan, n)
        per = [plan.per_robot.get(j, plan.default) for j in range(n)]
        self.compute_ms = np.array([f.compute_ms for f in per])
        self.rate = np.array([f.bandwidth for f in per])  # bytes/s, 0: no cap
        self.depth = np.array([f.burst or f.bandwidth for f in per])
        self.drop = np.array([f.overflow == "drop" for f in per])
        self.expire = np.array([f.overflow == "expire" for f in per])
        self.capped = bool((self.rate > 0).any())
        grp = plan.group_of(n)
        self._cut = grp[:, None] != grp[None, :]  # [receiver, sender] in different groups
        self._base_key: tuple[int, bytes, int] | None = None
        self._base_val: tuple[np.ndarray, np.ndarray] = (np.zeros(0), np.zeros(0))
        self.reset(groups)

    def reset(self, groups: int) -> None:
        """New episodes in every group: full token buckets."""
        self.tokens = np.tile(self.depth, (groups, 1)).astype(np.float64)
        self.last = np.full((groups, self.n), np.nan)

    def send_ms(self, t: int) -> np.ndarray:
        """[N] when each robot sends at tick t."""
        return t * self.tick_ms + self.compute_ms

    def _queue(self, senders: np.ndarray, sizes: np.ndarray, now: np.ndarray,
               deadline_ms: float) -> np.ndarray:
        """Charge the senders' buckets [G, N]; ms each message waits (0 unqueued, NaN dropped:
        `drop` when it does not fit, `expire` when it would leave after `deadline_ms`)."""
        q = np.zeros(senders.shape)
        if not self.capped:
            return q
        capped = senders & (self.rate > 0)[None]
        rate = np.where(self.rate > 0, self.rate, 1.0)[None] / 1e3  # bytes per ms
        refill = np.where(np.isnan(self.last), 0.0, now - self.last)
        tokens = np.minimum(self.depth[None], self.tokens + rate * refill)
        fits = tokens >= sizes
        expired = self.expire[None] & (now + (sizes - tokens) / rate > deadline_ms)
        dropped = capped & ~fits & (self.drop[None] | expired)
        new = np.where(dropped, tokens, tokens - sizes)
        q = np.where(capped & ~fits & ~dropped, -new / rate, 0.0)
        q[dropped] = np.nan
        self.tokens = np.where(capped, new, self.tokens)
        self.last = np.where(capped, now, self.last)
        return q

    def _base(self, kind: int, episodes: np.ndarray, t: int) -> tuple[np.ndarray, np.ndarray]:
        """The seeded draws of tick t's copies of `kind`, [G, N, N] kept and delay (ms),
        computed once per tick and kind (every hidden-state message of a tick reads them)."""
        key = (kind, episodes.tobytes(), t)
        if self._base_key != key:
            links = (self._loss, self._lat, self._jit)  # not rebuilt per call (a hot path)
            n = self.n
            self._base_val = (
                delivery_mask(self.plan, episodes, t, n, kind, links=links, partition=False),
                delay_ms(self.plan, episodes, t, n, kind, self._lat, self._jit))
            self._base_key = key
        return self._base_val

    def deadline_ms(self, kind: int, t: int) -> float:
        """When a copy of `kind` sent at tick t is late (ms from the episode's start)."""
        frac = TRAJ_FRAC if kind == KIND_TRAJ else HIDDEN_FRAC
        return t * self.tick_ms + frac * self.tick_ms

    def decide(self, keep: np.ndarray, delay: np.ndarray, cut: np.ndarray | bool,
               send_ms: np.ndarray | float, queue_ms: np.ndarray | float,
               deadline_ms: float) -> tuple[np.ndarray, np.ndarray]:
        """The fate of copies (and when the ones not lost or cut arrive) from their seeded draws
        (`keep`: not lost, `delay`: latency + jitter), partition cut, send time and the sender's
        queue delay (NaN: dropped by its bandwidth cap); any broadcastable shapes. The one rule
        every delivery uses: the batched evaluator, the world's radio and a robot's direct
        delivery (`swarm.net.direct`) call it on a whole tick, one sender's column or one
        receiver's row, and so decide every copy alike."""
        shape = np.broadcast_shapes(np.shape(keep), np.shape(delay), np.shape(cut),
                                    np.shape(send_ms), np.shape(queue_ms))
        fate = np.zeros(shape, dtype=np.int8)
        arrival = np.broadcast_to(np.asarray(send_ms, dtype=np.float64), shape).copy()
        if self.plan.zero:
            return fate, arrival
        fate[np.broadcast_to(~np.asarray(keep), shape)] = LOST
        fate[np.broadcast_to(cut, shape)] = CUT
        arrival = arrival + queue_ms + delay
        fate[(fate == OK) & np.broadcast_to(np.isnan(queue_ms), shape)] = DROPPED
        fate[(fate == OK) & (arrival > deadline_ms)] = LATE
        return fate, arrival

    def _fates(self, kind: int, episodes: np.ndarray, t: int, senders: np.ndarray,
               sizes: np.ndarray) -> Fates:
        g, n = senders.shape
        now = np.broadcast_to(self.send_ms(t)[None], (g, n))
        q = self._queue(senders, sizes, now, self.deadline_ms(kind, t))
        if self.plan.zero:
            keep, delay = np.ones((g, n, n), dtype=bool), np.zeros((g, n, n))
        else:
            keep, delay = self._base(kind, episodes, t)
        cut = self._cut[None] if self.plan.partition else False
        fate, arrival = self.decide(keep, delay, cut, now[:, None, :], q[:, None, :],
                                    self.deadline_ms(kind, t))
        idx = np.arange(n)
        fate[:, idx, idx] = OK
        return Fates(fate, arrival, senders & (q > 0))

    def charge(self, t: int, sender: int, size: float, kind: int) -> float:
        """Charge one message of `kind` of `sender` (group 0) sent at tick t to its token
        bucket: the ms it waits for tokens (0: none), NaN if the cap drops it. A bucket is its
        sender's own state, so a robot charges its own in direct delivery and stamps its
        messages with it."""
        senders = np.zeros((1, self.n), dtype=bool)
        senders[0, sender] = True
        sizes = np.zeros((1, self.n))
        sizes[0, sender] = size
        return float(self._queue(senders, sizes, self.send_ms(t)[None],
                                 self.deadline_ms(kind, t))[0, sender])

    def _pair(self, kind: int, episode: int, t: int, sel: tuple[object, object],
              cut: np.ndarray | bool, send: np.ndarray | float, queue_ms: np.ndarray | float,
              deadline_ms: float | None = None) -> tuple[np.ndarray, np.ndarray]:
        if self.plan.zero:
            keep, delay = np.ones(self.n, dtype=bool), np.zeros(self.n)
        else:
            k, d = self._base(kind, np.array([episode]), t)
            keep, delay = k[0][sel], d[0][sel]  # type: ignore[index]
        return self.decide(keep, delay, cut if self.plan.partition else False, send, queue_ms,
                           self.deadline_ms(kind, t) if deadline_ms is None else deadline_ms)

    def column(self, kind: int, episode: int, t: int, sender: int,
               queue_ms: float) -> np.ndarray:
        """Fates [N] of `sender`'s message of `kind` at tick t to every receiver, given the ms it
        waited in the sender's bucket (NaN: dropped)."""
        fate = self._pair(kind, episode, t, (slice(None), sender), self._cut[:, sender],
                          float(self.send_ms(t)[sender]), queue_ms)[0]
        fate[sender] = OK
        return fate

    def row(self, kind: int, episode: int, t: int, receiver: int,
            queue_ms: np.ndarray) -> np.ndarray:
        """Fates [N] of every sender's message of `kind` at tick t to `receiver`, given each
        sender's queue delay [N] (NaN: dropped): what a robot decides in direct delivery."""
        fate = self._pair(kind, episode, t, (receiver, slice(None)), self._cut[receiver],
                          self.send_ms(t), np.asarray(queue_ms, dtype=np.float64))[0]
        fate[receiver] = OK
        return fate

    def row_at(self, kind: int, episode: int, t: int, receiver: int, send_ms: np.ndarray,
               queue_ms: np.ndarray, deadline_ms: float) -> tuple[np.ndarray, np.ndarray]:
        """`row` on the wall clock (direct delivery, `--clock real`): fates [N] and arrival
        times [N] (ms) of every sender's message given when each came (`send_ms`, the
        receiver's clock) and the receiver's own deadline; the same draws and the same rule."""
        fate, arrival = self._pair(kind, episode, t, (receiver, slice(None)),
                                   self._cut[receiver], np.asarray(send_ms, dtype=np.float64),
                                   np.asarray(queue_ms, dtype=np.float64), deadline_ms)
        fate[receiver] = OK
        return fate, arrival

    def hidden_from(self, episode: int, t: int, sender: int, size: float
                    ) -> tuple[np.ndarray, float]:
        """Fates [N] of one hidden-state message of `sender` (one group) to every receiver:
        column `sender` of `hidden()` for that sender alone, in O(N) (a swarm's world decides
        each message as it arrives); and the ms it waited for tokens."""
        q = self.charge(t, sender, size, KIND_HIDDEN)
        return self.column(KIND_HIDDEN, episode, t, sender, q), q

    def traj(self, episodes: np.ndarray, t: int, senders: np.ndarray,
             sizes: np.ndarray) -> Fates:
        """Fates of tick t's trajectory copies of `senders` [G, N] with payload `sizes` [G, N];
        range is applied by the caller (it needs the true positions)."""
        return self._fates(KIND_TRAJ, np.asarray(episodes), t, senders, sizes)

    def hidden(self, episodes: np.ndarray, t: int, senders: np.ndarray,
               sizes: np.ndarray) -> Fates:
        """Fates of tick t's hidden-state copies (charged after the same tick's trajectory
        messages: call `traj` first)."""
        return self._fates(KIND_HIDDEN, np.asarray(episodes), t, senders, sizes)
