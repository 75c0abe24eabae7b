"""The radio channel in virtual time: the fate of every copy of a tick's messages, decided when
it is sent, as a pure function of the fault plan, the seed and the message sizes.

Times are milliseconds from the episode's start. Tick t starts at `t * tick_ms`; robot j sends
its trajectory message, then (chained policies) its hidden-state message, at
`t * tick_ms + compute_ms[j]` (its modelled compute time, `LinkFault.compute_ms`). A copy
j -> i arrives at send + queue + latency + jitter, where the queue is the sender's token bucket
(`bandwidth` bytes/s, `burst` deep, emptied at every episode's start) in virtual time, and the
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

    def _queue(self, senders: np.ndarray, sizes: np.ndarray, now: np.ndarray) -> np.ndarray:
        """Charge the senders' buckets [G, N]; ms each message waits (0 unqueued, NaN dropped)."""
        q = np.zeros(senders.shape)
        if not self.capped:
            return q
        capped = senders & (self.rate > 0)[None]
        rate = np.where(self.rate > 0, self.rate, 1.0)[None] / 1e3  # bytes per ms
        refill = np.where(np.isnan(self.last), 0.0, now - self.last)
        tokens = np.minimum(self.depth[None], self.tokens + rate * refill)
        fits = tokens >= sizes
        dropped = capped & ~fits & self.drop[None]
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

    def _fates(self, kind: int, episodes: np.ndarray, t: int, senders: np.ndarray,
               sizes: np.ndarray, deadline_ms: float) -> Fates:
        g, n = senders.shape
        now = np.broadcast_to(self.send_ms(t)[None], (g, n))
        q = self._queue(senders, sizes, now)
        fate = np.zeros((g, n, n), dtype=np.int8)
        arrival = np.broadcast_to(now[:, None, :], (g, n, n)).copy()
        if not self.plan.zero:
            keep, delay = self._base(kind, episodes, t)
            fate[~keep] = LOST
            if self.plan.partition:
                fate[:, self._cut] = CUT
            arrival = arrival + q[:, None, :] + delay
            fate[(fate == OK) & np.isnan(q)[:, None, :]] = DROPPED
            fate[(fate == OK) & (arrival > deadline_ms)] = LATE
        idx = np.arange(n)
        fate[:, idx, idx] = OK
        return Fates(fate, arrival, senders & (q > 0))

    def hidden_from(self, episode: int, t: int, sender: int, size: float) -> np.ndarray:
        """Fates [N] of one hidden-state message of `sender` (one group) to every receiver:
        column `sender` of `hidden()` for that sender alone, in O(N) (a swarm's world decides
        each message as it arrives)."""
        n = self.n
        senders = np.zeros((1, n), dtype=bool)
        senders[0, sender] = True
        sizes = np.zeros((1, n))
        sizes[0, sender] = size
        now = self.send_ms(t)[None]
        q = float(self._queue(senders, sizes, now)[0, sender])
        fate = np.zeros(n, dtype=np.int8)
        if not self.plan.zero:
            keep, delay = self._base(KIND_HIDDEN, np.array([episode]), t)
            fate[~keep[0, :, sender]] = LOST
            if self.plan.partition:
                fate[self._cut[:, sender]] = CUT
            if np.isnan(q):
                fate[fate == OK] = DROPPED
            else:
                arrival = now[0, sender] + q + delay[0, :, sender]
                deadline = t * self.tick_ms + HIDDEN_FRAC * self.tick_ms
                fate[(fate == OK) & (arrival > deadline)] = LATE
        fate[sender] = OK
        return fate

    def traj(self, episodes: np.ndarray, t: int, senders: np.ndarray,
             sizes: np.ndarray) -> Fates:
        """Fates of tick t's trajectory copies of `senders` [G, N] with payload `sizes` [G, N];
        range is applied by the caller (it needs the true positions)."""
        return self._fates(KIND_TRAJ, np.asarray(episodes), t, senders, sizes,
                           t * self.tick_ms + TRAJ_FRAC * self.tick_ms)

    def hidden(self, episodes: np.ndarray, t: int, senders: np.ndarray,
               sizes: np.ndarray) -> Fates:
        """Fates of tick t's hidden-state copies (charged after the same tick's trajectory
        messages: call `traj` first)."""
        return self._fates(KIND_HIDDEN, np.asarray(episodes), t, senders, sizes,
                           t * self.tick_ms + HIDDEN_FRAC * self.tick_ms)
