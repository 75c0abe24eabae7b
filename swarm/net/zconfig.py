"""The one Zenoh configuration helper shared by every process entry point.

Defaults are safe for a laptop or CI box: peer mode, multicast scouting OFF, listening on
127.0.0.1 only, a 1 s lease so a hung peer is noticed quickly, and shared memory off (it would
bypass kernel traffic shaping). `--zenoh-config FILE` loads a full JSON5 file (see deploy/);
`--connect/--listen/--mode/--cfg KEY:JSON5` override on top, as in zenoh-python's examples.
"""

from __future__ import annotations

import argparse
import json
import re
import socket
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field

import zenoh

from world.config import ConfigError


@dataclass
class ZenohOptions:
    """Where a process's Zenoh session listens and connects."""

    mode: str = "peer"
    """`peer`, `client` or `router`."""
    connect: list[str] = field(default_factory=list)
    """Endpoints to connect to, e.g. `tcp/127.0.0.1:7447`."""
    listen: list[str] = field(default_factory=list)
    """Endpoints to listen on; empty means `tcp/127.0.0.1:0` (an ephemeral loopback port)."""
    config_file: str | None = None
    """A JSON5 Zenoh configuration file loaded first."""
    cfg: list[str] = field(default_factory=list)
    """Extra `KEY:JSON5` settings applied last."""

    @property
    def may_acl(self) -> bool:
        """Whether an access list may stop robots putting to one another (`--secure`'s, or one
        in a config file): then the world forwards every hidden-state message itself (a robot
        started by hand with `--secure` had its fast-lane puts refused: 10 s a tick)."""
        return self.config_file is not None or any(c.startswith("access_control")
                                                   for c in self.cfg)

    def to_config(self) -> zenoh.Config:
        """The session config; anything Zenoh rejects is a one-line ConfigError."""
        try:
            return self._config()
        except zenoh.ZError as exc:
            raise ConfigError(f"zenoh configuration: {zenoh_reason(exc)}") from None

    def _config(self) -> zenoh.Config:
        conf = zenoh.Config.from_file(self.config_file) if self.config_file else zenoh.Config()
        if not self.config_file:
            conf.insert_json5("scouting/multicast/enabled", "false")
            conf.insert_json5("transport/link/tx/lease", "1000")
            conf.insert_json5("transport/shared_memory/enabled", "false")
        conf.insert_json5("mode", json.dumps(self.mode))
        if not self.config_file and no_scouting_wait(self.mode, self.connect):
            conf.insert_json5("scouting/delay", "0")
        # a client never listens; a peer or router listens on an ephemeral loopback port
        default = [] if self.config_file or self.mode == "client" else ["tcp/127.0.0.1:0"]
        listen = self.listen or default
        if listen:
            conf.insert_json5("listen/endpoints", json.dumps(listen))
        if self.connect:
            conf.insert_json5("connect/endpoints", json.dumps(self.connect))
        for item in self.cfg:
            key, sep, value = item.partition(":")
            if not sep:
                raise ConfigError(f"--cfg expects KEY:JSON5, got {item!r}")
            conf.insert_json5(key, value)
        return conf

    def to_args(self) -> list[str]:
        """Command-line flags that rebuild these options in a child process."""
        out = ["--zenoh-mode", self.mode]
        for e in self.connect:
            out += ["--connect", e]
        for e in self.listen:
            out += ["--listen", e]
        if self.config_file:
            out += ["--zenoh-config", self.config_file]
        for c in self.cfg:
            out += ["--cfg", c]
        return out


def no_scouting_wait(mode: str, connect: list[str]) -> bool:
    """Whether a session opens without Zenoh's scouting wait: a router that connects to nobody
    (the hub). Zenoh holds a router's `open` for `scouting/delay` (500 ms) after binding its
    listeners, to find peers first; with multicast off and nothing to connect to there is nobody
    to find, and the world and every hand-started hub paid that half second."""
    return mode == "router" and not connect


def add_arguments(parser: argparse.ArgumentParser, mode: str = "peer") -> None:
    """The Zenoh flags of a command whose session is in `mode` unless told otherwise."""
    g = parser.add_argument_group("zenoh")
    g.add_argument("--zenoh-mode", default=mode, choices=["peer", "client", "router"],
                   help=f"this process's Zenoh mode (default {mode})")
    g.add_argument("--connect", action="append", default=[], metavar="ENDPOINT",
                   help="endpoint to connect to, e.g. tcp/127.0.0.1:7447 (repeatable)")
    g.add_argument("--listen", action="append", default=[], metavar="ENDPOINT",
                   help="endpoint to listen on (repeatable; default tcp/127.0.0.1:0)")
    g.add_argument("--zenoh-config", default=None, metavar="FILE", help="JSON5 Zenoh config file")
    g.add_argument("--cfg", action="append", default=[], metavar="KEY:JSON5",
                   help="extra Zenoh setting applied last (repeatable)")


IP_PROTOCOLS = ("tcp", "udp", "tls", "quic", "ws")  # PROTO/HOST:PORT
OTHER_PROTOCOLS = ("unixsock-stream", "unixpipe", "vsock", "serial")  # PROTO/ADDRESS


def check_endpoint(endpoint: str, flag: str = "--connect") -> str:
    """A Zenoh endpoint `PROTO/ADDRESS[?METADATA][#CONFIG]`, checked as it is parsed: a known
    protocol and, for an IP one, HOST:PORT with a port in [1, 65535] ([0, 65535] to listen on:
    0 is an ephemeral port). Zenoh itself takes `tcp/127.0.0.1:notaport` and fails only when the
    session opens (a refused connection or no answer, far from the flag): a ConfigError names
    the flag instead."""
    proto, sep, rest = str(endpoint).partition("/")
    address = re.split(r"[?#]", rest, maxsplit=1)[0]
    form = f"{flag} {endpoint!r}: expected PROTO/HOST:PORT, e.g. tcp/127.0.0.1:7447"
    if not sep or not proto or not address:
        raise ConfigError(form)
    if proto in OTHER_PROTOCOLS:
        return endpoint
    if proto not in IP_PROTOCOLS:
        raise ConfigError(f"{flag} {endpoint!r}: unknown protocol {proto!r} (one of "
                          f"{', '.join(IP_PROTOCOLS + OTHER_PROTOCOLS)})")
    host, colon, port = address.rpartition(":")
    if not colon or not host or host in ("[]",) or any(c.isspace() for c in host) or (
            host.startswith("[") != host.endswith("]")):
        raise ConfigError(form)
    lo = 0 if flag == "--listen" else 1
    if not (port.isascii() and port.isdigit() and lo <= int(port) <= 65535):
        raise ConfigError(f"{flag} {endpoint!r}: port {port!r} is not a number in "
                          f"[{lo}, 65535]")
    return endpoint


def from_args(args: argparse.Namespace) -> ZenohOptions:
    """The options of the flags, checked at once (before any session or process exists)."""
    for flag, endpoints in (("--connect", args.connect), ("--listen", args.listen)):
        for e in endpoints:
            check_endpoint(e, flag)
    if args.zenoh_config is not None and not args.zenoh_config.strip():  # (not "not given")
        raise ConfigError("--zenoh-config wants a file name, got an empty one")
    opts = ZenohOptions(mode=args.zenoh_mode, connect=list(args.connect),
                        listen=list(args.listen), config_file=args.zenoh_config,
                        cfg=list(args.cfg))
    opts.to_config()
    return opts


def zenoh_reason(exc: BaseException) -> str:
    """Zenoh's message without its Rust source location, on one line."""
    text = " ".join(str(exc).replace("\\n", " ").split())
    text = re.sub(r" at /\S+?\.rs:\d+\.?", "", text)
    m = re.search(r'msg: "(.*?)"', text)
    return (m.group(1) if m else text).strip()


CONNECT_RETRY_S = 0.25
"""How often a client tries its router again while it waits for it (`open_session`'s wait)."""


@contextmanager
def open_session(opts: ZenohOptions, wait: float = 0.0) -> Iterator[zenoh.Session]:
    """`with open_session(opts) as session:` a session for these options, closed on the way out.
    A client tries its router again for up to `wait` seconds (the command's `--wait`) while
    nothing listens at its endpoints: Zenoh fails a client's open at once then, where a peer or
    a router keeps trying in the background, so a robot, rollout worker, recorder or `swarm
    fault` started right after its router (typed back to back) exited 1 before it was up. A
    refused connection is then one line, not a traceback; a close that fails (Zenoh's "close
    operation timed out" on a link that lost its peer, under kernel loss) is a warning line,
    never the process's error: it was raised from the `with`, hid the error that ended the
    body (a world with no robot up) and failed the run of a robot that had done its work."""
    conf = opts.to_config()
    deadline = time.monotonic() + wait
    while True:
        try:
            session = zenoh.open(conf)
            break
        except zenoh.ZError as exc:
            waits = opts.mode == "client" and not any(map(_listening, opts.connect))
            if waits and time.monotonic() + CONNECT_RETRY_S < deadline:
                time.sleep(CONNECT_RETRY_S)
                continue
            where = ", ".join(opts.connect or opts.listen) or "defaults"
            within = f" within {round(wait, 1):g} s" if waits and wait > 0 else ""
            raise RuntimeError(f"cannot open a Zenoh session ({where}){within}: "
                               f"{zenoh_reason(exc)}") from None
    try:
        yield session
    finally:
        try:
            session.close()
        except zenoh.ZError as exc:
            print(f"swarm: warning: the Zenoh session did not close cleanly: {zenoh_reason(exc)}",
                  file=sys.stderr, flush=True)


def _listening(endpoint: str) -> bool:
    """Whether something accepts a TCP connection at an IP endpoint (tcp, tls, ws; quic and udp
    are taken as listening: no handshake to try). A client retries only while nothing listens:
    a refusal by a listening router (another CA's certificate, a bad TLS file) is said at once,
    not after the whole wait as if the router were absent."""
    proto, _, rest = endpoint.partition("/")
    if proto not in ("tcp", "tls", "ws"):
        return True
    host, _, port = re.split(r"[?#]", rest, maxsplit=1)[0].rpartition(":")
    try:
        with socket.create_connection((host.strip("[]"), int(port)), timeout=0.5):
            return True
    except (OSError, ValueError):
        return False


def free_port(host: str = "127.0.0.1") -> int:
    """A TCP port free on `host` right now (tests and the supervisor's hub endpoint)."""
    with socket.socket() as s:
        s.bind((host, 0))
        return int(s.getsockname()[1])
