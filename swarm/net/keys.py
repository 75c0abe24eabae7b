"""Every Zenoh key expression of a run; nothing else formats a key.

All keys live under `swarm/<run-id>/`, so two runs on one network never meet. Robot ids are
decimal. See the README's "Keys and schemas" section for who publishes what.
"""

from __future__ import annotations

import re

from world.config import ConfigError

ROOT = "swarm"
_RUN_ID = re.compile(r"^[A-Za-z0-9_\-]{1,64}$")


def check_run_id(run: str) -> str:
    """A run id is 1-64 characters of letters, digits, '-' and '_' (no key-expression syntax)."""
    if not _RUN_ID.match(run):
        raise ConfigError(f"bad run id {run!r}: use 1-64 letters, digits, '-' or '_'")
    return run


WORLD_GONE_S = 2.0
"""How long the world's liveliness token must stay gone (no `end` record seen) before a
listener that outlives it (the recorder, a learner) takes the run as over."""


class Keys:
    """Key expressions of run `run`."""

    def __init__(self, run: str) -> None:
        self.run = check_run_id(run)
        self.base = f"{ROOT}/{run}"

    # world -> robots
    def obs(self, robot: int) -> str:
        return f"{self.base}/world/obs/{robot}"

    @property
    def config(self) -> str:
        """Queryable served by the world: the run's configuration."""
        return f"{self.base}/world/config"

    @property
    def status(self) -> str:
        """World -> supervisor: one status record per tick."""
        return f"{self.base}/world/status"

    @property
    def end(self) -> str:
        """World -> everyone: the run is over (robots exit at once instead of waiting to rejoin)."""
        return f"{self.base}/world/end"

    @property
    def result(self) -> str:
        """World -> supervisor: the run's result at the end."""
        return f"{self.base}/world/result"

    # robots -> radio -> robots
    def traj(self, robot: int | str) -> str:
        return f"{self.base}/robot/{robot}/traj"

    def hidden(self, robot: int | str) -> str:
        return f"{self.base}/robot/{robot}/hidden"

    def direct(self, robot: int | str, hidden: bool = False) -> str:
        """Robot -> robots (direct delivery): its stamped trajectory (or hidden-state) messages
        (`messages.Stamped`); receivers apply range and the fault plan themselves."""
        return f"{self.base}/robot/{robot}/{'dhidden' if hidden else 'dtraj'}"

    def inbox(self, robot: int) -> str:
        """Radio -> robot: the bundle of trajectory messages it heard this tick."""
        return f"{self.base}/radio/inbox/{robot}"

    def inbox_hidden(self, robot: int) -> str:
        """Radio -> robot: its predecessor's hidden-state message."""
        return f"{self.base}/radio/hidden/{robot}"

    # robots -> world
    def action(self, robot: int | str) -> str:
        return f"{self.base}/robot/{robot}/action"

    def robot_status(self, robot: int | str) -> str:
        return f"{self.base}/robot/{robot}/status"

    # learning: robots / world / workers -> learner -> robots / workers
    def rollout(self, robot: int | str) -> str:
        """Robot -> learner: its record of an episode (at the episode's end)."""
        return f"{self.base}/robot/{robot}/rollout"

    @property
    def episode(self) -> str:
        """World -> learner: rewards and metrics of an episode (at its end)."""
        return f"{self.base}/world/episode"

    def worker_episodes(self, worker: int | str) -> str:
        """Rollout worker -> learner: whole episodes in the trainer's terms. One key a worker,
        so a secure run's ACL lets each worker's certificate put only its own."""
        return f"{self.base}/worker/{worker}/episodes"

    @property
    def weights(self) -> str:
        """Learner -> robots and workers: versioned weights (also a queryable: the current)."""
        return f"{self.base}/learner/weights"

    @property
    def learner_config(self) -> str:
        """Queryable served by the learner: world config, policy, model and train settings."""
        return f"{self.base}/learner/config"

    @property
    def learner_status(self) -> str:
        return f"{self.base}/learner/status"

    @property
    def alive_learner(self) -> str:
        return f"{self.base}/alive/learner"

    # liveliness and control
    def alive_robot(self, robot: int | str) -> str:
        return f"{self.base}/alive/robot/{robot}"

    def alive_worker(self, worker: int | str) -> str:
        """A rollout worker's token: two workers of one id would play the same episodes."""
        return f"{self.base}/alive/worker/{worker}"

    @property
    def alive_world(self) -> str:
        return f"{self.base}/alive/world"

    def alive_router(self, zid: str) -> str:
        """A host router's token (`swarm router --run-id`), by its Zenoh id."""
        return f"{self.base}/alive/router/{zid}"

    @property
    def alive_recorder(self) -> str:
        """The recorder's token: declared once it listens and its file is open."""
        return f"{self.base}/alive/recorder"

    @property
    def alive_all(self) -> str:
        """Every liveliness token of the run (the supervisor and the recorder watch them all)."""
        return f"{self.base}/alive/**"

    @property
    def everything(self) -> str:
        """Every key of the run (the recorder's subscription; the bound of every ACL rule)."""
        return f"{self.base}/**"

    @property
    def control(self) -> str:
        """Supervisor -> world: stop requests (and, later, live fault changes)."""
        return f"{self.base}/control"

    def kind_of(self, key: str) -> tuple[str, int | None]:
        """What a key of this run carries: (kind, robot id or None: a rollout worker's key names
        no robot, see `worker_of`); ("", None) for a key that
        is not one of this run's (another run's, or made up). Kinds: obs, status, end, result,
        episode, traj, hidden, action, rstatus, rollout, direct, bundle, radio_hidden, control,
        weights, lstatus, worker_episodes (the names `swarm.net.record.msgjson` maps to schemas)."""
        prefix = self.base + "/"
        if not str(key).startswith(prefix):
            return "", None
        parts = str(key)[len(prefix):].split("/")
        fixed = {("world", "status"): "status", ("world", "end"): "end",
                 ("world", "result"): "result", ("world", "episode"): "episode",
                 ("control",): "control", ("learner", "weights"): "weights",
                 ("learner", "status"): "lstatus"}
        kind = fixed.get(tuple(parts))
        if kind is not None:
            return kind, None
        robot: int | None = None
        if len(parts) == 3 and parts[0] == "world" and parts[1] == "obs":
            kind, robot = "obs", _id(parts[2])
        elif len(parts) == 3 and parts[0] == "robot":
            kind = {"traj": "traj", "hidden": "hidden", "action": "action", "status": "rstatus",
                    "rollout": "rollout", "dtraj": "direct", "dhidden": "direct"}.get(parts[2], "")
            robot = _id(parts[1])
        elif len(parts) == 3 and parts[0] == "worker" and parts[2] == "episodes":
            ok = _id(parts[1]) is not None  # (a worker's id, not a robot's: None)
            return ("worker_episodes", None) if ok else ("", None)
        elif len(parts) == 3 and parts[0] == "radio":
            kind = {"inbox": "bundle", "hidden": "radio_hidden"}.get(parts[1], "")
            robot = _id(parts[2])
        if not kind or robot is None:
            return "", None
        return kind, robot

    @staticmethod
    def robot_of(key: str) -> int:
        """The robot id in `.../robot/<id>/...`, `.../obs/<id>`, `.../inbox/<id>` keys."""
        parts = str(key).split("/")
        for i, part in enumerate(parts[:-1]):
            if part in ("robot", "obs", "inbox", "hidden") and parts[i + 1].isdigit():
                return int(parts[i + 1])
        if parts and parts[-1].isdigit():
            return int(parts[-1])
        raise ValueError(f"no robot id in key {key!r}")


    @staticmethod
    def worker_of(key: str) -> int | None:
        """The rollout worker id in a `.../worker/<id>/episodes` key, else None."""
        parts = str(key).split("/")
        return _id(parts[-2]) if len(parts) >= 3 and parts[-3] == "worker" else None


def _id(text: str) -> int | None:
    """A robot id as keys spell it (decimal, no sign, at most 6 digits), else None."""
    return int(text) if text.isdigit() and len(text) <= 6 and text.isascii() else None
