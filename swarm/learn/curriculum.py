"""The exploration-ratio-based curriculum of the paper (section 4.3)."""

from __future__ import annotations

from dataclasses import dataclass

from swarm.learn.config import TrainConfig
from world.config import WorldConfig, replace


@dataclass
class Curriculum:
    """Exploration-ratio-based curriculum (paper 4.3): dynamic blocks are introduced in levels.

    Level k trains with min(k * step, n_dynamic) dynamic blocks (same add_every). After each
    update the running mean elratio is ema <- c ema + (1 - c) mean(batch elratio) (reset when a
    level starts); the level advances once it has run `min_updates` and ema >= threshold, or
    after `max_updates` regardless, until the world's own n_dynamic is reached.
    """

    level: int = 0
    updates_at_level: int = 0
    ema: float | None = None

    def world(self, world: WorldConfig, cfg: TrainConfig) -> WorldConfig:
        if cfg.curriculum_step <= 0 or not world.dynamic:
            return world
        return replace(world, n_dynamic=min(self.level * cfg.curriculum_step, world.n_dynamic))

    def observe(self, elratio: float, world: WorldConfig, cfg: TrainConfig) -> bool:
        """Record one update's mean elratio; True when the level advanced."""
        c = cfg.curriculum_ema
        self.ema = elratio if self.ema is None else c * self.ema + (1 - c) * elratio
        self.updates_at_level += 1
        if self.world(world, cfg).n_dynamic >= world.n_dynamic or cfg.curriculum_step <= 0:
            return False
        ready = (self.updates_at_level >= cfg.curriculum_min_updates
                 and self.ema >= cfg.curriculum_threshold)
        forced = 0 < cfg.curriculum_max_updates <= self.updates_at_level
        if ready or forced:
            self.level, self.updates_at_level, self.ema = self.level + 1, 0, None
            return True
        return False

