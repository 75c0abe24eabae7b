"""What a robot process reports: its counters (the result and the status record) and the
attention of its last decision (CommAttn robots, drawn live on the dashboard); and what it
accepts: the run's record (`fetch_config`), the ticks its messages may name (`TickGuard`) and
how long it waits for its predecessor's hidden-state message (`hop_deadline`)."""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
import zenoh

from policies.base import Policy
from swarm.net.inbox import Inbox, check_free, query
from swarm.net.keys import Keys
from swarm.net.messages import BadMessage
from swarm.procs.runconfig import RunRecord
from world.config import ConfigError


class WorldLeft(RuntimeError):
    """The world's token stayed gone before the run's end: this robot gave up on the run."""


@dataclass
class RobotCounters:
    msgs_in: int = 0
    msgs_out: int = 0
    bytes_in: int = 0
    bytes_out: int = 0
    bad: int = 0
    stale: int = 0
    missed: int = 0  # ticks it could not act on (no bundle in time)
    missed_hidden: int = 0  # predecessor's hidden-state message lost or late: decoded without
    last_latency_ms: float = 0.0
    weights_bad: int = 0  # weights messages rejected (wrong policy, shape or version)
    weights_late: int = 0  # train_sync episodes begun without the version the world named
    rollouts_lost: int = 0  # episode records dropped by the injected rollout loss
    stalls: int = 0  # times this process was stopped or starved (robot.STALL_S)
    rejoins: int = 0  # times the world's token came back after vanishing (session drop)
    errors: int = 0  # ticks it could not decide on (an exception in the policy), skipped
    decisions: int = 0
    compute_ms: float = 0.0  # planning time of its decisions, summed (waits excluded)
    wait_ms: float = 0.0  # time spent waiting for bundles and predecessors, summed
    bad_by_key: dict[str, int] = field(default_factory=dict)

    def record(self, robot: int, ep: int, final: bool, version: int,
               dropped: dict[str, int]) -> dict[str, object]:
        """The robot status record of these counters (`dropped`: what its inbox dropped)."""
        return {"robot": robot, "ep": ep, "final": final, "msgs_in": self.msgs_in,
                "msgs_out": self.msgs_out, "bytes_in": self.bytes_in,
                "bytes_out": self.bytes_out, "bad": self.bad, "stale": self.stale,
                "missed": self.missed, "missed_hidden": self.missed_hidden,
                "latency_ms": self.last_latency_ms, "version": version,
                "weights_bad": self.weights_bad, "weights_late": self.weights_late,
                "rollouts_lost": self.rollouts_lost, "stalls": self.stalls,
                "rejoins": self.rejoins, "errors": self.errors,
                "compute_ms": self.compute_ms / max(self.decisions, 1),
                "wait_ms": self.wait_ms / max(self.decisions, 1), **dropped}


def attention_of(policy: Policy, robot: int, n: int, t: int) -> tuple[int, list[float]] | None:
    """(t, this robot's attention weights over the team) from the policy's `last_attention`
    (CommAttn: [N] or [G, N, N] weights over the members heard, zero elsewhere), for the robot
    status record; None for a policy without attention or weights that do not fit."""
    att = getattr(policy, "last_attention", None)
    if att is None:
        return None
    w = np.asarray(att, dtype=np.float64)
    if w.ndim == 3:
        w = w[0]
    if w.ndim == 2:
        w = w[robot] if w.shape[0] == n else w[0]
    if w.shape != (n,) or not np.isfinite(w).all():
        return None
    return t, [float(x) for x in w]


class TickGuard:
    """The ticks a robot accepts messages of: this run's episodes and horizon; observations
    only after the last one acted on and, in the same episode, no farther from its position
    than one move a tick; bundles and hidden states at most `ahead` ticks past it (each is kept
    until its tick: one far ahead would be kept for ever). BadMessage otherwise."""

    def __init__(self, horizon: int, first_episode: int, episodes: int) -> None:
        self.horizon, self.first, self.episodes = horizon, first_episode, episodes
        self.last: tuple[int, int, int, int] | None = None  # (ep, t, y, x) acted on last
        # the one acted on before `last` when `last` skipped ticks ahead (a robot that was
        # stopped, or not sent any while the world counted it gone); None after a step of one
        self.before_skip: tuple[int, int, int, int] | None = None

    def steps(self, frm: tuple[int, ...], ep: int, t: int) -> int:
        """World ticks from observation `frm` (ep, t, ...) to (ep, t): an episode's last
        observation is its tick `horizon` (done), the next episode's first its tick 0."""
        return (ep - frm[0]) * (self.horizon + 1) + t - frm[1]

    def obs(self, ep: int, t: int, y: int, x: int) -> None:
        """An observation is acted on only after the last one, within reach of its position;
        or, right after a skip ahead, if it is the world's next after the one before the skip
        (the skip was a forged observation: without this, one far ahead silenced the robot
        for the rest of the run, each real one after it refused as old)."""
        self.tick(ep, t, ahead=None)
        last, before = self.last, self.before_skip
        if last is not None and (ep, t) <= last[:2]:
            if before is None or self.steps(before, ep, t) != 1:
                raise BadMessage(f"observation of ep {ep} tick {t} after tick {last[1]} of "
                                 f"ep {last[0]}")
            last = before  # (then checked for reach from it, as any next observation)
        if last is not None and ep == last[0] and max(abs(y - last[2]), abs(x - last[3])) > \
                t - last[1]:
            raise BadMessage(f"position ({y}, {x}) out of reach of ({last[2]}, {last[3]}) in "
                             f"{t - last[1]} tick(s)")
        self.before_skip = last if last is not None and self.steps(last, ep, t) > 1 else None
        self.last = (ep, t, y, x)

    def tick(self, ep: int, t: int, ahead: int | None = 1) -> None:
        if not self.first <= ep < self.first + self.episodes:
            raise BadMessage(f"episode {ep} is not one of this run's")
        if t > self.horizon:
            raise BadMessage(f"tick {t} past the horizon {self.horizon}")
        last = self.last
        if ahead is not None and last is not None and self.steps(last, ep, t) > ahead:
            raise BadMessage(f"ep {ep} tick {t} is ahead of the observed ep {last[0]} tick "
                             f"{last[1]}")


def count_after_end(inbox: Inbox, c: RobotCounters, seconds: float = 0.1) -> None:
    """Count what reaches the robot within `seconds` after the run's end record: Zenoh calls
    each subscription's callback on a thread of its own, so what the world sent before its end
    (the last tick's observation) can come just after it, and the final counts (`msgs_in`)
    depended on that race."""
    end = time.monotonic() + seconds
    while (ev := inbox.next(end - time.monotonic())) is not None:
        if ev[0] not in ("end", "world:live", "world:dead"):
            c.msgs_in += 1
            c.bytes_in += len(ev[2] or b"")


def hop_deadline(t_recv: float, deadline: float, robot: int, n: int,
                 floor: float = 0.0) -> float:
    """How long robot `robot` waits for its predecessor's hidden-state message: until its slot,
    (robot + 1) / n of the way to the tick deadline.

    Ids along a chain strictly decrease, so a predecessor j < robot gives up on its own
    predecessor at its earlier slot and its message (late only by its decode and one hop) still
    reaches `robot` before this one. A lost message therefore costs one slot of waiting and
    breaks one link, never the whole budget of every robot downstream (the deadline cascade of
    waiting until the tick deadline, see docs/DECISIONS.md).

    `floor`: the slots spread over the rest of the way from that share on, `floor + (1 -
    floor) * (robot + 1) / n` (the virtual clock's 0.5: there a lost or late message is said at
    once, `Hidden.miss`, so a slot runs out only on a stalled predecessor, and an early robot's
    2/N of the watchdog let a stall of a second or two change its decision with no timeout
    counted). Still one slot apart: a floor shared by the early robots (max(share, floor))
    broke every link up to the middle of the chain behind one stalled robot."""
    share = floor + (1.0 - floor) * (robot + 1) / max(n, 1)
    return t_recv + (deadline - t_recv) * share


def fetch_config(session: zenoh.Session, keys: Keys, timeout: float) -> RunRecord:
    """Ask the world for the run's record, retrying until `timeout`."""
    return query(session, keys.config, timeout,
                 lambda b: RunRecord.unpack(b, f"run record from {keys.config}"),
                 f"world answered on {keys.config}")


CLAIM_SETTLE_S = 1.0
"""How long after its session opened a robot started by hand still asks whether its id is taken:
a peer reaches the robot holding the id only once gossip has linked them (`check_free`)."""


def join_run(session: zenoh.Session, keys: Keys, robot: int, wait_world: float,
             settle: float) -> RunRecord:
    """The run's record, once robot id `robot` is known to be in its range and free (one-line
    ConfigError otherwise), asking until `settle` s after the call (`check_free`): call it right
    after the session opened."""
    opened = time.monotonic()
    rec = fetch_config(session, keys, wait_world)
    if not 0 <= robot < rec.world.n_robots:
        raise ConfigError(f"robot id {robot} outside 0..{rec.world.n_robots - 1} of run "
                          f"{keys.run}")
    check_free(session, keys.alive_robot(robot), f"robot {robot} of run {keys.run}",
               since=opened, settle=settle)
    return rec
