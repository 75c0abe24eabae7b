"""A rollout worker: batched episodes with the learner's current weights, published to it.

`swarm rollout-worker --run-id R --connect tcp/HOST:PORT --worker-id K` asks the learner for the
run's configuration and current weights, then loops: collect `batch` episodes with sampled
actions (the batched trainer's `collect`, one process, `threads` torch threads), put each as an
`EpisodeRollout` on `worker/<K>/episodes`, adopt any newer weights between batches. Worker K plays
episodes of its own seed (the train offset + run seed + K + 1, never an evaluation seed), so
workers on several hosts never repeat each other's episodes; restarted, it goes on after the last
episode its learner heard from it (`RunRecord.workers`), so it does not repeat its own either.
It exits after `max_batches` (0: never) or on Ctrl-C, with the same summary either way; while
the learner is gone it goes on with its last weights (what it sends meanwhile is lost, as on any
pub/sub link without a subscriber), and whenever a learner's token comes up (the first, the same
one back, or a fresh one replacing it) it asks for its weights.
"""

from __future__ import annotations

import logging
import time
from typing import Any

import numpy as np
import torch

from policies import policy_class
from swarm.common.spawn import supervised
from swarm.learn.config import TrainConfig, check_worker
from swarm.learn.join import episodes_of
from swarm.learn.rollout import collect
from swarm.learn.weights import adopt
from swarm.net.inbox import Event, Inbox, check_free, publisher, query, replies
from swarm.net.keys import Keys
from swarm.net.learning import Weights
from swarm.net.messages import BIG, BadMessage
from swarm.net.zconfig import ZenohOptions, open_session
from swarm.procs.robot_status import CLAIM_SETTLE_S
from swarm.procs.runconfig import RunRecord
from world.config import ConfigError, from_dict

log = logging.getLogger("swarm.worker")


def batch_episodes(worker: int, first: int, batches: int, batch: int) -> np.ndarray:
    """The episodes of a worker's next batch, from `first` (where its learner has it); a
    ConfigError (one line) once they would pass BIG, the highest a learner takes: a worker whose
    learner served a next episode near it would otherwise send batch after batch of episodes
    every learner drops."""
    start = first + batches * batch
    if start + batch - 1 > BIG:
        raise ConfigError(f"rollout worker {worker}: its next episodes ({start}..) pass {BIG}, "
                          "the highest a learner takes (its learner's record says it is at "
                          f"episode {first}); start it with another --worker-id")
    return start + np.arange(batch)


def main(run_id: str, zopts: ZenohOptions, worker_id: int = 0, batch: int = 16,
         threads: int = 1, max_batches: int = 0, wait: float = 30.0) -> dict[str, Any]:
    check_worker(worker_id, batch, threads, max_batches, wait)
    keys = Keys(run_id)
    torch.set_num_threads(threads)
    with open_session(zopts, wait) as session:
        opened = time.monotonic()
        rec = query(session, keys.learner_config, wait,
                    lambda b: RunRecord.unpack(b, "the learner's run record"),
                    f"learner answered on {keys.learner_config}")
        cfg = rec.world
        if rec.train is None or rec.model is None:
            raise ConfigError("the learner's run record has no train or model table")
        tc = from_dict(TrainConfig, rec.train, "learner train")
        cls = policy_class(rec.run.policy)
        policy = cls(cfg, model=from_dict(cls.config_cls, rec.model, "learner model"))
        # two workers of one id would play the same episodes (their seeds follow the id)
        check_free(session, keys.alive_worker(worker_id),
                   f"rollout worker {worker_id} of run {run_id}", since=opened,
                   settle=0.0 if supervised() else CLAIM_SETTLE_S)
        inbox = Inbox(session).subscribe(keys.weights, "w").liveliness(
            keys.alive_learner, "learner").token(keys.alive_worker(worker_id))
        pub = publisher(session, keys.worker_episodes(worker_id))
        version, origin, sent, bad, batches, sent_bytes = -1, -1, 0, 0, 0, 0
        seed = tc.train_seed_offset + tc.seed + worker_id + 1
        first = (rec.workers or {}).get(worker_id, 0)  # restarted: where the learner has it
        if first:
            log.warning("worker %d: the learner heard its episodes up to %d; going on from "
                        "there", worker_id, first - 1)
        t0, interrupted = time.monotonic(), False
        try:
            while max_batches <= 0 or batches < max_batches:
                while (ev := inbox.next(0)) is not None:  # adopt the newest weights between batches
                    kind, payload = ev.kind, ev.payload
                    if kind == "learner:dead":  # keep going on the last weights; it may come back
                        log.warning("worker %d: learner gone", worker_id)
                    elif kind == "learner:live":  # the first, or one that replaced it: its
                        # weights went out before this worker could hear them, so ask
                        for reply in replies(session, keys.weights, 2.0):
                            inbox.q.put(Event("w", keys.weights, reply))
                    elif kind == "w":
                        try:
                            w = Weights.unpack(payload or b"")
                            if w.newer_than(version, origin):  # (or another learner's)
                                adopt(policy, w)
                                version, origin = w.version, w.origin
                        except (BadMessage, ValueError) as exc:  # (numpy's, should a check miss)
                            bad += 1
                            log.warning("worker %d rejected weights: %s", worker_id, exc)
                if version < 0:
                    time.sleep(0.05)
                    if time.monotonic() - t0 > wait:
                        raise TimeoutError("no weights from the learner")
                    continue
                episodes = batch_episodes(worker_id, first, batches, batch)
                roll = collect(policy, cfg, seed, episodes)
                for er in episodes_of(roll, version):
                    payload = er.pack()
                    pub.put(payload)
                    sent += 1
                    sent_bytes += len(payload)
                batches += 1
        except KeyboardInterrupt:  # Ctrl-C: its usual end without --max-batches
            if version < 0:  # (nothing done yet: an interrupted start)
                raise
            interrupted = True
        finally:
            inbox.close()
        wall = time.monotonic() - t0
        return {"worker": worker_id, "first_episode": first, "episodes": sent,
                "batches": batches, "bytes": sent_bytes,
                "weights_bad": bad, "version": version, "episodes_per_s": sent / max(wall, 1e-9),
                "interrupted": interrupted}
