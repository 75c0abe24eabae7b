"""`swarm router` (a Zenoh router process), `swarm run --hosts K` (emulated hosts, see
swarm/net/kernel/hosts.py) and `swarm run --netns` (kernel faults, swarm/net/kernel/netns.py)."""

from __future__ import annotations

import argparse
from typing import Any

from swarm.cli.secure import add_secure_flag, secure_options
from swarm.net import zconfig
from world.config import ConfigError


def add_netns_flags(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("kernel-level realism (root; see swarm/net/kernel/netns.py)")
    g.add_argument("--netns", action="store_true",
                   help="world and robots in network namespaces joined by veth pairs")
    g.add_argument("--kernel-loss", metavar="P",
                   help="with --netns: packet drop probability per direction of each robot link "
                        "(iptables statistic; TCP retransmits, so messages arrive late)")
    g.add_argument("--kernel-bandwidth", metavar="RATE",
                   help="with --netns: tc tbf cap per direction of each robot link, e.g. 8kB/s "
                        "(above 0; default none: no cap)")
    g.add_argument("--netns-lease", metavar="DUR",
                   help="with --netns: Zenoh lease of every session, above 0 (default 1s; a "
                        "number alone is ms); TCP's retransmission backoff under loss can "
                        "outlast a short one")
    g.add_argument("--netns-transport", choices=["tcp", "udp"],
                   help="with --netns: the robots' Zenoh link (default tcp; udp is best effort)")


def netns_faults(args: argparse.Namespace) -> Any:
    """The NetnsConfig of `--netns` (None without it); kernel flags need --netns."""
    from swarm.net.kernel.netns import NetnsConfig, check_tools

    given = [getattr(args, k, None) for k in ("kernel_loss", "kernel_bandwidth", "netns_lease",
                                              "netns_transport")]
    if not getattr(args, "netns", False):
        if any(v is not None for v in given):
            raise ConfigError("--kernel-loss, --kernel-bandwidth and --netns-* flags need --netns")
        return None
    faults = NetnsConfig.parse(*given)
    check_tools(faults)  # not root, or a tool missing: one line before any spawn
    return faults


def add_hosts_flag(p: argparse.ArgumentParser) -> None:
    p.add_argument("--hosts", type=int, metavar="K",
                   help="emulated hosts (root): K network namespaces on a bridge, a Zenoh router "
                        "each, robots spread round robin; pair with --delivery direct")


def hosts_option(args: argparse.Namespace) -> int:
    """The number of emulated hosts of `swarm run` (0: none), checked before any spawn."""
    k = getattr(args, "hosts", None)
    if k is None:
        return 0
    from swarm.net.kernel.hosts import MAX_HOSTS, hosts_reason

    if not 1 <= k <= MAX_HOSTS:
        raise ConfigError(f"--hosts must lie in [1, {MAX_HOSTS}], got {k}")
    if getattr(args, "netns", False):
        raise ConfigError("--hosts and --netns are two topologies: give one")
    reason = hosts_reason()
    if reason:
        raise ConfigError(reason)
    return int(k)


def cmd_router(args: argparse.Namespace) -> int:
    import logging
    import sys

    from swarm.net.kernel.hosts import route

    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING,
                        stream=sys.stderr, format="%(asctime)s %(name)s %(levelname)s %(message)s")
    zopts = zconfig.from_args(args)
    if args.router_id is not None and not args.secure:
        raise ConfigError("--router-id names this router's identity under --secure DIR; "
                          "without --secure it does nothing")
    if args.secure:  # on a real host: its own identity polices this host's clients
        if not args.run_id:
            raise ConfigError("swarm router --secure needs --run-id (the run its ACL admits)")
        if args.router_id is None:
            args.router_id = 1
        if not 1 <= args.router_id <= 64:
            raise ConfigError(f"--router-id must lie in [1, 64], got {args.router_id}")
        zopts = secure_options(args, zopts, f"router-{args.router_id}", args.run_id)
    try:
        route(zopts, args.run_id)
    except KeyboardInterrupt:
        return 130
    return 0


def add_parsers(sub: Any) -> None:
    """Register `router` on the `swarm` subparsers."""
    p = sub.add_parser("router", help="a Zenoh router process (one per host)",
                       description="Route Zenoh traffic between this host's processes and the "
                                   "other hosts' routers (a Python session in router mode).")
    p.add_argument("--run-id", help="declare a liveliness token under the run's keys")
    p.add_argument("-v", "--verbose", action="store_true", help="log at INFO")
    p.add_argument("--router-id", type=int, default=None, metavar="H",
                   help="with --secure: this router's identity router-H (default 1; "
                        "`swarm certs --routers R` makes router-1..R)")
    zconfig.add_arguments(p, mode="router")
    add_secure_flag(p)
    p.set_defaults(func=cmd_router)
