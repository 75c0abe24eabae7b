"""Emulated hosts (`swarm run --hosts K`): a run spread over K Linux network namespaces, each a
host with its own address on one bridge, each with its own Zenoh router, the routers connected
to one another; so multi-host is exercised on one machine exactly as on several.

Host k is namespace `swarm-<run id>-h<k>` with address `.k+2` of a /24 in 10.215.0.0/16 (chosen
clear of every route the host has); the bridge `sw<tag>b` in the root namespace holds `.1`, so
the supervisor reaches every host from where it stays. Host 0's router is the world's own
session (in router mode, as in a single-host run); hosts 1..K-1 get a router process each
(`swarm router`, `route` here: a Python session in router mode), listening on its host's
address and connected to the world and to the routers of the hosts before it. Robot i runs on
host i mod K and connects to its host's router only. No fault is injected in the kernel: with the
virtual clock a run is still a function of its seed and plan, and `--delivery direct` takes
the radio out of the path, so robot-to-robot messages go router to router, not through the
world.

`Hosts` has the interface the supervisor uses for `--netns` (`swarm.net.kernel.netns.Topology`):
`up`/`down` (idempotent, at exit and on SIGTERM too; `remove` cleans up after a SIGKILLed
supervisor), `exec_prefix`, `world_ns`, `robot_ns`, `hub_addr`, `world_listen`,
`robot_endpoint`, `routers`, `describe`.
"""

from __future__ import annotations

import ipaddress
import logging
import shutil
import subprocess
import time
from typing import Any

from swarm.net.kernel.netns import (
    Namespaced,
    _link_exists,
    _run,
    _tag,
    check_tools,
    free_subnet,
    namespaces,
)
from swarm.net.keys import Keys
from swarm.net.zconfig import ZenohOptions, open_session
from world.config import ConfigError

HOST_NET = ipaddress.ip_network("10.215.0.0/16")
MAX_HOSTS = 250


def check_host_count(hosts: int, n_robots: int, flag: str = "--hosts") -> None:
    """K emulated hosts for a team of `n_robots`: robots are dealt round robin, so more hosts
    than robots would leave one empty (and start its namespace and router for nothing)."""
    if hosts > n_robots:
        raise ConfigError(f"{flag} {hosts} is more hosts than the {n_robots} robots (robots are "
                          "dealt round robin: a host without one would be empty)")


def hosts_reason() -> str | None:
    """Why emulated hosts cannot run here (None: they can): root, `ip`, `ip netns`, bridges."""
    try:
        check_tools()
    except ConfigError as exc:
        return str(exc).replace("--netns", "--hosts")
    p = subprocess.run(["ip", "netns", "list"], capture_output=True, text=True)
    if p.returncode != 0:
        return f"`ip netns` is unavailable: {p.stderr.strip()}"
    return None


class Hosts(Namespaced):
    """The namespaces, bridge and veths of one run's K emulated hosts."""

    def __init__(self, run_id: str, n_robots: int, k: int) -> None:
        if not 1 <= k <= MAX_HOSTS:
            raise ConfigError(f"--hosts must lie in [1, {MAX_HOSTS}], got {k}")
        self.run_id, self.n, self.k = run_id, n_robots, k
        tag = _tag(run_id)
        self.host_ns = [f"swarm-{run_id}-h{h}" for h in range(k)]
        self.bridge = f"sw{tag}b"
        self.root_if = [f"sw{tag}v{h}" for h in range(k)]  # on the bridge
        self.host_if = [f"sw{tag}e{h}" for h in range(k)]  # in host h
        self.world_ns = self.host_ns[0]
        self.robot_ns = [self.host_ns[self.host_of(i)] for i in range(n_robots)]
        self.addr: list[str] = []
        self.hub_addr = ""
        self.transport = "tcp"  # every session's link ("tls" under --secure)

    def host_of(self, robot: int) -> int:
        """The host robot `robot` runs on (round robin)."""
        return robot % self.k

    # --- endpoints ----------------------------------------------------------------------------
    def endpoint(self, host: int, port: int) -> str:
        """Host `host`'s router (host 0: the world)."""
        return f"{self.transport}/{self.addr[host]}:{port}"

    def world_listen(self, port: int) -> list[str]:
        return [self.endpoint(0, port)]

    def robot_endpoint(self, i: int, port: int) -> str:
        """The one endpoint robot i connects to: its own host's router."""
        return self.endpoint(self.host_of(i), port)

    def relay_addresses(self) -> dict[str, list[str]]:
        """Identity -> the addresses its certificate must name (`--secure`): host h's router."""
        return {"world": [self.addr[0]], **{f"router-{h}": [self.addr[h]]
                                            for h in range(1, self.k)}}

    def router_endpoints(self, h: int, port: int) -> tuple[list[str], list[str]]:
        """(listen, connect) of host h's router: its address; the world and hosts 1..h-1."""
        return [self.endpoint(h, port)], [self.endpoint(g, port) for g in range(h)]

    def routers(self, port: int) -> list[tuple[str, list[str], ZenohOptions, str, str]]:
        """(name, `swarm` arguments, its session, namespace, address) of each router process to
        start once the world listens: host h's listens on its address and connects to the world
        and to hosts 1..h-1's routers."""
        out = []
        for h in range(1, self.k):
            listen, connect = self.router_endpoints(h, port)
            out.append((f"router{h}", ["router", "--run-id", self.run_id],
                        ZenohOptions("router", connect, listen), self.host_ns[h], self.addr[h]))
        return out

    def describe(self) -> dict[str, Any]:
        return {"hosts": self.k, "host_ns": self.host_ns, "host_addr": self.addr,
                "robot_host": [self.host_of(i) for i in range(self.n)]}

    # --- life cycle ---------------------------------------------------------------------------
    def up(self) -> Hosts:
        reason = hosts_reason()
        if reason:
            raise ConfigError(reason)
        if self.is_up:
            return self
        clash = set(namespaces()) & set(self.host_ns)
        self._bring_up(sorted(clash)[0] if clash else
                       self.bridge if _link_exists(self.bridge) else None, "--hosts")
        return self

    def _make(self) -> None:
        net = free_subnet(HOST_NET, 24, self.run_id, "--hosts (the hosts' bridge)")
        self.hub_bridge = str(net[1])
        self.addr = [str(net[h + 2]) for h in range(self.k)]
        self.hub_addr = self.addr[0]
        cmds = [f"netns add {ns}" for ns in self.host_ns]
        cmds += [f"link add {self.bridge} type bridge", f"link set {self.bridge} addrgenmode none",
                 f"addr add {self.hub_bridge}/24 dev {self.bridge}", f"link set {self.bridge} up"]
        for h, ns in enumerate(self.host_ns):
            a, b = self.root_if[h], self.host_if[h]  # no IPv6: only our IPv4 on the wire
            cmds += [f"link add {a} type veth peer name {b} netns {ns}",
                     f"link set {a} master {self.bridge}", f"link set {a} addrgenmode none",
                     f"link set {a} up"]
        _run(["ip", "-batch", "-"], "\n".join(cmds) + "\n")
        for h, ns in enumerate(self.host_ns):
            b = self.host_if[h]
            _run(["ip", "-n", ns, "-batch", "-"], "\n".join([
                "link set lo up", f"addr add {self.addr[h]}/24 dev {b}",
                f"link set {b} addrgenmode none", f"link set {b} up"]) + "\n")

    def _remove(self) -> None:
        remove(self.run_id, self.k)


def remove(run_id: str, k: int) -> None:
    """Delete the hosts of run `run_id` (what a SIGKILLed supervisor left)."""
    if shutil.which("ip") is None:
        return
    t = Hosts(run_id, 0, max(1, min(k, MAX_HOSTS)))
    for name in (*t.root_if, t.bridge):
        _run(["ip", "link", "del", name], check=False)
    existing = set(namespaces())
    lines = [f"netns del {ns}" for ns in t.host_ns if ns in existing]
    if lines:
        _run(["ip", "-force", "-batch", "-"], "\n".join(lines) + "\n", check=False)


def topology(run_id: str, n_robots: int, netns: Any = None, hosts: int = 0) -> Any:
    """The supervisor's topology: `--netns` namespaces, `--hosts` hosts, or None (loopback)."""
    if netns is not None and hosts:
        raise ConfigError("--hosts and --netns are two topologies: give one")
    if hosts:
        return Hosts(run_id, n_robots, hosts)
    if netns is not None:
        from swarm.net.kernel.netns import Topology

        return Topology(run_id, n_robots, netns)
    return None


def route(zopts: ZenohOptions, run_id: str | None = None) -> None:
    """The router process (`swarm router`): a Python session in router mode that only routes
    (zenohd is not installable here; any Zenoh session can route), until interrupted (Ctrl-C,
    SIGTERM, its supervisor's death). `--hosts` starts one per host but the world's; on real
    hosts, start one per machine and point that machine's processes at it. With `run_id` it
    declares `swarm/<run>/alive/router/<zid>`, so a run can see which routers are up."""
    zopts.mode = "router"
    with open_session(zopts) as session:
        token = None
        if run_id is not None:
            key = Keys(run_id).alive_router(str(session.zid()))
            token = session.liveliness().declare_token(key)
        logging.getLogger("swarm.router").info("routing: listen %s, connect %s", zopts.listen,
                                               zopts.connect)
        try:
            while True:
                time.sleep(0.5)  # short: a signal another thread took is handled on waking
        finally:
            if token is not None:
                token.undeclare()
