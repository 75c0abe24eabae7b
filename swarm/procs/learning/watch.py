"""What a learner knows of its run's world (`RunWatch`): once the world's token comes up, the
run's record is fetched from it (as the robots do) and held against the learner's own world,
policy and seed, since episodes of another world or seed cannot be joined (`check_run`: one
line, exit 2, instead of a warning per episode and a lockstep world waiting on it); and the
run's end, at the world's `end` record or when its token has been gone for `GONE_S` (as the
recorder ends). A learner that never sees a world (rollout workers only) runs until stopped."""

from __future__ import annotations

import dataclasses
import logging
import time

import zenoh

from swarm.net.inbox import Event, query
from swarm.net.keys import WORLD_GONE_S as GONE_S
from swarm.net.keys import Keys
from swarm.net.messages import K_RESULT, BadMessage, unpack_record
from swarm.procs.runconfig import RunRecord
from world.config import ConfigError, WorldConfig

log = logging.getLogger("swarm.learner")
ASK_S = 5.0  # how long the world's record is asked for once its token is up


def check_run(rec: RunRecord, cfg: WorldConfig, policy: str, seed: int) -> None:
    """ConfigError naming every difference between run `rec` and a learner of world `cfg`,
    `policy` and `seed` (and a run that does not train)."""
    diff = [f"{f.name} {getattr(cfg, f.name)!r} here, {getattr(rec.world, f.name)!r} in the run"
            for f in dataclasses.fields(WorldConfig)
            if getattr(cfg, f.name) != getattr(rec.world, f.name)]
    if policy != rec.run.policy:
        diff.append(f"policy {policy} here, {rec.run.policy} in the run")
    if seed != rec.run.seed:
        diff.append(f"seed {seed} here, {rec.run.seed} in the run")
    if diff:
        raise ConfigError(f"this learner does not fit run {rec.run.run_id}: {'; '.join(diff)} "
                          "(give the run's world flags or --config, --policy and --seed)")
    if not rec.run.train:
        raise ConfigError(f"run {rec.run.run_id} does not train (its world needs --train or "
                          "[run] train = true): no episode would reach this learner")


class RunWatch:
    """Feed it the learner's `world:*` and `end` events (`see`); `ended` says why the run is
    over ("" while it is not)."""

    def __init__(self, session: zenoh.Session, keys: Keys, cfg: WorldConfig, policy: str,
                 seed: int) -> None:
        self.session, self.keys = session, keys
        self.cfg, self.policy, self.seed = cfg, policy, seed
        self.checked = False
        self.gone_since: float | None = None
        self.seen = False
        self.why = ""

    def see(self, ev: Event) -> bool:
        """Take `ev` if it is the world's (True), else leave it to the learner (False)."""
        if ev.kind == "end":
            try:
                rec = unpack_record(ev.payload or b"", K_RESULT)
            except BadMessage:
                return True
            if rec.get("run_id") == self.keys.run:
                self.why = "the world's end record"
        elif ev.kind == "world:live":
            self.seen, self.gone_since = True, None
            if not self.checked:
                self._check()
        elif ev.kind == "world:dead":
            if self.seen and self.gone_since is None:
                self.gone_since = time.monotonic()
        else:
            return False
        return True

    @property
    def ended(self) -> str:
        if not self.why and self.gone_since is not None and \
                time.monotonic() - self.gone_since >= GONE_S:
            self.why = f"the world's token gone for {GONE_S:g} s"
        return self.why

    def _check(self) -> None:
        self.checked = True
        what = f"run record from {self.keys.config}"
        try:
            rec = query(self.session, self.keys.config, ASK_S,
                        lambda b: RunRecord.unpack(b, what), what)
        except TimeoutError as exc:  # (a world stalled, or gone again: nothing to hold)
            log.warning("learner could not check the run's world: %s", exc)
            return
        check_run(rec, self.cfg, self.policy, self.seed)
