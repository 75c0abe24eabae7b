"""The radio layer: owns delivery of robot-to-robot messages (SPEC section 5).

It knows the true positions, as an emulator's channel model does, and hands each receiver its
tick's trajectory messages as one bundle (the senders within `comm_range`, itself included), so
no robot waits on a timer when nothing is lost. Hidden-state messages are forwarded only to the
robots whose predecessor p(i) sent them. The neighbourhood and predecessor come from
world.decentral, the same functions the batched evaluator uses.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from world.config import WorldConfig
from world.decentral import neighbourhood, predecessor


@dataclass
class RadioCounters:
    """Per-run message counters, reported in the run's result."""

    traj_in: int = 0
    traj_delivered: int = 0  # (sender, receiver) deliveries
    hidden_in: int = 0
    hidden_delivered: int = 0
    late: int = 0  # arrived after their tick's deadline; never used
    out_of_range: int = 0  # (sender, receiver) pairs the range limit cut
    bytes_in: int = 0
    bytes_out: int = 0
    per_link_delivered: dict[tuple[int, int], int] = field(default_factory=dict)


class Radio:
    """Range-limited delivery for one tick at a time."""

    def __init__(self, cfg: WorldConfig) -> None:
        self.cfg = cfg
        self.counters = RadioCounters()
        self.hears = np.zeros((cfg.n_robots, cfg.n_robots), dtype=bool)
        self.pred = np.full(cfg.n_robots, -1, dtype=np.int64)

    def bundles(self, positions: np.ndarray, senders: dict[int, bytes]) -> dict[int, list[bytes]]:
        """Receiver -> payloads it hears, in sender-id order.

        `positions` [N, 2] are the true (y, x) at this tick; `senders` maps robot id -> its
        validated trajectory payload (robots that did not send are not heard by anyone).
        """
        n = self.cfg.n_robots
        present = np.zeros(n, dtype=bool)
        present[list(senders)] = True
        hears = neighbourhood(self.cfg.comm_range, positions[None], present[None])[0]
        self.hears = hears
        self.pred = predecessor(hears[None])[0]
        c = self.counters
        c.out_of_range += int(present.sum() ** 2 - hears.sum())
        out: dict[int, list[bytes]] = {}
        for i in senders:
            heard = [senders[j] for j in np.flatnonzero(hears[i])]
            out[i] = heard
            c.traj_delivered += len(heard)
            c.bytes_out += sum(len(p) for p in heard)
        return out

    def hidden_receivers(self, sender: int) -> list[int]:
        """The robots whose predecessor this tick is `sender`."""
        return [int(i) for i in np.flatnonzero(self.pred == sender)]
