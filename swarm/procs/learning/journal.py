"""The episodes a learner heard of since its last checkpoint, so that a learner killed between two
updates and resumed counts what it held (never trained on) instead of forgetting it.

One line per episode heard of, `<n> s<episode>` (a swarm episode) or `<n> w<worker>:<episode>` (a
rollout worker's), n being the learner's `received` count with that episode. A line is written to
the OS as it is made (line-buffered), so a SIGKILL loses none; the file is emptied after every
checkpoint, which itself holds how many episodes it had heard of and not yet settled (`pending`:
joining, or waiting for a batch). On resume, those and the lines whose n is past the
checkpoint's `received` are the episodes the stopped learner had and lost (`lost` in its
accounting); earlier lines are ones the checkpoint already counts (a kill between the
checkpoint's rename and the emptying). They are left in the file until the next checkpoint,
which counts them: a learner killed again before it makes one finds them again, once. The
episodes named are settled for the resumed learner: a late record of a swarm episode is late,
not a new episode, and a restarted worker goes on after its last one. Only a resumed learner
reads the file; a fresh one starts it again."""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from pathlib import Path
from typing import TextIO

from swarm.learn.config import MAX_WORKER_ID
from swarm.net.messages import BIG
from world.config import ConfigError

log = logging.getLogger("swarm.learner")


@dataclass
class Past:
    """What a journal names (`Journal.past`)."""

    count: int = 0  # episodes past the checkpoint's `received`
    swarm: set[int] = field(default_factory=set)  # every swarm episode named
    workers: dict[int, int] = field(default_factory=dict)  # worker id -> its last episode named


def _count(text: str) -> bool:
    """A non-negative decimal integer that fits 64 bits."""
    return text.isascii() and text.isdigit() and len(text) < 19


class Journal:
    def __init__(self, path: Path) -> None:
        self.path = path
        self.file: TextIO | None = None

    def past(self, received: int) -> Past:
        """What the file names (nothing without a file): how many episodes past `received`, and
        every swarm episode and each worker's last episode; a line that does not parse (not
        ours, or cut) is skipped and said."""
        out = Past()
        try:
            lines = self.path.read_text(errors="replace").splitlines()
        except FileNotFoundError:
            return out
        except OSError as exc:  # (a folder of its name, no permission: one line, no traceback)
            raise ConfigError(f"{self.path} cannot be read: {exc.strerror or exc}") from None
        past: set[int] = set()  # (a line written twice is one episode)
        skipped = 0
        for line in lines:
            head, _, tail = line.partition(" ")
            if not _count(head):
                skipped += 1
                continue
            if int(head) > received:
                past.add(int(head))
            worker, colon, ep = tail[1:].strip().partition(":")
            if tail[:1] == "s" and not colon and _count(worker) and int(worker) <= BIG:
                out.swarm.add(int(worker))
            elif tail[:1] == "w" and colon and _count(worker) and _count(ep) and \
                    int(worker) <= MAX_WORKER_ID and int(ep) <= BIG:
                w = int(worker)
                out.workers[w] = max(out.workers.get(w, -1), int(ep))
        if skipped:
            log.warning("learner: %d unreadable lines in %s skipped", skipped, self.path)
        out.count = len(past)
        return out

    def open(self, fresh: bool) -> None:
        """Append (resumed), or start the file again (`fresh`: an earlier learner's lines, one
        that never made a checkpoint, are no episodes of this one; said when there were any)."""
        if fresh and self.path.is_file() and self.path.stat().st_size:
            log.warning("learner: %s of an earlier learner (no checkpoint to resume) started "
                        "again", self.path)
        try:
            self.file = self.path.open("w" if fresh else "a", buffering=1)
        except OSError as exc:
            raise ConfigError(f"{self.path} cannot be written: {exc.strerror or exc}") from None

    def heard(self, n: int, ep: int, worker: int | None = None) -> None:
        """Episode `ep`, the learner's `n`th: a swarm episode, or worker `worker`'s."""
        if self.file is not None:
            self.file.write(f"{n} s{ep}\n" if worker is None else f"{n} w{worker}:{ep}\n")

    def clear(self) -> None:
        """After a checkpoint: every line so far is counted there."""
        if self.file is not None:
            self.file.seek(0)
            self.file.truncate()

    def close(self) -> None:
        if self.file is not None:
            self.file.close()
            self.file = None
