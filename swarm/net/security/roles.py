"""Who may do what in a run: the roles of the roster and the `access_control` they make.

Who may do what is one table, `roles(keys, robots, workers)`, built from the key builders of
`swarm.net.keys.Keys`, so the ACL cannot drift from the keys the processes use. Each role lists
the keys its process puts, queries, serves, subscribes to, declares liveliness tokens on and
watches. From it, `acl(identity, ...)` makes the `access_control` of one session:

- Zenoh checks an ACL on each node, per neighbour (the subject is the neighbour's certificate
  common name), on what the node receives from it (`ingress`) and sends to it (`egress`). Only
  the node a process is directly connected to sees its certificate, so the originator of a
  message is checked where it enters the network: at the world, the router every other session
  connects to (`RELAYS`). There robot-3 may originate only what role robot-3 may (ingress) and
  receive only what it may receive (egress).
- Every other session's neighbour is the world, which also relays what others originate; its
  ACL lets the world deliver exactly what this process may receive, and lets the process send
  only what its own role originates (to any neighbour: the world, or a peer in a peer-to-peer
  deployment, whose messages it accepts only as far as that peer's role originates them).
- Emulated hosts (`swarm run --hosts K --secure DIR`) add routers `router-1..K-1`, relays like
  the world: each checks the originator of what its own clients send, exactly as the world
  does, and relays trust one another for everything of the run (a message admitted at one
  relay crosses the others unchanged).
- Default deny: an identity outside the roster (or a session without a certificate of the
  run's CA, which TLS refuses before any message) may do nothing, and nothing outside
  `swarm/<run>/**` is ever allowed.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from swarm.net.keys import Keys
from world.config import ConfigError

CA_CERT, CA_KEY, ROSTER = "ca.pem", "ca.key", "roster.json"
SINGLETONS = ("world", "supervisor", "learner", "operator", "recorder")
RELAYS = ("world",)
"""Identities whose sessions route other processes' messages (the world runs in router mode);
the routers of emulated hosts (`router-<h>`) are relays too (`is_relay`)."""
ALL_KINDS = ("put", "delete", "query", "reply", "declare_subscriber", "declare_queryable",
             "liveliness_token", "declare_liveliness_subscriber", "liveliness_query")
"""Every message kind an ACL rule can name: what relays pass one another."""


def is_relay(identity: str) -> bool:
    """The world, or the router of an emulated host (`router-1`, `router-2`, ...)."""
    kind, _, num = identity.partition("-")
    return identity in RELAYS or (kind == "router" and num.isdigit() and int(num) >= 1)

SELF_CHECK = ("liveliness_query", "liveliness_token")
"""What two processes of one identity exchange: a liveliness query on its own token, and the
answer (`swarm.net.inbox.check_free`), so that a second world or robot-3 stops at once."""

DECLARATIONS = ("declare_subscriber", "declare_queryable")
"""What a relay tells its neighbours about the others' subscribers and queryables (so that a
publisher knows someone listens); allowed for every key of the run, in both directions."""


def identities(robots: int, workers: int = 0, routers: int = 0) -> list[str]:
    """Every process identity of a roster, each the common name of one certificate; `routers`
    are the routers of hosts 1..routers (host 0's is the world)."""
    return [*SINGLETONS, *(f"robot-{i}" for i in range(robots)),
            *(f"worker-{k}" for k in range(workers)),
            *(f"router-{h}" for h in range(1, routers + 1))]


@dataclass(frozen=True)
class Role:
    """What one identity's process does on the network (key expressions of its run)."""

    put: tuple[str, ...] = ()
    """Keys it publishes on."""
    query: tuple[str, ...] = ()
    """Keys it queries (and gets replies on)."""
    serve: tuple[str, ...] = ()
    """Keys of its queryables (queried there, replies from there)."""
    subscribe: tuple[str, ...] = ()
    """Keys it subscribes to (it receives puts on them)."""
    token: tuple[str, ...] = ()
    """Liveliness tokens it declares."""
    watch: tuple[str, ...] = ()
    """Liveliness tokens it subscribes to."""

    def sends(self) -> dict[tuple[str, ...], tuple[str, ...]]:
        """Message kinds -> keys this process may originate."""
        return {("put",): self.put, ("query",): self.query,
                ("reply", "declare_queryable"): self.serve, ("declare_subscriber",): self.subscribe,
                ("liveliness_token",): self.token,  # (and whether its own id is up: `check_free`)
                ("declare_liveliness_subscriber", "liveliness_query"): self.watch + self.token}

    def receives(self, everything: str) -> dict[tuple[str, ...], tuple[str, ...]]:
        """Message kinds -> keys this process may be sent (`everything`: `Keys.everything`)."""
        return {("put",): self.subscribe, ("reply",): self.query, ("query",): self.serve,
                ("liveliness_token",): self.watch + self.token, DECLARATIONS: (everything,)}


def roles(keys: Keys, robots: int, workers: int = 0, routers: int = 0) -> dict[str, Role]:
    """The role of every identity of a run with `robots` robots, `workers` rollout workers and
    `routers` host routers."""
    k = keys
    out = {
        "world": Role(put=(k.obs("*"), k.inbox("*"), k.inbox_hidden("*"), k.status,  # type: ignore[arg-type]
                           k.result, k.end, k.episode),
                      serve=(k.config,), token=(k.alive_world,), watch=(k.alive_robot("*"),),
                      subscribe=(k.traj("*"), k.hidden("*"), k.action("*"), k.control,
                                 k.robot_status("*"), k.learner_status)),  # (train_sync)
        "supervisor": Role(put=(k.control,), watch=(k.alive_all,),
                           subscribe=(k.status, k.robot_status("*"), k.result, k.control,
                                      k.learner_status)),
        "learner": Role(put=(k.weights, k.learner_status), serve=(k.weights, k.learner_config),
                        token=(k.alive_learner,),
                        subscribe=(k.rollout("*"), k.episode, k.worker_episodes("*"))),
        # (checks a fault fits the run, and that its --at-tick is still ahead)
        "operator": Role(put=(k.control,), query=(k.config,), subscribe=(k.status,)),
        "recorder": Role(subscribe=(k.everything,), watch=(k.alive_all,),
                         query=(k.config, k.learner_config),
                         token=(k.alive_recorder,)),
    }
    for i in range(robots):  # radio delivery (traj, hidden, bundles) or direct (dtraj, dhidden)
        out[f"robot-{i}"] = Role(
            put=(k.traj(i), k.hidden(i), k.direct(i), k.direct(i, hidden=True), k.action(i),
                 k.robot_status(i), k.rollout(i)),
            query=(k.config, k.weights), token=(k.alive_robot(i),),
            watch=(k.alive_world, k.alive_robot("*")),
            subscribe=(k.obs(i), k.inbox(i), k.inbox_hidden(i), k.direct("*"),
                       k.direct("*", hidden=True), k.end, k.weights))
    for w in range(workers):
        out[f"worker-{w}"] = Role(put=(k.worker_episodes(w),), query=(k.learner_config, k.weights),
                                  subscribe=(k.weights,), watch=(k.alive_learner,),
                                  token=(k.alive_worker(w),))
    for h in range(1, routers + 1):  # what it originates itself: its liveliness token
        out[f"router-{h}"] = Role(token=(k.alive_router("*"),))
    return out


def _rules(subject: str, flow: str, table: dict[tuple[str, ...], tuple[str, ...]]
           ) -> list[dict[str, Any]]:
    return [{"id": f"{subject}/{flow}/{'+'.join(msgs)}", "messages": list(msgs),
             "flows": [flow], "permission": "allow", "key_exprs": list(keys)}
            for msgs, keys in table.items() if keys]


def acl(identity: str, keys: Keys, robots: int, workers: int = 0,
        routers: int = 0) -> dict[str, Any]:
    """The `access_control` of the session of `identity` in run `keys.run` (module docstring)."""
    table = roles(keys, robots, workers, routers)
    if identity not in table:
        raise ConfigError(f"identity {identity!r} is not in the run's roster "
                          f"({robots} robots, {workers} workers, {routers} routers)")
    everything = {ALL_KINDS: (keys.everything,)}
    me = table[identity]
    rules: list[dict[str, Any]] = []
    subjects: list[dict[str, Any]] = []
    policies: list[dict[str, Any]] = []
    for other, role in table.items():
        if other == identity:  # a second process of my identity may ask whether I am up
            own = {SELF_CHECK: me.token}  # (`check_free`: it stops at once if I am)
            mine = _rules(other, "ingress", own) + _rules(other, "egress", own)
            if mine:
                rules += mine
                subjects.append({"id": other, "cert_common_names": [other]})
                policies.append({"id": other, "rules": [r["id"] for r in mine],
                                 "subjects": [other]})
            continue
        if is_relay(identity) and is_relay(other):  # relays pass on what the others admitted
            ingress = egress = everything
        else:
            # a relay delivers what I may receive (from anyone it admitted); anyone else sends
            # only what it originates itself
            ingress = me.receives(keys.everything) if is_relay(other) else role.sends()
            # a relay may send anyone what that one may receive; anyone else sends only its own
            egress = role.receives(keys.everything) if is_relay(identity) else me.sends()
        mine = _rules(other, "ingress", ingress) + _rules(other, "egress", egress)
        rules += mine
        subjects.append({"id": other, "cert_common_names": [other]})
        policies.append({"id": other, "rules": [r["id"] for r in mine], "subjects": [other]})
    return {"enabled": True, "default_permission": "deny", "rules": rules,
            "subjects": subjects, "policies": policies}
