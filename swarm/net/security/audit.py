"""`swarm audit`: attack a running swarm as a foreign peer and report what got through.

Sessions tried against the run's hub endpoint, in this order:

- `plain_tcp`: no TLS at all (`tcp/HOST:PORT`, no credentials);
- `tls_without_certificate`: TLS trusting the run's CA, but no client certificate;
- `wrong_ca`: a certificate with the attacker's name (default robot-3) from another,
  self-signed CA (needs the `cryptography` package; skipped without it);
- `valid_<identity>`: the attacker's real certificate of the run (with `--secure DIR`).

Each session that opens forges well-formed messages for `duration` seconds: the victim robot's
action (default robot 4) for every tick it sees on the attacker's observation key, a weights
message of a far-future version, and a control record (a no-op, or `stop` with `stop=True`);
and puts one message on a key the attacker's identity owns (`own_key`), which must get through
on a valid session: proof that the session was connected and the witness sees what passes. A
witness session (identity `recorder` with `--secure`, plain otherwise) subscribes to those keys
and counts the forged messages it receives, each known by its attachment (the audit's nonce,
the session's name and the kind: the payloads themselves are what a real process would send, so a
forged control record is one the run acts on). Zenoh's ACL drops a refused message
inside the router, so "never reached anyone" is what the witness can show; the run's own
counters (and its metrics against the same run without `--secure`) show the rest.
"""

from __future__ import annotations

import json
import secrets
import shutil
import tempfile
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import zenoh

from swarm.net.keys import Keys
from swarm.net.learning import Weights
from swarm.net.messages import K_CONTROL, K_OBS, Action, pack_record, peek_tick
from swarm.net.security.tls import Secure
from swarm.net.zconfig import zenoh_reason
from world.config import ConfigError

MARK_MS = 4242.4242  # planning_ms of a forged action: no robot plans this long
FORGED = ("action", "weights", "control")


@dataclass
class Attempt:
    """One foreign session: did it open, what it sent, what the witness saw of it."""

    name: str
    connected: bool = False
    error: str = ""
    ticks_seen: int = 0
    sent: dict[str, int] = field(default_factory=dict)
    delivered: dict[str, int] = field(default_factory=dict)


def _conf(endpoint: str, tls: dict[str, Any] | None) -> zenoh.Config:
    conf = zenoh.Config()
    conf.insert_json5("mode", '"client"')
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("connect/endpoints", json.dumps([endpoint]))
    conf.insert_json5("transport/shared_memory/enabled", "false")
    if tls is not None:
        conf.insert_json5("transport/link/tls", json.dumps(tls))
    return conf


def _swap(endpoint: str, proto: str) -> str:
    return proto + "/" + endpoint.split("/", 1)[1]


class Audit:
    """The attack on run `run_id` at `endpoint` (plain or tls)."""

    def __init__(self, run_id: str, endpoint: str, secure: Secure | None = None,
                 attacker: int = 3, victim: int = 4, duration: float = 2.0,
                 stop: bool = False) -> None:
        self.keys, self.endpoint, self.secure = Keys(run_id), endpoint, secure
        self.attacker, self.victim, self.duration, self.stop = attacker, victim, duration, stop
        self.nonce = secrets.token_hex(4)
        self.attempts: list[Attempt] = []
        self._lock = threading.Lock()
        self.own_key = self.keys.rollout(attacker)
        self._tmp: str | None = None  # the throw-away CA's directory

    # --- the witness ------------------------------------------------------------------------
    def _witness(self) -> zenoh.Session:
        return witness_session(self.endpoint, self.secure)

    def _mark(self, a: Attempt, kind: str) -> bytes:
        """The attachment of attempt `a`'s forged message of `kind` (the run ignores it)."""
        return f"swarm-audit {self.nonce} {a.name} {kind}".encode()

    def _seen(self, sample: zenoh.Sample) -> None:
        att = sample.attachment
        if att is None:
            return
        tag, nonce, name, kind = (att.to_bytes().decode(errors="replace").split(" ") + [""] * 4)[:4]
        if tag != "swarm-audit" or nonce != self.nonce:
            return  # the run's own traffic, or another audit's
        with self._lock:
            for a in self.attempts:
                if a.name == name:
                    a.delivered[kind] = a.delivered.get(kind, 0) + 1

    # --- the attackers ----------------------------------------------------------------------
    def sessions(self) -> list[tuple[str, str, dict[str, Any] | None]]:
        """(name, endpoint, tls settings or None) of every foreign session to try."""
        ep, who = self.endpoint, f"robot-{self.attacker}"
        tls_ep = ep if ep.startswith("tls/") else _swap(ep, "tls")
        out: list[tuple[str, str, dict[str, Any] | None]] = [("plain_tcp", _swap(ep, "tcp"), None)]
        if self.secure is not None:
            ca = str(self.secure.cert_dir / "ca.pem")
            out.append(("tls_without_certificate", tls_ep,
                        {"root_ca_certificate": ca, "verify_name_on_connect": True}))
        foreign = self._foreign_certs(who)
        if foreign is not None:  # it trusts the run's CA, so only the run can refuse it
            cert, key = str(foreign / f"{who}.pem"), str(foreign / f"{who}.key")
            ca = self.secure.cert_dir / "ca.pem" if self.secure else foreign / "ca.pem"
            out.append(("wrong_ca", tls_ep, {
                "root_ca_certificate": str(ca), "connect_certificate": cert,
                "connect_private_key": key, "verify_name_on_connect": True}))
        if self.secure is not None:
            out.append((f"valid_{who}", tls_ep, self.secure.tls(who)))
        return out

    def _foreign_certs(self, who: str) -> Path | None:
        """A throw-away CA and a certificate named `who` from it (None without cryptography)."""
        try:
            from swarm.net.security.certs import make_certs

            self._tmp = tempfile.mkdtemp(prefix="swarm-audit-")
            d = Path(self._tmp) / "foreign"
            make_certs(d, robots=self.attacker + 1)
            return d
        except Exception:  # noqa: BLE001 (no cryptography: that session is skipped)
            return None

    def _forge(self, a: Attempt, session: zenoh.Session) -> None:
        k = self.keys
        ticks: list[tuple[int, int] | None] = []  # (None: not an observation)
        session.declare_subscriber(k.obs(self.attacker),
                                   lambda s: ticks.append(peek_tick(s.payload.to_bytes(), K_OBS)))

        def put(kind: str, key: str, payload: bytes) -> None:
            session.put(key, payload, attachment=self._mark(a, kind))
            a.sent[kind] = a.sent.get(kind, 0) + 1

        weights = Weights("audit", 2**31 - 2, {"audit": self.nonce},
                          {"forged": np.zeros(1, dtype=np.float32)}).pack()
        # (a field of its own would make the run drop it as malformed: `--stop` would stop
        # nothing)
        control = pack_record(K_CONTROL, {"stop": True} if self.stop else {"process": []})
        put("own_key", self.own_key, f"swarm audit {self.nonce} {a.name}".encode())
        put("weights", k.weights, weights)
        put("control", k.control, control)
        done: set[tuple[int, int]] = set()
        deadline = time.monotonic() + self.duration
        while time.monotonic() < deadline:
            for tick in list(ticks):
                if tick is not None and tick not in done:
                    done.add(tick)
                    ep, t = tick
                    put("action", k.action(self.victim),
                        Action(ep, t, self.victim, 0, MARK_MS).pack())
            time.sleep(0.005)
        if not done:  # no tick seen: one forged action for the first tick
            put("action", k.action(self.victim), Action(0, 0, self.victim, 0, MARK_MS).pack())
        a.ticks_seen = len(done)

    def attempt(self, name: str, endpoint: str, tls: dict[str, Any] | None) -> Attempt:
        a = Attempt(name)
        with self._lock:
            self.attempts.append(a)
        try:
            session = zenoh.open(_conf(endpoint, tls))
        except zenoh.ZError as exc:
            a.error = zenoh_reason(exc)
            return a
        a.connected = True
        try:
            time.sleep(0.3)  # let the session's subscriptions and declarations settle
            self._forge(a, session)
        finally:
            session.close()
        return a

    def run(self) -> dict[str, Any]:
        k = self.keys
        with self._witness() as witness:
            subs = [witness.declare_subscriber(key, self._seen) for key in
                    (k.action(self.victim), k.weights, k.control, self.own_key)]
            time.sleep(0.3)
            try:
                for name, ep, tls in self.sessions():
                    self.attempt(name, ep, tls)
            finally:
                if self._tmp is not None:
                    shutil.rmtree(self._tmp, ignore_errors=True)
            time.sleep(0.5)  # what was let through has reached the witness by now
            for s in subs:
                s.undeclare()
        return self.report()

    def report(self) -> dict[str, Any]:
        sessions = {a.name: {"connected": a.connected, "error": a.error,
                             "ticks_seen": a.ticks_seen, "sent": dict(a.sent),
                             "delivered": {kind: a.delivered.get(kind, 0)
                                           for kind in (*FORGED, "own_key") if kind in a.sent}}
                    for a in self.attempts}
        accepted = sum(a.delivered.get(kind, 0) for a in self.attempts for kind in FORGED)
        valid = [a for a in self.attempts if a.name.startswith("valid_")]
        witnessed = all(a.delivered.get("own_key", 0) > 0 for a in valid)
        return {"run": self.keys.run, "endpoint": self.endpoint,
                "secure": self.secure is not None, "attacker": f"robot-{self.attacker}",
                "victim": self.victim, "sessions": sessions, "accepted": accepted,
                "connected": [a.name for a in self.attempts if a.connected],
                "witness_ok": witnessed,
                "verdict": "pass" if accepted == 0 and witnessed and
                all(not a.connected for a in self.attempts if not a.name.startswith("valid_"))
                else "fail"}


def witness_session(endpoint: str, secure: Secure | None) -> zenoh.Session:
    """The witness's session into the run at `endpoint` (the recorder identity with `secure`;
    it may also ask the world for the run's record, which `swarm audit` checks --as and
    --victim against before any attack); RuntimeError if it cannot join."""
    tls = None
    if secure is not None:
        tls = secure.tls("recorder")
    elif endpoint.startswith("tls/"):
        raise RuntimeError("the run's endpoint is TLS: give --secure DIR (the witness "
                           "uses the recorder identity)")
    try:
        return zenoh.open(_conf(endpoint, tls))
    except zenoh.ZError as exc:
        raise RuntimeError(f"the witness cannot join the run at {endpoint}: "
                           f"{zenoh_reason(exc)}") from None


def team_ids(n: int, attacker: int | None, victim: int | None) -> tuple[int, int]:
    """(attacker, victim) robot ids within a team of `n` robots: a given id is checked against
    the team (ConfigError naming its flag), a missing one chosen in it (robot 3 forging robot
    4's action on a team of at least 5; on a smaller team its last two robots)."""
    if n < 2:
        raise ConfigError(f"the run has {n} robot: --as and --victim must be two different "
                          "robots of its team")
    for flag, v in (("--as", attacker), ("--victim", victim)):
        if v is not None and not 0 <= v < n:
            raise ConfigError(f"{flag} {v} is not a robot of the run: its team has robots "
                              f"0..{n - 1}")
    if attacker is None:
        attacker = next(i for i in (min(3, n - 2), *range(n)) if i != victim)
    if victim is None:
        victim = next(i for i in (min(4, n - 1), *range(n)) if i != attacker)
    if attacker == victim:
        raise ConfigError("--as and --victim must be two different robot ids")
    return attacker, victim


def main(run_id: str, endpoint: str, secure: Secure | None = None, attacker: int = 3,
         victim: int = 4, duration: float = 2.0, stop: bool = False) -> dict[str, Any]:
    """Attack run `run_id` at `endpoint` and return the report."""
    return Audit(run_id, endpoint, secure, attacker, victim, duration, stop).run()
