"""Configuration of one distributed run, shared by the world, robot and supervisor processes."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class RunConfig:
    """What a swarm run does; the world serves it (with the world config) to every robot."""

    run_id: str = "run"
    """Namespaces every key: `swarm/<run_id>/...`."""
    policy: str = "nearest-frontier"
    """Registry name of the policy every robot runs."""
    checkpoint: str | None = None
    """Checkpoint file of a learned policy (a path the robots can read)."""
    seed: int = 0
    """Episode seed: episode e of the run is episode e of `swarm eval --seed`."""
    episodes: int = 5
    """Episodes to run, numbered first_episode, first_episode + 1, ..."""
    first_episode: int = 0
    """Number of the first episode."""
    greedy: bool = True
    """Greedy (argmax) decisions; False samples with the counter-based noise."""
    tick_timeout: float = 2.0
    """Seconds the world waits for a tick's actions before stepping without the missing ones."""
    start_timeout: float = 60.0
    """Seconds the world waits for every robot to come alive before the first tick."""
    pace: float = 0.0
    """Cap on ticks per second so a person can watch (0: as fast as the swarm goes)."""
    robot_threads: int = 1
    """torch threads per robot process (many processes share 2 cores)."""
    train: bool = False
    """Learning in the field: robots record their episodes for the learner and adopt its
    weights at episode boundaries; the world publishes each episode's rewards."""
    rollout_loss: float = 0.0
    """With `train`: each robot drops its episode record with this probability (seeded, like
    the radio's loss), a fault on the rollout traffic to the learner."""

    def __post_init__(self) -> None:
        from swarm.keys import check_run_id

        check_run_id(self.run_id)
        if self.episodes < 1:
            raise ValueError(f"episodes must be >= 1, got {self.episodes}")
        if self.pace < 0:
            raise ValueError(f"pace must be >= 0, got {self.pace}")
        if self.tick_timeout <= 0 or self.start_timeout <= 0:
            raise ValueError("timeouts must be > 0")
        if not 0.0 <= self.rollout_loss <= 1.0:
            raise ValueError(f"rollout_loss must lie in [0, 1], got {self.rollout_loss}")
