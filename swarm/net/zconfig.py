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


def add_arguments(parser: argparse.ArgumentParser) -> None:
    g = parser.add_argument_group("zenoh")
    g.add_argument("--zenoh-mode", default="peer", choices=["peer", "client", "router"])
    g.add_argument("--connect", action="append", default=[], metavar="ENDPOINT",
                   help="endpoint to connect to, e.g. tcp/127.0.0.1:7447 (repeatable)")
    g.add_argument("--listen", action="append", default=[], metavar="ENDPOINT",
                   help="endpoint to listen on (repeatable; default tcp/127.0.0.1:0)")
    g.add_argument("--zenoh-config", default=None, metavar="FILE", help="JSON5 Zenoh config file")
    g.add_argument("--cfg", action="append", default=[], metavar="KEY:JSON5",
                   help="extra Zenoh setting applied last (repeatable)")


def from_args(args: argparse.Namespace) -> ZenohOptions:
    """The options of the flags, checked at once (before any session or process exists)."""
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


def open_session(opts: ZenohOptions) -> zenoh.Session:
    """A session for these options; a refused connection is one line, not a traceback."""
    conf = opts.to_config()
    try:
        return zenoh.open(conf)
    except zenoh.ZError as exc:
        where = ", ".join(opts.connect or opts.listen) or "defaults"
        raise RuntimeError(f"cannot open a Zenoh session ({where}): {zenoh_reason(exc)}") from None


def free_port(host: str = "127.0.0.1") -> int:
    """A TCP port free on `host` right now (tests and the supervisor's hub endpoint)."""
    with socket.socket() as s:
        s.bind((host, 0))
        return int(s.getsockname()[1])
