"""The episodes a learner heard of since its last checkpoint, so that a learner killed between
two updates and resumed counts what it held (never trained on) instead of forgetting it.

One line per episode heard of, `<n> <episode>`, n being the learner's `received` count with
that episode. A line is written to the OS as it is made (line-buffered), so a SIGKILL loses
none; the file is emptied after every checkpoint. On resume, the lines whose n is past the
checkpoint's `received` are the episodes the stopped learner had and lost (`lost` in its
accounting); earlier lines are ones the checkpoint already counts (a kill between the
checkpoint's rename and the emptying). They are left in the file until the next checkpoint,
which counts them: a learner killed again before it makes one finds them again, once."""

from __future__ import annotations

import logging
from pathlib import Path
from typing import TextIO

log = logging.getLogger("swarm.learner")


class Journal:
    def __init__(self, path: Path) -> None:
        self.path = path
        self.file: TextIO | None = None

    def past(self, received: int) -> int:
        """How many episodes the file names past `received` (0 without a file); a line that
        does not parse (not ours, or cut) is skipped and said."""
        try:
            lines = self.path.read_text(errors="replace").splitlines()
        except FileNotFoundError:
            return 0
        past = skipped = 0
        for line in lines:
            head = line.split(" ", 1)[0]
            if not head.isdigit():
                skipped += 1
                continue
            past += int(head) > received
        if skipped:
            log.warning("learner: %d unreadable lines in %s skipped", skipped, self.path)
        return past

    def open(self) -> None:
        self.file = self.path.open("a", buffering=1)

    def heard(self, n: int, ep: int) -> None:
        if self.file is not None:
            self.file.write(f"{n} {ep}\n")

    def clear(self) -> None:
        """After a checkpoint: every line so far is counted there."""
        if self.file is not None:
            self.file.seek(0)
            self.file.truncate()

    def close(self) -> None:
        if self.file is not None:
            self.file.close()
            self.file = None
