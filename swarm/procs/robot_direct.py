"""A robot process in direct delivery (`--delivery direct`): the plumbing between
`swarm.procs.robot.RobotProcess` and `swarm.net.direct.DirectLink`.

The robot's trajectory and hidden-state sends go out stamped on its own `direct` key; what the
robot waited for from the radio (its bundle, its predecessor's hidden state) it now assembles
from its peers' stamped messages, deciding each copy's fate itself. The robot's tick loop is
unchanged: `RobotProcess` calls `inbox`, `begin` and `wait` where it would otherwise
talk to the radio.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Any

import numpy as np
import zenoh

from swarm.net.direct import WAIT_FRAC, DirectLink, live_plan
from swarm.net.faults import plan_from_table
from swarm.net.inbox import Event, Inbox, publisher
from swarm.net.messages import (
    K_HIDDEN,
    K_RSTATUS,
    K_TRAJ,
    BadMessage,
    Bundle,
    Obs,
    Traj,
    pack_record,
    unpack_record,
)
from world.config import ConfigError, WorldConfig
from world.decentral import TrajMessages


@dataclass
class Heard:
    """What robot `robot` heard at tick `t` of episode `ep`, validated: a radio bundle's
    messages, or in direct delivery the peers' messages it kept."""

    ep: int
    t: int
    robot: int
    msgs: TrajMessages
    succ: list[int] | None = None  # the bundle's successors: send them the hidden state directly

    @classmethod
    def of(cls, cfg: WorldConfig, bundle: Bundle) -> Heard:
        """Bundle `bundle` as its robot's policy input, [1, N, ...]; BadMessage unless every one
        is a valid trajectory message of the bundle's tick, from distinct senders, its own among
        them (the radio always hands a robot its own message back)."""
        m = TrajMessages.empty(cfg)
        trajs = Traj.unpack_many(bundle.trajs, cfg, bundle.ep, bundle.t)
        ids = [tr.robot for tr in trajs]
        if bundle.robot not in ids:  # (first: an empty bundle failed numpy's broadcast below)
            raise BadMessage("bundle without the robot's own message")
        m.present[0, ids] = True
        m.pos[0, ids] = [(tr.y, tr.x) for tr in trajs]
        for tr in trajs:
            if tr.recent:
                m.recent[0, tr.robot, cfg.recent_len - len(tr.recent):] = tr.recent
        # every bitmap and patch in one call each (a bundle holds tens of messages)
        packed = np.frombuffer(b"".join(tr.visited for tr in trajs), dtype=np.uint8)
        m.visited[0, ids] = np.unpackbits(packed.reshape(len(ids), -1), axis=1,
                                          count=cfg.cells).astype(bool)
        m.patch[0, ids] = np.frombuffer(b"".join(tr.patch for tr in trajs),
                                        dtype=np.uint8).reshape(len(ids), cfg.vision, cfg.vision)
        return cls(bundle.ep, bundle.t, bundle.robot, m, bundle.succ)


class _StampingPublisher:
    """Stands in for the robot's traj/hidden publisher: the same payload, stamped with its
    sender's bucket, on the robot's direct key."""

    def __init__(self, pub: zenoh.Publisher, link: DirectLink, kind: int) -> None:
        self.pub, self.link, self.kind = pub, link, kind

    def put(self, payload: bytes) -> None:
        self.pub.put(self.link.stamp(self.kind, payload))


class _StatusPublisher:
    """Stands in for the robot's status publisher: the same record plus its direct-delivery
    counters (`DirectLink.record`), which the world sums into the run's result."""

    def __init__(self, pub: zenoh.Publisher, link: DirectLink) -> None:
        self.pub, self.link = pub, link

    def put(self, payload: bytes) -> None:
        rec = unpack_record(payload, K_RSTATUS)
        rec["direct"] = self.link.record()
        self.pub.put(pack_record(K_RSTATUS, rec))


class _DirectInbox(Inbox):
    """The robot's inbox, which hands the events of direct delivery (peers' stamped messages,
    their liveliness) to the link and returns only the others to the robot; during a direct
    wait it returns None after each such event, so the wait can look at what it has."""

    def __init__(self, session: zenoh.Session, delivery: DirectDelivery) -> None:
        super().__init__(session)
        self.delivery = delivery

    def next(self, timeout: float) -> Event | None:
        end = time.monotonic() + min(timeout, 3600.0) if timeout > 0 else 0.0
        while True:
            ev = super().next(end - time.monotonic())
            if ev is None or not self.delivery.take(*ev):
                return ev
            if self.delivery.waiting:
                return None


def with_delivery(proc: Any, faults: dict[str, Any]) -> Any:
    """`proc` with direct delivery attached when its run asks for it (`RunConfig.delivery`)."""
    if proc.run_cfg.delivery == "direct":
        proc.direct = DirectDelivery(proc, faults)
    return proc


class DirectDelivery:
    """Direct delivery for robot process `proc`, with the run's `[faults]` table."""

    def __init__(self, proc: Any, faults: dict[str, Any]) -> None:
        self.proc = proc
        cfg, run = proc.cfg, proc.run_cfg
        plan = plan_from_table(faults, run.seed, cfg.n_robots)
        self.link = DirectLink(cfg, proc.robot, plan, run.tick_timeout, real=run.clock == "real")
        for old in (proc.traj_pub, proc.hid_pub):
            old.undeclare()
        k, r, s = proc.keys, proc.robot, proc.session
        proc.traj_pub = _StampingPublisher(publisher(s, k.direct(r)), self.link, K_TRAJ)
        proc.hid_pub = _StampingPublisher(publisher(s, k.direct(r, hidden=True), express=True),
                                          self.link, K_HIDDEN)
        proc.status_pub = _StatusPublisher(proc.status_pub, self.link)  # type: ignore[assignment]
        self.t_begin = 0.0
        self.budget_s = 0.0
        self.waiting = False  # in `wait`: the inbox returns after each direct-delivery event

    def inbox(self) -> Inbox:
        """The robot's inbox, subscribed to every peer's stamped trajectory messages, to the
        hidden states of the robots that can be its predecessor (lower ids), and to the peers'
        liveliness (a gone peer is not waited for)."""
        k, r = self.proc.keys, self.proc.robot
        inbox = _DirectInbox(self.proc.session, self).subscribe(k.direct("*"), "direct", True)
        for j in range(r):
            inbox.subscribe(k.direct(j, hidden=True), "direct", True)
        return inbox.liveliness(k.alive_robot("*"), "peer")

    def begin(self, obs: Obs) -> None:
        """An observation: a new tick to deliver (or an episode's end, reported at once so the
        world can sum every robot's counters)."""
        if obs.faults:  # a live change from this tick on (the world's radio switches with it;
            try:          # an episode's last observation may carry it too)
                self.link.set_plan(live_plan(obs.faults, self.proc.run_cfg.seed,
                                             self.proc.cfg.n_robots))
            except ConfigError as exc:
                self.proc._bad(self.proc.keys.obs(self.proc.robot), f"live faults: {exc}")
        if obs.done:
            self.link.done_ep = max(self.link.done_ep, obs.ep)
            self.proc.status()
            return
        self.link.begin(obs)
        self.t_begin, self.budget_s = time.monotonic(), obs.budget_ms / 1e3
        if not self.link.sees_peers():  # (at a run's start, or after a peer's restart)
            self.waiting, limit = True, self.t_begin + WAIT_FRAC * self.budget_s
            try:
                while not self.link.sees_peers() and time.monotonic() < limit and \
                        self._pump(limit) is not None:
                    pass
            finally:
                self.waiting = False

    def take(self, kind: str, key: str, payload: bytes | None) -> bool:
        """Handle an event of direct delivery (True), or leave it to the robot (False)."""
        if kind == "direct":
            self.proc.c.msgs_in += 1
            self.proc.c.bytes_in += len(payload or b"")
            try:
                self.link.offer(key, payload or b"")
            except (BadMessage, ValueError) as exc:
                self.proc._bad(key, str(exc))
            return True
        if kind in ("peer:live", "peer:dead"):
            self.link.peer(key, kind == "peer:live")
            return True
        return False

    def wait(self, kind: str, ep: int, t: int, sender: int | None, deadline: float) -> Any:
        """`RobotProcess._wait` in direct delivery: the tick's heard messages (`Heard`) once every
        live robot's trajectory message is in (or WAIT_FRAC of the budget passed), or the
        predecessor's hidden state (a miss marker when its fate is known to be a miss); None
        when an observation or the world's end cuts the wait short, or at `deadline`."""
        self.waiting = True
        try:
            return self._wait(kind, ep, t, sender, deadline)
        finally:
            self.waiting = False

    def _wait(self, kind: str, ep: int, t: int, sender: int | None, deadline: float) -> Any:
        proc, link = self.proc, self.link
        if kind == "bundle":
            limit = min(deadline, self.t_begin + WAIT_FRAC * self.budget_s)
            while not link.traj_complete() and time.monotonic() < limit:
                if self._pump(limit) is None:
                    return None
            payloads = link.heard()  # complete, or time is up: the messages that came
            while link.real and time.monotonic() < min(link.due, deadline):  # real clock: they
                if self._pump(min(link.due, deadline)) is None:  # are its once they arrive
                    return None
            try:
                return Heard.of(proc.cfg, Bundle(ep, t, proc.robot, payloads))
            except BadMessage as exc:
                proc._bad(proc.keys.direct("*"), str(exc))
                return None
        assert sender is not None
        while True:
            link.wake_at = math.inf
            h = link.hidden(sender)
            if h is not None:
                return h
            if time.monotonic() >= deadline or self._pump(min(deadline, link.wake_at)) is None:
                return None

    def _pump(self, deadline: float) -> bool | None:
        """Take events until one arrives or `deadline` (False: none for the robot); None when
        the wait must end (a new observation came, the world is gone, the run ended)."""
        item = self.proc._next(deadline)
        if item is None:
            return False
        k, msg = item
        if k == "obs":
            self.proc._pending_obs = msg
            return None
        return None if k in ("wdead", "end") else True
