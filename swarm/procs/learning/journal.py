"""The episodes a learner heard of since its last checkpoint, so that a learner killed between two
updates and resumed counts what it held (never trained on) instead of forgetting it.

One line per episode heard of, `<n> s<episode>` (a swarm episode) or `<n> w<episode>` (a rollout
worker's), n being the learner's `received` count with that episode. A line is written to the OS
as it is made (line-buffered), so a SIGKILL loses none; the file is emptied after every
checkpoint, which itself holds how many episodes it had heard of and not yet settled (`pending`:
joining, or waiting for a batch). On resume, those and the lines whose n is past the
checkpoint's `received` are the episodes the stopped learner had and lost (`lost` in its
accounting); earlier lines are ones the checkpoint already counts (a kill between the
checkpoint's rename and the emptying). They are left in the file until the next checkpoint,
which counts them: a learner killed again before it makes one finds them again, once. The
highest swarm episode named tells a resumed learner which episodes its stopped self had heard
of, so a late record of one is late, not a new episode. Only a resumed learner reads the file; a
fresh one starts it again."""

from __future__ import annotations

import logging
from pathlib import Path
from typing import TextIO

from world.config import ConfigError

log = logging.getLogger("swarm.learner")


class Journal:
    def __init__(self, path: Path) -> None:
        self.path = path
        self.file: TextIO | None = None

    def past(self, received: int) -> tuple[int, int]:
        """How many episodes the file names past `received` (0 without a file), and the highest
        swarm episode it names (-1: none); a line that does not parse (not ours, or cut) is
        skipped and said."""
        try:
            lines = self.path.read_text(errors="replace").splitlines()
        except FileNotFoundError:
            return 0, -1
        except OSError as exc:  # (a folder of its name, no permission: one line, no traceback)
            raise ConfigError(f"{self.path} cannot be read: {exc.strerror or exc}") from None
        past: set[int] = set()  # (a line written twice is one episode)
        skipped, top = 0, -1
        for line in lines:
            head, _, tail = line.partition(" ")
            if not (head.isascii() and head.isdigit() and len(head) < 19):
                skipped += 1
                continue
            if int(head) > received:
                past.add(int(head))
            ep = tail[1:].strip()
            if tail[:1] == "s" and ep.isascii() and ep.isdigit() and len(ep) < 19:
                top = max(top, int(ep))
        if skipped:
            log.warning("learner: %d unreadable lines in %s skipped", skipped, self.path)
        return len(past), top

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

    def heard(self, n: int, ep: int, swarm: bool) -> None:
        if self.file is not None:
            self.file.write(f"{n} {'s' if swarm else 'w'}{ep}\n")

    def clear(self) -> None:
        """After a checkpoint: every line so far is counted there."""
        if self.file is not None:
            self.file.seek(0)
            self.file.truncate()

    def close(self) -> None:
        if self.file is not None:
            self.file.close()
            self.file = None
