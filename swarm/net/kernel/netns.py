"""Kernel-level realism: the processes of a `swarm run` in Linux network namespaces.

One namespace for the world, one per robot, a veth pair world <-> robot i (a /30 in
10.214.0.0/16; the same addresses in every run, as each run's namespaces are private) and a veth
pair between the root namespace, where the supervisor stays, and the world (a /30 in
10.213.0.0/16 chosen per run, clear of every route the host already has). Kernel faults sit on
the robot links: `tc tbf` on the egress of both ends caps bandwidth, iptables' `statistic` match
in the robot's namespace drops packets at random (INPUT and OUTPUT, so a packet crossing one
link meets the loss once and a robot -> world -> robot message twice). TCP SYNs are spared, so
connections can be set up; every other packet (data, ACKs, FINs) may be dropped.

Namespaces are `swarm-<run id>-w` and `swarm-<run id>-r<i>`; veth names carry a 6-hex tag of the
run id (Linux allows 15 characters). `Topology` is a context manager whose teardown deletes every
namespace and veth it made (never one that existed before); it also runs at interpreter exit and
on SIGTERM, and is idempotent; `remove(run_id, n)` cleans up after a SIGKILLed supervisor.
"""

from __future__ import annotations

import atexit
import hashlib
import ipaddress
import json
import os
import shutil
import signal
import subprocess
import sys
from dataclasses import dataclass
from types import FrameType, TracebackType
from typing import Any

from swarm.net.faults import parse_duration_ms, parse_rate
from world.config import ConfigError

ROBOT_NET = ipaddress.ip_network("10.214.0.0/16")
ROOT_NET = ipaddress.ip_network("10.213.0.0/16")
MTU = 1500


@dataclass(frozen=True)
class NetnsConfig:
    """Kernel faults on every robot link (both directions), and the Zenoh lease of the run."""

    loss: float = 0.0
    """Probability that a packet is dropped, per direction of a link (iptables `statistic`)."""
    bandwidth: float = 0.0
    """Cap in bytes/s per direction of a link (`tc tbf`); 0: unlimited."""
    burst: float = 0.0
    """tbf bucket depth in bytes (0: one second's worth of `bandwidth`, at least 2 MTU)."""
    queue_ms: float = 1000.0
    """tbf `latency`: the longest a packet waits in the shaper before it is dropped."""
    transport: str = "tcp"
    """Zenoh link of the robots: `tcp` (lost packets are retransmitted) or `udp` (best effort:
    a lost datagram loses its messages). The supervisor's link is always tcp."""
    lease_ms: float = 0.0
    """Zenoh lease of every session of the run (0: the usual 1 s). Under loss, TCP's
    retransmission backoff can starve a session longer than its lease, which closes it."""

    def __post_init__(self) -> None:
        if not 0.0 <= self.loss < 1.0:
            raise ConfigError(f"kernel loss must be in [0, 1), got {self.loss}")
        if self.bandwidth < 0 or self.burst < 0 or self.queue_ms <= 0 or self.lease_ms < 0:
            raise ConfigError("kernel bandwidth, burst and lease must be >= 0, queue > 0")
        if self.transport not in ("tcp", "udp"):
            raise ConfigError(f"netns transport must be tcp or udp, got {self.transport!r}")

    @classmethod
    def parse(cls, loss: Any = None, bandwidth: Any = None, lease: Any = None,
              transport: str | None = None) -> NetnsConfig:
        """From the flags' text: `--kernel-loss 0.2 --kernel-bandwidth 8kB/s --netns-lease 10s`."""
        try:
            p = float(loss) if loss is not None else 0.0
        except (TypeError, ValueError):
            raise ConfigError(f"bad kernel loss {loss!r}") from None
        rate = parse_rate(bandwidth) if bandwidth is not None else 0.0
        if bandwidth is not None and rate == 0 and str(bandwidth).strip().lower() != "none":
            # (0 is the field's "unlimited": a user asking for no bandwidth got all of it)
            raise ConfigError(f"bad --kernel-bandwidth {bandwidth!r}: a cap must be above 0 B/s "
                              "(no cap: leave it out, or write none)")
        negative = lease is not None and str(lease).strip().startswith("-")
        lease_ms = parse_duration_ms(lease) if lease is not None and not negative else 0.0
        if lease is not None and lease_ms < 1:  # (0 is the field's "the usual 1 s"; Zenoh
            # takes whole ms: 0.4 would be a lease of 0)
            raise ConfigError(f"bad --netns-lease {lease!r}: a lease must be at least 1 ms "
                              "(the usual 1s: leave it out)")
        return cls(loss=p, bandwidth=rate, lease_ms=lease_ms, transport=transport or "tcp")

    def zenoh_cfg(self) -> list[str]:
        """`KEY:JSON5` settings every session of the run takes: a client retries its connection
        for up to 30 s (a first attempt lost to the faults is not the end), and the lease."""
        lease = [f"transport/link/tx/lease:{round(self.lease_ms)}"] if self.lease_ms else []
        return ["connect/timeout_ms:30000", *lease]


def _tag(run_id: str) -> str:
    return hashlib.sha1(run_id.encode()).hexdigest()[:6]


def _robot_pair(i: int) -> tuple[str, str]:
    """(world-side, robot-side) address of robot i's /30."""
    base = int(ROBOT_NET.network_address) + 4 * i
    return str(ipaddress.ip_address(base + 1)), str(ipaddress.ip_address(base + 2))


def _run(cmd: list[str], stdin: str | None = None, check: bool = True) -> str:
    try:
        p = subprocess.run(cmd, input=stdin, text=True, capture_output=True, timeout=30)
    except (OSError, subprocess.TimeoutExpired) as exc:
        raise ConfigError(f"netns: `{' '.join(cmd)}` failed: {exc}") from None
    if check and p.returncode != 0:
        raise ConfigError(f"netns: `{' '.join(cmd)}` failed: {_cause(p)}")
    return p.stdout


def _cause(p: subprocess.CompletedProcess[str]) -> str:
    """What a failed `ip`/`tc`/`iptables` said, in one line: `ip -batch` ends with "Command
    failed -:N" after the line that names the cause, so that line is kept."""
    lines = [ln.strip() for ln in (p.stderr or p.stdout or "").splitlines() if ln.strip()]
    causes = [ln for ln in lines if not ln.startswith("Command failed")] or lines
    why = "; ".join(causes[:2]) if causes else f"exit status {p.returncode}"
    if "Operation not permitted" in why:
        why += " (root without CAP_NET_ADMIN and CAP_SYS_ADMIN, e.g. an unprivileged container)"
    return why


def check_tools(faults: NetnsConfig = NetnsConfig()) -> None:
    """ConfigError (one line) unless root with `ip` (and `tc`/`iptables` when the faults need
    them) on the PATH."""
    if os.geteuid() != 0:
        raise ConfigError("--netns needs root (network namespaces, veth, tc, iptables)")
    need = ["ip"] + (["tc"] if faults.bandwidth else []) + (
        ["iptables", "iptables-restore"] if faults.loss else [])
    missing = [t for t in need if shutil.which(t) is None]
    if missing:
        raise ConfigError(f"--netns needs {', '.join(missing)} on the PATH "
                          f"(apt-get install iproute2 iptables)")


def namespaces() -> list[str]:
    """Names of the network namespaces that exist now (`ip netns list`)."""
    return [line.split()[0] for line in _run(["ip", "netns", "list"]).splitlines() if line.strip()]


def free_subnet(pool: ipaddress.IPv4Network, prefix: int, run_id: str,
                what: str) -> ipaddress.IPv4Network:
    """A /`prefix` of `pool` that overlaps no route of the root namespace, searched from a slot
    keyed by the run id (so concurrent runs pick different ones); a one-line ConfigError when
    none is free."""
    routes = json.loads(_run(["ip", "-j", "-4", "route", "show", "table", "all"]) or "[]")
    used = []
    for r in routes:
        dst = r.get("dst", "default")
        if dst != "default" and r.get("type", "unicast") in ("unicast", "local"):
            used.append(ipaddress.ip_network(dst if "/" in dst else f"{dst}/32", strict=False))
    size = 2 ** (32 - prefix)
    slots = pool.num_addresses // size
    start = int(_tag(run_id), 16) % slots
    for k in range(slots):
        net = ipaddress.ip_network(
            (int(pool.network_address) + size * ((start + k) % slots), prefix))
        if not any(net.overlaps(u) for u in used):
            return net
    raise ConfigError(f"{what}: no free /{prefix} in {pool}")


class Namespaced:
    """What a run's set of network namespaces (`Topology`, `hosts.Hosts`) shares: made so that
    it is torn down however the process ends (at exit, on SIGTERM, at once if making it
    fails), removed by `down()` (idempotent), entered with `ip netns exec`, a context manager.
    Subclasses give `up()` (checks, then `_bring_up`), `_make()` and `_remove()`."""

    run_id: str
    is_up = False
    _old_term: Any = None

    def up(self) -> Any:
        raise NotImplementedError

    def _make(self) -> None:
        raise NotImplementedError

    def _remove(self) -> None:
        raise NotImplementedError

    def _bring_up(self, clash: str | None, label: str) -> None:
        """`_make()` under the teardown guarantees; `clash` names a namespace or link that
        exists already (not ours: never touched): a one-line ConfigError."""
        if clash:
            raise ConfigError(f"{label}: {clash} exists already (another run with id "
                              f"{self.run_id!r}?)")
        atexit.register(self.down)
        if signal.getsignal(signal.SIGTERM) is signal.SIG_DFL:
            try:  # SIGTERM unwinds (finally: down) instead of killing with the namespaces left
                self._old_term = signal.signal(signal.SIGTERM, _exit_on_term)
            except ValueError:  # not the main thread
                pass
        self.is_up = True
        try:
            self._make()
        except BaseException:
            self.down()
            raise

    def down(self) -> None:
        """Delete what `up()` made (idempotent; errors are ignored)."""
        if self._old_term is not None:
            try:
                signal.signal(signal.SIGTERM, self._old_term)
            except ValueError:
                pass
            self._old_term = None
        atexit.unregister(self.down)
        if self.is_up:
            self.is_up = False
            self._remove()

    def exec_prefix(self, ns: str) -> list[str]:
        """The command prefix that runs a child inside namespace `ns` (exec: same pid)."""
        return ["ip", "netns", "exec", ns]

    def __enter__(self) -> Any:
        return self.up()

    def __exit__(self, et: type[BaseException] | None, e: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.down()


class Topology(Namespaced):
    """The namespaces, veths and kernel faults of one run; `up()` makes them, `down()` removes."""

    def __init__(self, run_id: str, n_robots: int, faults: NetnsConfig = NetnsConfig()) -> None:
        self.run_id, self.n, self.faults = run_id, n_robots, faults
        tag = _tag(run_id)
        self.world_ns = f"swarm-{run_id}-w"
        self.robot_ns = [f"swarm-{run_id}-r{i}" for i in range(n_robots)]
        self.host_if, self.hub_if = f"sw{tag}h", f"sw{tag}x"  # root side, world side
        self.world_if = [f"sw{tag}w{i}" for i in range(n_robots)]
        self.robot_if = [f"sw{tag}r{i}" for i in range(n_robots)]
        if len(self.world_if[-1] if n_robots else "") > 15:
            raise ConfigError(f"--netns supports at most 999999 robots, got {n_robots}")
        self.host_addr = self.hub_addr = ""
        self.transport = ""  # "tls" under --secure: every link, the robots' and the supervisor's

    # --- addresses the processes use ------------------------------------------------------
    def world_addr(self, i: int) -> str:
        """Where robot i reaches the world (the world side of its link)."""
        return _robot_pair(i)[0]

    def robot_addr(self, i: int) -> str:
        return _robot_pair(i)[1]

    def robot_endpoint(self, i: int, port: int) -> str:
        """The Zenoh endpoint robot i connects to."""
        return f"{self.transport or self.faults.transport}/{self.world_addr(i)}:{port}"

    def world_listen(self, port: int) -> list[str]:
        """The world's endpoints: tcp on the root link's world side, then each robot link's."""
        return [f"{self.transport or 'tcp'}/{self.hub_addr}:{port}",
                *(self.robot_endpoint(i, port) for i in range(self.n))]

    def relay_addresses(self) -> dict[str, list[str]]:
        """Identity -> the addresses its certificate must name (`--secure`): the world's."""
        return {"world": [self.hub_addr, *(self.world_addr(i) for i in range(self.n))]}

    def routers(self, port: int) -> list[tuple[str, list[str], str, str]]:
        """Router processes to start (swarm.net.kernel.hosts has some): none, the world routes."""
        return []

    def describe(self) -> dict[str, Any]:
        f = self.faults
        return {"world_ns": self.world_ns, "robot_ns": self.robot_ns, "hub_addr": self.hub_addr,
                "kernel_loss": f.loss, "kernel_bandwidth": f.bandwidth,
                "lease_ms": f.lease_ms or 1000.0, "transport": f.transport}

    # --- life cycle ---------------------------------------------------------------------------
    def up(self) -> Topology:
        check_tools(self.faults)
        if self.is_up:
            return self
        clash = set(namespaces()) & {self.world_ns, *self.robot_ns}
        self._bring_up(sorted(clash)[0] if clash else
                       self.host_if if _link_exists(self.host_if) else None, "netns")
        return self

    def _make(self) -> None:
        net = free_subnet(ROOT_NET, 30, self.run_id, "netns (the supervisor's link)")
        self.host_addr, self.hub_addr = str(net[1]), str(net[2])
        w = self.world_ns
        cmds = [f"netns add {ns}" for ns in (w, *self.robot_ns)]
        cmds.append(f"link add {self.host_if} type veth peer name {self.hub_if} netns {w}")
        cmds += [f"link add {a} netns {w} type veth peer name {b} netns {ns}"
                 for a, b, ns in zip(self.world_if, self.robot_if, self.robot_ns, strict=True)]
        cmds += [f"addr add {self.host_addr}/30 dev {self.host_if}",
                 f"link set {self.host_if} addrgenmode none", f"link set {self.host_if} up"]
        _run(["ip", "-batch", "-"], "\n".join(cmds) + "\n")
        inside = {w: ["link set lo up", f"addr add {self.hub_addr}/30 dev {self.hub_if}",
                      f"link set {self.hub_if} addrgenmode none", f"link set {self.hub_if} up"]}
        for i, ns in enumerate(self.robot_ns):
            a, b = self.world_if[i], self.robot_if[i]  # no IPv6: only our IPv4 on the wire
            inside[w] += [f"addr add {self.world_addr(i)}/30 dev {a}",
                          f"link set {a} addrgenmode none", f"link set {a} up"]
            inside[ns] = ["link set lo up", f"addr add {self.robot_addr(i)}/30 dev {b}",
                          f"link set {b} addrgenmode none", f"link set {b} up"]
        for ns, lines in inside.items():
            _run(["ip", "-n", ns, "-batch", "-"], "\n".join(lines) + "\n")
        self._faults()

    def _faults(self) -> None:
        f = self.faults
        if f.bandwidth:
            bits = max(8, round(8 * f.bandwidth))
            burst = max(int(f.burst or f.bandwidth), 2 * MTU)
            tbf = f"tbf rate {bits}bit burst {burst} latency {f.queue_ms:g}ms"
            _run(["tc", "-n", self.world_ns, "-batch", "-"], "".join(
                f"qdisc add dev {d} root {tbf}\n" for d in self.world_if))
            for ns, d in zip(self.robot_ns, self.robot_if, strict=True):
                _run(["tc", "-n", ns, "qdisc", "add", "dev", d, "root", *tbf.split()])
        if f.loss:
            for ns, d in zip(self.robot_ns, self.robot_if, strict=True):
                rules = ["*filter"]
                for chain, io in (("INPUT", "-i"), ("OUTPUT", "-o")):
                    rules += [f"-A {chain} {io} {d} -p tcp --tcp-flags SYN SYN -j ACCEPT",
                              f"-A {chain} {io} {d} -m statistic --mode random "
                              f"--probability {f.loss:.6f} -j DROP"]
                _run(["ip", "netns", "exec", ns, "iptables-restore", "--noflush"],
                     "\n".join([*rules, "COMMIT"]) + "\n")

    def _remove(self) -> None:
        remove(self.run_id, self.n)


def _exit_on_term(signum: int, frame: FrameType | None) -> None:
    sys.exit(128 + signum)


def _link_exists(name: str) -> bool:
    return subprocess.run(["ip", "link", "show", name], capture_output=True).returncode == 0


def remove(run_id: str, n_robots: int) -> None:
    """Delete the namespaces and veths of run `run_id` (what a SIGKILLed supervisor left)."""
    t = Topology(run_id, n_robots)
    if shutil.which("ip") is None:
        return
    # the root veth first: a process left in the world namespace would keep it alive
    _run(["ip", "link", "del", t.host_if], check=False)
    existing = set(namespaces())
    lines = [f"netns del {ns}" for ns in (t.world_ns, *t.robot_ns) if ns in existing]
    if lines:
        _run(["ip", "-force", "-batch", "-"], "\n".join(lines) + "\n", check=False)
