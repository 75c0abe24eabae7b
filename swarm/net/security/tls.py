"""The Zenoh settings of a secure session (`--secure DIR`): TLS with mutual authentication, the
session's own certificate, and the access control of its identity (swarm.net.security.roles).
No torch and no `cryptography` here: a process only reads the files `swarm certs` made
(swarm.net.security.certs), and every one it needs is checked before a session opens.
"""

from __future__ import annotations

import dataclasses
import json
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from swarm.net.keys import Keys
from swarm.net.security.roles import CA_CERT, CA_KEY, ROSTER, acl, identities, is_relay, roles
from swarm.net.zconfig import no_scouting_wait
from world.config import ConfigError


@dataclass(frozen=True)
class Secure:
    """The credentials and roster one session of a secure run uses."""

    cert_dir: Path
    """Directory made by `swarm certs` (ca.pem, <identity>.pem/.key, roster.json)."""
    identity: str
    """This session's identity: the common name of its certificate."""
    run_id: str
    """The run whose keys the ACL allows."""
    robots: int
    """Robots of the roster (robot-0 .. robot-N-1)."""
    workers: int = 0
    """Rollout workers of the roster (worker-0 .. worker-K-1)."""
    extra_files: tuple[str, ...] = field(default=())
    """Other identities whose certificate and key must be present (a supervisor's children)."""
    routers: int = 0
    """Host routers of the roster (router-1 .. router-R: `swarm run --hosts R+1`)."""
    run_certs: tuple[tuple[str, str], ...] = ()
    """(identity, certificate file) issued for this run's addresses (`--hosts`, `--netns`: the
    relays' certificates naming the namespaces' addresses), used instead of DIR/<identity>.pem."""

    @classmethod
    def load(cls, cert_dir: str | Path, identity: str, run_id: str, robots: int | None = None,
             need: tuple[str, ...] = (), routers: int | None = None) -> Secure:
        """Read the roster of `cert_dir` and check every file the session (and `need`, the
        identities it will start) reads: one line naming the first file missing or unsafe."""
        d = Path(cert_dir).expanduser().resolve()
        if d.exists() and not d.is_dir():
            raise ConfigError(f"--secure {cert_dir} is not a directory (give the directory "
                              f"`swarm certs --out DIR --robots N` made)")
        if not d.is_dir():
            raise ConfigError(f"--secure {cert_dir}: no such directory (make it with "
                              f"`swarm certs --out {cert_dir} --robots N`)")
        roster: dict[str, Any] = {}
        if (d / ROSTER).exists():
            try:
                roster = json.loads((d / ROSTER).read_text())
                if not isinstance(roster, dict):
                    raise ValueError("not a JSON object (what `swarm certs` writes)")
                int(roster.get("robots", 0)), int(roster.get("workers", 0))
            except (OSError, ValueError, TypeError, AttributeError) as exc:
                raise ConfigError(f"{d / ROSTER}: {exc}") from None
        n = robots if robots is not None else int(roster.get("robots", 0))
        workers = int(roster.get("workers", 0))
        nr = routers if routers is not None else int(roster.get("routers", 0))
        kind, _, num = identity.partition("-")
        if not roster and num.isdigit():  # a host given only its own files: room for its own id
            if kind == "robot":
                n = max(n, int(num) + 1)
            elif kind == "router":
                nr = max(nr, int(num))
            else:
                workers = max(workers, int(num) + 1)
        sec = cls(d, identity, Keys(run_id).run, max(n, 1), workers, tuple(need), nr)
        if identity not in roles(Keys(run_id), sec.robots, sec.workers, sec.routers):
            raise ConfigError(f"--secure: identity {identity!r} is not in the roster of {d} "
                              f"({sec.robots} robots, {sec.workers} workers, "
                              f"{sec.routers} routers)")
        sec.check()
        return sec

    def files(self, identity: str | None = None) -> tuple[Path, Path]:
        """(certificate, key) of `identity` (default: this session's)."""
        who = identity or self.identity
        cert = dict(self.run_certs).get(who)
        return (Path(cert) if cert else self.cert_dir / f"{who}.pem"), self.cert_dir / f"{who}.key"

    def check(self) -> None:
        """Every file present, readable, PEM, and every key private to its owner."""
        paths = [self.cert_dir / CA_CERT]
        for who in (self.identity, *self.extra_files):
            paths += self.files(who)
        for p in paths:
            try:
                head = p.read_bytes()[:64]
            except FileNotFoundError:
                raise ConfigError(f"--secure: {p} is missing (run `swarm certs --out "
                                  f"{self.cert_dir} --robots N`)") from None
            except OSError as exc:
                raise ConfigError(f"--secure: cannot read {p}: {exc.strerror}") from None
            if not head.startswith(b"-----BEGIN "):
                raise ConfigError(f"--secure: {p} is not a PEM file")
            if p.suffix == ".key" and os.stat(p).st_mode & 0o077:
                raise ConfigError(f"--secure: {p} is readable by others (chmod 600 {p})")
        for who in (self.identity, *self.extra_files):
            check_identity(self.cert_dir / CA_CERT, *self.files(who), who)

    def tls(self, identity: str | None = None) -> dict[str, Any]:
        """`transport/link/tls`: this CA, this identity's certificate for both directions,
        client certificates required, the server's name checked against the endpoint."""
        cert, key = (str(p) for p in self.files(identity))
        return {"root_ca_certificate": str(self.cert_dir / CA_CERT),
                "listen_certificate": cert, "listen_private_key": key,
                "connect_certificate": cert, "connect_private_key": key,
                "enable_mtls": True, "verify_name_on_connect": True}

    def settings(self, identity: str | None = None) -> dict[str, Any]:
        """The Zenoh settings (`path -> value`) that make a session secure."""
        who = identity or self.identity
        return {"transport/link/protocols": ["tls"],
                "transport/link/tls": self.tls(who),
                "access_control": acl(who, Keys(self.run_id), self.robots, self.workers,
                                      self.routers)}

    def cfg(self) -> list[str]:
        """The settings as `--cfg KEY:JSON5` items (swarm.net.zconfig.ZenohOptions.cfg)."""
        return [f"{k}:{json.dumps(v)}" for k, v in self.settings().items()]

    def session_config(self, identity: str, mode: str, listen: list[str],
                       connect: list[str]) -> dict[str, Any]:
        """A complete Zenoh configuration (what `--zenoh-config FILE` loads) for `identity`."""
        conf: dict[str, Any] = {
            "mode": mode, "listen": {"endpoints": listen}, "connect": {"endpoints": connect},
            "scouting": {"multicast": {"enabled": False},
                         **({"delay": 0} if no_scouting_wait(mode, connect) else {})},
            "transport": {"link": {"protocols": ["tls"], "tx": {"lease": 1000},
                                   "tls": self.tls(identity)},
                          "shared_memory": {"enabled": False}},
            "access_control": acl(identity, Keys(self.run_id), self.robots, self.workers,
                                  self.routers),
        }
        return conf


def check_endpoints(endpoints: list[str], flag: str) -> None:
    """A secure session uses TLS endpoints only."""
    for e in endpoints:
        if not e.startswith("tls/"):
            raise ConfigError(f"--secure: {flag} {e} is not a TLS endpoint (use tls/HOST:PORT)")


def dumps(conf: dict[str, Any]) -> str:
    """A session configuration as JSON5 a person can read: one ACL rule, subject, policy a line."""
    acl_ = conf.get("access_control")
    rest = {k: v for k, v in conf.items() if k != "access_control"}
    text = json.dumps(rest, indent=2)[:-2]
    if acl_:
        lines = ['  "access_control": {']
        lines += [f'    "{k}": {json.dumps(acl_[k])},' for k in ("enabled", "default_permission")]
        for k in ("rules", "subjects", "policies"):
            lines += [f'    "{k}": [', *(f"      {json.dumps(x)}," for x in acl_[k]), "    ],"]
        text += ",\n" + "\n".join([*lines, "  },"])
    return text + "\n}\n"


def write_config(path: str | Path, conf: dict[str, Any], header: str) -> Path:
    """Write a session configuration as JSON5 with a comment header, 0644."""
    from swarm.common.atomic import write_text

    lines = "".join(f"// {line}\n" for line in header.splitlines())
    return write_text(path, lines + dumps(conf))


def identity_of(process: str) -> str:
    """The identity of a supervisor's child by its log name (`robot3` -> `robot-3`, `router1`
    -> `router-1`)."""
    if process.startswith("robot") and process[5:].isdigit():
        return f"robot-{process[5:]}"
    if process.startswith("worker") and process[6:].isdigit():
        return f"worker-{process[6:]}"
    if process.startswith("router") and process[6:].isdigit():
        return f"router-{process[6:]}"
    return process


def write_run_configs(sec: Secure, out_dir: str | Path, hub: str,
                      layout: dict[str, tuple[list[str], list[str]]] | None = None
                      ) -> dict[str, Path]:
    """The configuration of every session of a `swarm run` (the world listening on `hub` as the
    router, everyone else a client of it; or each identity's (listen, connect) from `layout`,
    relays in router mode), written to `out_dir/<identity>.json5` for the user to read and for
    each process to load; identity -> path."""
    out: dict[str, Path] = {}
    for who in identities(sec.robots, sec.workers, sec.routers):
        relay = is_relay(who)
        listen, connect = (layout or {}).get(who, ([hub], []) if relay else ([], [hub]))
        conf = sec.session_config(who, "router" if relay else "client", listen, connect)
        out[who] = write_config(Path(out_dir) / f"{who}.json5", conf, (
            f"Zenoh session of {who} in secure run {sec.run_id}, generated by swarm run "
            f"--secure {sec.cert_dir}.\nTLS with mutual authentication; access_control: "
            "what each neighbour (by certificate common name) may send\nto this session "
            "(ingress) and be sent by it (egress); see swarm/net/security/roles.py."))
    return out


def check_identity(ca: Path, cert: Path, key: Path, who: str) -> None:
    """What TLS would refuse only once a session tries to connect (the process then fails with
    "Unable to connect", its file unnamed, and a `swarm run` waits for it for a minute): a
    certificate that is no certificate, is not the CA's, has expired, names another identity
    or is not for its key. Checked when `cryptography` is installed (the `secure` extra)."""
    try:
        from cryptography import x509
        from cryptography.hazmat.primitives.serialization import (
            Encoding,
            PublicFormat,
            load_pem_private_key,
        )
    except ImportError:
        return
    import datetime as dt

    def bad(path: Path, why: str, delete: tuple[Path, ...] = ()) -> ConfigError:
        """The advice works as given: `swarm certs` certifies an existing key again, but
        refuses a file it cannot read and a key copied from another identity (`delete` them;
        it makes what is missing)."""
        first = f"delete {' and '.join(p.name for p in delete)}, then " if delete else ""
        return ConfigError(f"--secure: {path} {why} ({first}run `swarm certs --out "
                           f"{path.parent} --robots N` again)")

    try:
        ca_cert = x509.load_pem_x509_certificate(ca.read_bytes())
    except ValueError:
        raise bad(ca, "is not a certificate", (ca,)) from None
    try:
        c = x509.load_pem_x509_certificate(cert.read_bytes())
    except ValueError:
        raise bad(cert, "is not a certificate", (cert,)) from None
    try:
        k = load_pem_private_key(key.read_bytes(), None)
    except (ValueError, TypeError):
        raise bad(key, "is not an unencrypted private key", (key,)) from None
    try:
        c.verify_directly_issued_by(ca_cert)
    except Exception:  # (InvalidSignature: another CA's; TypeError: a key type it cannot check)
        raise bad(cert, f"is not signed by {ca.name} (another CA's?)") from None
    now = dt.datetime.now(dt.UTC)
    if not c.not_valid_before_utc <= now <= c.not_valid_after_utc:
        raise bad(cert, f"is valid {c.not_valid_before_utc:%Y-%m-%d} to "
                        f"{c.not_valid_after_utc:%Y-%m-%d}, not now")
    names = [a.value for a in c.subject.get_attributes_for_oid(x509.NameOID.COMMON_NAME)]
    if names != [who]:
        raise bad(cert, f"is for {', '.join(map(str, names)) or 'no name'}, not {who}",
                  (cert, key))  # (a pair copied from another identity: its key too)
    spki = lambda pub: pub.public_bytes(Encoding.DER, PublicFormat.SubjectPublicKeyInfo)  # noqa: E731
    if spki(c.public_key()) != spki(k.public_key()):  # (any key type: EC, RSA, Ed25519)
        raise bad(cert, f"is not for the key {key.name}", (cert, key))


def run_identities(robots: int, learner: bool = False, recorder: bool = False,
                   routers: int = 0) -> tuple[str, ...]:
    """Every identity whose certificate a `swarm run --secure` reads (besides its own)."""
    return ("world", *(f"robot-{i}" for i in range(robots)), *(("learner",) if learner else ()),
            *(("recorder",) if recorder else ()), *(f"router-{h}" for h in range(1, routers + 1)))


def run_configs(cert_dir: str | Path, run_id: str, robots: int, port: int, out_dir: Path,
                learner: bool = False, recorder: bool = False) -> tuple[str, dict[str, Path]]:
    """(hub endpoint, identity -> config file) of a `swarm run --secure` whose world listens on
    127.0.0.1:`port`; every certificate the run's processes read is checked first."""
    sec = Secure.load(cert_dir, "supervisor", run_id, robots,
                      need=run_identities(robots, learner, recorder))
    hub = f"tls/127.0.0.1:{port}"
    return hub, write_run_configs(sec, out_dir, hub)


def topology_secure(cert_dir: str | Path, run_id: str, robots: int, hosts: int = 0,
                    learner: bool = False, recorder: bool = False) -> Secure:
    """The supervisor's credentials for `swarm run --secure DIR` with `--hosts K` (hosts >= 1) or
    `--netns` (hosts 0), checked before any spawn: the run's files, the routers' keys (`swarm
    certs --routers K-1`) and the CA key, with which `topology_configs` names the run's
    addresses in the world's (and routers') certificates."""
    routers = max(hosts - 1, 0)
    need = run_identities(robots, learner, recorder, routers)
    d = Path(cert_dir).expanduser().resolve()
    if not d.is_dir():
        Secure.load(cert_dir, "supervisor", run_id, robots)  # its one-line "no such directory"
    missing = [f"router-{h}" for h in range(1, routers + 1) if not (d / f"router-{h}.key").exists()]
    if missing:
        raise ConfigError(f"--secure {cert_dir} --hosts {hosts}: no key for {missing[0]} (run "
                          f"`swarm certs --out {cert_dir} --robots {robots} --routers "
                          f"{routers}`)")
    sec = Secure.load(cert_dir, "supervisor", run_id, robots, need=need, routers=routers)
    ca_key = d / CA_KEY
    if not os.access(ca_key, os.R_OK):
        raise ConfigError(f"--secure {cert_dir}: {ca_key} is needed to name the run's namespace "
                          "addresses in the world's and routers' certificates")
    from swarm.net.security.certs import crypto

    crypto()  # the `cryptography` package, before anything starts
    return sec


def topology_configs(sec: Secure, topo: Any, port: int,
                     out_dir: Path) -> tuple[str, dict[str, Path]]:
    """(hub, identity -> config file) of a secure run in namespaces (`topo`: an up
    `swarm.net.kernel.hosts.Hosts` or `swarm.net.kernel.netns.Topology`), every endpoint TLS:
    the world's (and each host router's) certificate issued again for the same key, naming the
    addresses it is reached at (chosen when the run starts, so `swarm certs` cannot know them),
    into `out_dir/run-certs`."""
    from swarm.net.security.certs import run_certs

    topo.transport = "tls"
    made = run_certs(sec.cert_dir, Path(out_dir) / "run-certs", topo.relay_addresses())
    sec = dataclasses.replace(sec, run_certs=tuple((k, str(v)) for k, v in made.items()))
    listen = topo.world_listen(port)
    layout = {"world": (listen, []),
              **{f"router-{h}": topo.router_endpoints(h, port) for h in range(1, sec.routers + 1)},
              **{f"robot-{i}": ([], [topo.robot_endpoint(i, port)]) for i in range(sec.robots)}}
    return listen[0], write_run_configs(sec, out_dir, listen[0], layout)


def apply(opts: Any, sec: Secure) -> Any:
    """`ZenohOptions` made secure: TLS endpoints only (a listening session defaults to
    tls/127.0.0.1:0), this identity's TLS settings and ACL applied before any `--cfg`."""
    check_endpoints(opts.connect, "--connect")
    check_endpoints(opts.listen, "--listen")
    listen = opts.listen or ([] if opts.mode == "client" or opts.config_file
                             else ["tls/127.0.0.1:0"])
    new = dataclasses.replace(opts, listen=listen, cfg=[*sec.cfg(), *opts.cfg])
    new.to_config()
    return new


TEMPLATE_HEADER = """{what}, as `--secure` generates it
(run id RUN, 3 robots, certificates in /etc/swarm/certs; the world at WORLD_HOST:7448, a second
host's router, router-1, at ROUTER_HOST:7448).
Do not edit by hand: `swarm run --secure DIR` writes one per process into LOG_DIR/zenoh/, and
`swarm world|robot|learner|rollout-worker|fault --secure DIR` build theirs in memory.
Regenerate: python -c 'from swarm.net.security.tls import write_templates; write_templates()'
(tests/test_secure.py fails when this file and the generator disagree).
Make the certificates with `swarm certs --out /etc/swarm/certs --robots 3 --routers 1
--host WORLD_HOST --host ROUTER_HOST`."""


def templates() -> dict[str, str]:
    """deploy/ file name -> text of the example configs of a 3-robot run on real hosts."""
    sec = Secure(Path("/etc/swarm/certs"), "world", "RUN", 3, routers=1)
    hub = "tls/WORLD_HOST:7448"
    out = {}
    for name, who, mode, listen, connect, what in (
            ("tls-acl.json5", "world", "router", ["tls/0.0.0.0:7448"], [],
             "The world (the router every other process connects to) of a secure run"),
            ("tls-acl-robot.json5", "robot-0", "client", [], [hub],
             "Robot 0 of a secure run, on its own host"),
            ("tls-acl-router.json5", "router-1", "router", ["tls/0.0.0.0:7448"], [hub],
             "Router 1 of a secure run (`swarm router --secure DIR --router-id 1`): the\n"
             "router of a second host, whose processes connect to it")):
        text = "".join(f"// {line}\n" for line in TEMPLATE_HEADER.format(what=what).splitlines())
        out[name] = text + dumps(sec.session_config(who, mode, listen, connect))
    return out


def write_templates(deploy: str | Path = "deploy") -> None:
    """Rewrite the deploy/ examples from the generator."""
    for name, text in templates().items():
        (Path(deploy) / name).write_text(text)
