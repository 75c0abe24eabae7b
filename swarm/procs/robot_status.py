"""What a robot process reports: its counters (the result and the status record) and the
attention of its last decision (CommAttn robots, drawn live on the dashboard)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from policies.base import Policy


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
