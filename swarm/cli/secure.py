"""Command-line front ends of a run's security: `swarm certs`, `swarm audit`, and `--secure DIR`
for the commands that open a session into a run (swarm.net.security holds the rules)."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from swarm.cli.common import output_file, path_name
from world.config import ConfigError


def add_secure_flag(p: argparse.ArgumentParser) -> None:
    """`--secure DIR` on a command that opens a session into a run."""
    p.add_argument("--secure", metavar="DIR", type=_cert_dir,
                   help="TLS with mutual authentication and the run's access control, with the "
                        "certificates of DIR (made by `swarm certs`)")


def _cert_dir(text: str) -> str:
    """`--secure` value: an empty or blank name is refused, never read as "not given" (no TLS)."""
    if not text.strip():
        raise argparse.ArgumentTypeError("wants the certificate directory, got an empty name")
    return text


def secure_options(args: argparse.Namespace, zopts: Any, identity: str, run_id: str,
                   robots: int | None = None) -> Any:
    """`zopts` made secure for `identity` when `--secure DIR` was given (else unchanged); every
    file it needs is checked here, before a session opens: one line, exit status 2."""
    if getattr(args, "secure", None) is None:
        return zopts
    path_name(args.secure, "--secure")
    from swarm.net.security.tls import Secure, apply

    return apply(zopts, Secure.load(args.secure, identity, run_id, robots))


def check_run_secure(args: argparse.Namespace, run_id: str, robots: int,
                     learner: bool) -> None:
    """`swarm run --secure DIR`: every certificate and key the run reads, checked before the
    supervisor makes the run's temp folder (it checks them again as it writes the sessions'
    configs there; a run of more robots than the directory has certificates for was refused
    only then, its temp folder left behind)."""
    if args.secure is None:
        return
    from swarm.net.security.tls import Secure, run_identities, topology_secure

    path_name(args.secure, "--secure")
    recorder = getattr(args, "record", None) is not None
    if getattr(args, "hosts", None) or getattr(args, "netns", False):
        topology_secure(args.secure, run_id, robots, args.hosts or 0, learner, recorder)
    else:
        Secure.load(args.secure, "supervisor", run_id, robots,
                    need=run_identities(robots, learner, recorder))


def cmd_certs(args: argparse.Namespace) -> int:
    from rich.table import Table

    from swarm.cli.common import _consoles
    from swarm.net.security.certs import make_certs

    path_name(args.out, "--out")
    output_file(args.json)
    if args.json and Path(args.json).resolve().parent == Path(args.out).resolve():
        raise ConfigError(f"--json {args.json} is in --out {args.out}, which holds the "  # (it
                          "certificates and keys: write it elsewhere")  # replaced ca.pem)
    rep = make_certs(args.out, args.robots, args.workers, args.host, args.days, args.routers)
    out, _ = _consoles()
    t = Table(title=f"swarm certs {args.out}")
    t.add_column("what")
    t.add_column("files", overflow="fold")
    for what, files in (("made", rep.made), ("reissued (same key)", rep.reissued),
                        ("kept", rep.kept)):
        t.add_row(what, ", ".join(files) or "-")
    out.print(t)
    out.print("keys are 0600 in a 0700 directory; copy ca.pem, roster.json and only each host's "
              "own <identity>.pem/.key to it")
    if args.json:
        from swarm.common.atomic import write_json

        write_json(args.json, {"out": args.out, "made": rep.made, "reissued": rep.reissued,
                               "kept": rep.kept})
    return 0


def cmd_audit(args: argparse.Namespace) -> int:
    from swarm.common.spawn import lookup_run
    from swarm.net.keys import Keys
    from swarm.net.security.audit import main as audit_main
    from swarm.net.security.audit import team_ids
    from swarm.net.security.tls import Secure
    from swarm.net.zconfig import check_endpoint

    Keys(args.run)
    for flag, v in (("--as", args.attacker), ("--victim", args.victim)):
        if v is not None and not 0 <= v < 4096:
            raise ConfigError(f"{flag} must be a robot id, got {v}")
    if args.attacker is not None and args.attacker == args.victim:
        raise ConfigError("--as and --victim must be two different robot ids")
    if not 0.1 <= args.duration <= 600:
        raise ConfigError(f"--duration must lie in [0.1, 600] s, got {args.duration}")
    output_file(args.json)
    endpoint = check_endpoint(args.connect) if args.connect else lookup_run(args.run)
    if not endpoint.startswith(("tcp/", "tls/")):
        raise ConfigError(f"--connect {endpoint}: expected tcp/HOST:PORT or tls/HOST:PORT")
    if endpoint.startswith("tls/") and not args.secure:
        raise ConfigError(f"run {args.run} is secure ({endpoint}): give --secure DIR (the "
                          "witness uses the recorder identity)")
    sec = Secure.load(args.secure, "recorder", args.run) if args.secure else None
    attacker, victim = team_ids(_team_size(args.run, endpoint, sec), args.attacker, args.victim)
    if sec is not None:  # the witness is the recorder; the attacker holds robot I's credentials
        mine = Path(args.secure) / f"robot-{attacker}.pem"
        if not mine.is_file():  # certificates made for a smaller team than the run's
            raise ConfigError(f"--as {attacker}: {mine} is missing; pick --as and --victim "
                              "among the robots of the certificate directory")
        sec = Secure.load(args.secure, "recorder", args.run, need=(f"robot-{attacker}",))
    rep = audit_main(args.run, endpoint, sec, attacker, victim, args.duration, args.stop)
    _print_audit(rep)
    if args.json:
        from swarm.common.atomic import write_json

        write_json(args.json, rep)
    return 0 if rep["verdict"] == "pass" else 1


AUDIT_WAIT_S = 10.0  # how long `swarm audit` waits for the world to serve the run's record


def _team_size(run_id: str, endpoint: str, sec: Any) -> int:
    """The number of robots of run `run_id`, from the record its world serves (as `swarm fault`
    fetches it), asked by the audit's witness identity; ConfigError if it does not answer."""
    from swarm.net.keys import Keys
    from swarm.net.messages import BadMessage
    from swarm.net.security.audit import witness_session
    from swarm.procs.robot_status import fetch_config

    with witness_session(endpoint, sec) as session:
        try:
            return fetch_config(session, Keys(run_id), AUDIT_WAIT_S).world.n_robots
        except (TimeoutError, BadMessage) as exc:
            raise ConfigError(f"run {run_id} did not answer at {endpoint} ({exc}); nothing "
                              "was sent") from None


def _print_audit(rep: dict[str, Any]) -> None:
    from rich.table import Table

    from swarm.cli.common import _consoles

    out, _ = _consoles()
    t = Table(title=f"swarm audit of run {rep['run']} at {rep['endpoint']} "
                    f"({'secure' if rep['secure'] else 'not secure'})")
    for col in ("session", "connected", "forged action / weights / control delivered",
                "own key delivered", "why refused"):
        t.add_column(col, overflow="fold")
    for name, s in rep["sessions"].items():
        d = s["delivered"]
        forged = " / ".join(f"{d.get(k, 0)} of {s['sent'].get(k, 0)}"
                            for k in ("action", "weights", "control")) if s["connected"] else "-"
        own = f"{d.get('own_key', 0)} of {s['sent'].get('own_key', 0)}" if s["connected"] \
            else "-"
        t.add_row(name, "yes" if s["connected"] else "no", forged, own, s["error"][:80])
    out.print(t)
    out.print(f"forged messages accepted: {rep['accepted']}   witness saw the valid session's own "
              f"key: {rep['witness_ok']}   verdict: {rep['verdict']}")


def add_parsers(sub: Any) -> None:
    """Register `certs` and `audit` on the `swarm` subparsers."""
    p = sub.add_parser("certs", help="make a CA and one certificate per process identity",
                       description="Make (or complete) DIR: a CA, one ECDSA P-256 certificate + "
                                   "key per identity (world, supervisor, learner, operator, "
                                   "recorder, robot-0..N-1, worker-0..K-1, router-1..R) for "
                                   "`--secure DIR`. "
                                   "Re-running adds what is missing and never overwrites a key.")
    p.add_argument("--out", required=True, metavar="DIR", help="certificate directory (0700)")
    p.add_argument("--robots", type=int, required=True, metavar="N", help="robot identities")
    p.add_argument("--workers", type=int, default=0, metavar="K",
                   help="rollout-worker identities (default 0)")
    p.add_argument("--routers", type=int, default=0, metavar="R",
                   help="host-router identities router-1..R (default 0; `swarm run --hosts "
                        "R+1 --secure DIR` needs R = hosts - 1)")
    p.add_argument("--host", action="append", default=[], metavar="NAME|IP",
                   help="a host name or address the processes are reached at, besides "
                        "127.0.0.1/localhost (repeatable; in every certificate)")
    p.add_argument("--days", type=int, default=825, help="validity in days (default 825)")
    p.add_argument("--json", metavar="FILE", help="write what was made as one JSON object")
    p.set_defaults(func=cmd_certs)

    p = sub.add_parser("audit", help="attack a running swarm as a foreign peer",
                       description="Try, as a foreign peer, to join run RUN without credentials, "
                                   "with a certificate of another CA, and with a valid robot "
                                   "certificate to put another robot's action, weights and "
                                   "control; report what got through (exit 1 if anything "
                                   "forged did).")
    p.add_argument("--run", required=True, help="run id")
    p.add_argument("--connect", metavar="ENDPOINT",
                   help="the run's hub endpoint (default: the local registry of `swarm run`)")
    add_secure_flag(p)
    p.add_argument("--as", dest="attacker", type=int, default=None, metavar="I",
                   help="robot identity the attacker holds, one of the run's robots (default "
                        "3; on a team of fewer than 5, its second to last robot)")
    p.add_argument("--victim", type=int, default=None, metavar="J",
                   help="robot whose action is forged, one of the run's robots (default 4; on "
                        "a team of fewer than 5, its last robot)")
    p.add_argument("--duration", type=float, default=2.0, metavar="S",
                   help="seconds each session forges actions (default 2)")
    p.add_argument("--stop", action="store_true",
                   help="forge a stop request as the control message (default: a no-op one)")
    p.add_argument("--json", metavar="FILE", help="write the report as one JSON object")
    p.set_defaults(func=cmd_audit)
