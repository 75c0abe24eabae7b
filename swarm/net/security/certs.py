"""The run's certificates: one CA and one ECDSA P-256 certificate + key per process identity.

`make_certs(DIR, robots, workers, hosts)` writes `ca.pem`/`ca.key` and `<identity>.pem`/`.key`
for every identity of `swarm.net.security.roles.identities` (world, supervisor, learner, operator,
recorder, robot-0.., worker-0..) plus `roster.json` (how many robots and workers it covers).
The directory is 0700 and every key 0600. Re-running adds what is missing and never touches an
existing key: a certificate whose key exists but which is missing, signed by another CA or lacks
one of the requested host names is issued again for that same key.

Certificates are what Zenoh's TLS (rustls / webpki) accepts: v3, a subjectAltName with
127.0.0.1, ::1, localhost and every `--host`, EKU serverAuth + clientAuth (every session both
listens and connects), and the identity as the subject's common name, which the generated
`access_control` matches with `cert_common_names`. `cryptography` is imported only here, so
processes that never make certificates never load it.
"""

from __future__ import annotations

import datetime as dt
import ipaddress
import json
import os
import shutil
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from swarm.net.security.roles import CA_CERT, CA_KEY, ROSTER, identities
from world.config import ConfigError

ORG = "commattn-swarm"
LOCAL_HOSTS = ("127.0.0.1", "::1", "localhost")


@dataclass
class CertsReport:
    """What one `make_certs` call did, file by file."""

    made: list[str] = field(default_factory=list)
    """Keys and certificates written by this call."""
    reissued: list[str] = field(default_factory=list)
    """Certificates issued again for an existing key (missing, other CA, or new host names)."""
    kept: list[str] = field(default_factory=list)
    """Identities whose key and certificate were already right."""


def crypto() -> Any:
    """The `cryptography` modules used here; without the package, a one-line ConfigError."""
    try:
        import cryptography  # noqa: F401
    except ImportError:
        raise ConfigError("swarm certs needs the 'cryptography' package: "
                          "pip install 'commattn-swarm[secure]'") from None
    from cryptography import x509
    from cryptography.hazmat.primitives import hashes, serialization
    from cryptography.hazmat.primitives.asymmetric import ec
    from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

    return x509, hashes, serialization, ec, ExtendedKeyUsageOID, NameOID


def _write_new(path: Path, data: bytes, mode: int) -> None:
    """Create `path` with `mode` (fails if it exists: a key is never overwritten)."""
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, mode)
    with os.fdopen(fd, "wb") as fh:
        fh.write(data)
        fh.flush()
        os.fsync(fh.fileno())


def _write_cert(path: Path, data: bytes) -> None:
    """A certificate is public: replaced atomically, 0644."""
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.unlink(missing_ok=True)
    _write_new(tmp, data, 0o644)
    os.replace(tmp, path)


def _sans(hosts: list[str]) -> list[str]:
    out: list[str] = []
    for h in [*LOCAL_HOSTS, *hosts]:
        if h not in out:
            out.append(h)
    return out


def check_hosts(hosts: list[str]) -> list[str]:
    """Host names or IP addresses for the subjectAltName; a bad one is a ConfigError. A name is
    ASCII letters, digits and hyphens (an internationalized one goes in as its xn-- A-label:
    'ü日本' passed isalnum and made x509 raise after the CA was written)."""
    for h in hosts:
        try:
            ipaddress.ip_address(h)
            continue
        except ValueError:
            pass
        labels = h.rstrip(".").split(".")
        if not h or len(h) > 253 or not all(
                lab and len(lab) <= 63 and lab.isascii() and lab.replace("-", "").isalnum()
                and lab[0] != "-"
                for lab in labels):
            raise ConfigError(f"--host {h!r} is neither an IP address nor a DNS name")
    return list(hosts)


class _Issuer:
    """Signs with the CA of a directory (made on first use)."""

    def __init__(self, out: Path, days: int, report: CertsReport, create: bool = True) -> None:
        self.x509, self.hashes, self.ser, self.ec, self.EKU, self.NameOID = crypto()
        self.out, self.days, self.report = out, days, report
        if not create and not (out / CA_CERT).exists():
            raise ConfigError(f"{out / CA_CERT} is missing (run `swarm certs --out {out}`)")
        self.key = self._key(out / CA_KEY, "ca", create)
        cert_path = out / CA_CERT
        cert = self._load_cert(cert_path)
        if cert is not None and cert.public_key().public_numbers() != \
                self.key.public_key().public_numbers():
            raise ConfigError(f"{cert_path} does not match {out / CA_KEY}; move one of them away")
        if cert is None:
            cert = self._ca_cert()
            _write_cert(cert_path, cert.public_bytes(self.ser.Encoding.PEM))
            report.made.append(CA_CERT)
        self.cert = cert

    def _load_cert(self, path: Path) -> Any:
        if not path.exists():
            return None
        try:
            return self.x509.load_pem_x509_certificate(path.read_bytes())
        except ValueError:
            raise ConfigError(f"{path} is not a PEM certificate") from None

    def _key(self, path: Path, who: str, create: bool = True) -> Any:
        """The existing key at `path`, or a new one written 0600 (`create`; else an error)."""
        if not create and not path.exists():
            raise ConfigError(f"{path} is missing (run `swarm certs --out {path.parent}`)")
        if path.exists():
            try:
                key = self.ser.load_pem_private_key(path.read_bytes(), password=None)
            except (ValueError, TypeError):
                raise ConfigError(f"{path} is not an unencrypted PEM private key") from None
            if path.stat().st_mode & 0o077:
                os.chmod(path, 0o600)
            return key
        key = self.ec.generate_private_key(self.ec.SECP256R1())
        pem = key.private_bytes(self.ser.Encoding.PEM, self.ser.PrivateFormat.PKCS8,
                                self.ser.NoEncryption())
        _write_new(path, pem, 0o600)
        self.report.made.append(path.name)
        return key

    def one_key_each(self, cns: list[str]) -> None:
        """ConfigError (one line) if two existing keys among the CA's and `cns`' are one key:
        certifying both would give one key two identities (a key copied from another file)."""
        seen: dict[Any, str] = {self.key.public_key().public_numbers(): CA_KEY}
        for cn in cns:
            path = self.out / f"{cn}.key"
            if not path.exists():
                continue
            pub = self._key(path, cn, create=False).public_key().public_numbers()
            if pub in seen:
                raise ConfigError(f"{path} holds the same key as {self.out / seen[pub]}: one key "
                                  f"per identity (delete the copy and rerun; a new one is made)")
            seen[pub] = path.name

    def _name(self, cn: str) -> Any:
        x = self.x509
        return x.Name([x.NameAttribute(self.NameOID.ORGANIZATION_NAME, ORG),
                       x.NameAttribute(self.NameOID.COMMON_NAME, cn)])

    def _builder(self, subject: Any, public_key: Any, days: int) -> Any:
        now = dt.datetime.now(dt.UTC)
        x = self.x509
        return (x.CertificateBuilder().subject_name(subject).public_key(public_key)
                .serial_number(x.random_serial_number())
                .not_valid_before(now - dt.timedelta(hours=1))
                .not_valid_after(now + dt.timedelta(days=days))
                .add_extension(x.SubjectKeyIdentifier.from_public_key(public_key), critical=False))

    def _ca_cert(self) -> Any:
        x = self.x509
        name = self._name(f"{ORG} CA")
        return (self._builder(name, self.key.public_key(), self.days).issuer_name(name)
                .add_extension(x.BasicConstraints(ca=True, path_length=0), critical=True)
                .add_extension(x.KeyUsage(digital_signature=True, content_commitment=False,
                                          key_encipherment=False, data_encipherment=False,
                                          key_agreement=False, key_cert_sign=True, crl_sign=True,
                                          encipher_only=False, decipher_only=False),
                               critical=True)
                .sign(self.key, self.hashes.SHA256()))

    def _fits(self, cert: Any, key: Any, cn: str, sans: list[str]) -> bool:
        """`cert` is this CA's, for `key`, named `cn`, and names every host in `sans`."""
        x = self.x509
        try:
            cert.verify_directly_issued_by(self.cert)
            names = cert.subject.get_attributes_for_oid(self.NameOID.COMMON_NAME)
            alt = cert.extensions.get_extension_for_class(x.SubjectAlternativeName).value
        except (ValueError, TypeError, x.ExtensionNotFound, Exception):
            return False
        have = {str(v) for v in alt.get_values_for_type(x.IPAddress)}
        have |= set(alt.get_values_for_type(x.DNSName))
        wanted = {str(ipaddress.ip_address(h)) if _is_ip(h) else h for h in sans}
        now = dt.datetime.now(dt.UTC)  # (an expired one is issued again)
        return (cert.public_key().public_numbers() == key.public_key().public_numbers()
                and [n.value for n in names] == [cn] and wanted <= have
                and cert.not_valid_before_utc <= now <= cert.not_valid_after_utc)

    def identity(self, cn: str, hosts: list[str]) -> None:
        """Key and certificate of identity `cn` (made, completed or kept)."""
        key_path, cert_path = self.out / f"{cn}.key", self.out / f"{cn}.pem"
        had_key = key_path.exists()
        key = self._key(key_path, cn)
        sans = _sans(hosts)
        old = self._load_cert(cert_path)
        if old is not None and had_key and self._fits(old, key, cn, sans):
            self.report.kept.append(cn)
            return
        cert = self._sign(cn, key, sans)
        _write_cert(cert_path, cert.public_bytes(self.ser.Encoding.PEM))
        (self.report.reissued if had_key else self.report.made).append(cert_path.name)

    def _sign(self, cn: str, key: Any, sans: list[str]) -> Any:
        """A certificate of this CA for `key`, named `cn`, valid for the hosts `sans`."""
        x = self.x509
        alt = [x.IPAddress(ipaddress.ip_address(h)) if _is_ip(h) else x.DNSName(h) for h in sans]
        return (self._builder(self._name(cn), key.public_key(), self.days)
                .issuer_name(self.cert.subject)
                .add_extension(x.BasicConstraints(ca=False, path_length=None), critical=True)
                .add_extension(x.KeyUsage(digital_signature=True, content_commitment=False,
                                          key_encipherment=False, data_encipherment=False,
                                          key_agreement=False, key_cert_sign=False,
                                          crl_sign=False, encipher_only=False,
                                          decipher_only=False), critical=True)
                .add_extension(x.ExtendedKeyUsage([self.EKU.SERVER_AUTH, self.EKU.CLIENT_AUTH]),
                               critical=False)
                .add_extension(x.SubjectAlternativeName(alt), critical=False)
                .add_extension(x.AuthorityKeyIdentifier.from_issuer_public_key(
                    self.key.public_key()), critical=False)
                .sign(self.key, self.hashes.SHA256()))


def _is_ip(h: str) -> bool:
    try:
        ipaddress.ip_address(h)
        return True
    except ValueError:
        return False


def read_roster(out: Path) -> dict[str, Any]:
    """`roster.json` of a certificate directory ({} when there is none yet)."""
    path = out / ROSTER
    if not path.exists():
        return {}
    try:
        rec = json.loads(path.read_text())
        if not isinstance(rec, dict):
            raise ValueError("not an object")
        return rec
    except (OSError, ValueError) as exc:
        raise ConfigError(f"{path}: {exc}") from None


def make_certs(out: str | Path, robots: int, workers: int = 0, hosts: list[str] | None = None,
               days: int = 825, routers: int = 0) -> CertsReport:
    """Make (or complete) the certificate directory `out` for `robots` robots, `workers`
    rollout workers and `routers` host routers (router-1..; `swarm run --hosts routers+1`);
    `hosts` are added to every certificate's subjectAltName."""
    if not 1 <= robots <= 4096 or not 0 <= workers <= 1024 or not 0 <= routers <= 64:
        raise ConfigError(f"--robots must lie in [1, 4096], --workers in [0, 1024] and --routers "
                          f"in [0, 64], got {robots}, {workers} and {routers}")
    if not 1 <= days <= 10_000:
        raise ConfigError(f"--days must lie in [1, 10000], got {days}")
    if not str(out).strip():  # (Path("") is the working directory, which would be chmod 0700)
        raise ConfigError("--out wants a directory, got an empty name")
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise ConfigError(f"--out {out} exists and is not a directory")
    above = next((p for p in out.parents if p.exists()), None)
    if above is not None and not above.is_dir():
        raise ConfigError(f"--out {out} is under {above}, which is not a directory")
    check_hosts(list(hosts or []))  # everything that can be checked first: a refused
    crypto()  # command leaves no directory behind
    old = read_roster(out) if out.is_dir() else {}
    hosts = check_hosts(list(dict.fromkeys([*old.get("hosts", []), *(hosts or [])])))
    made_dirs = [p for p in (out, *out.parents) if not p.exists()]
    out.mkdir(parents=True, exist_ok=True, mode=0o700)
    try:
        return _fill(out, robots, workers, routers, hosts, days, old)
    except BaseException:  # (disk full, ^C): a directory this call made is not left half-made
        if made_dirs:
            shutil.rmtree(made_dirs[-1], ignore_errors=True)
        raise


def _fill(out: Path, robots: int, workers: int, routers: int, hosts: list[str], days: int,
          old: dict[str, Any]) -> CertsReport:
    """`make_certs`'s writing part, into the existing directory `out` (`old`: its roster)."""
    os.chmod(out, 0o700)
    robots = max(robots, int(old.get("robots", 0)))
    workers = max(workers, int(old.get("workers", 0)))
    routers = max(routers, int(old.get("routers", 0)))
    report = CertsReport()
    issuer = _Issuer(out, days, report)
    issuer.one_key_each(identities(robots, workers, routers))  # before anything is signed
    for cn in identities(robots, workers, routers):
        issuer.identity(cn, hosts)
    roster = {"robots": robots, "workers": workers, "routers": routers, "hosts": hosts,
              "identities": identities(robots, workers, routers)}
    (out / ROSTER).write_text(json.dumps(roster, indent=1) + "\n")
    return report


def run_certs(cert_dir: str | Path, out: str | Path, names: dict[str, list[str]],
              days: int = 30) -> dict[str, Path]:
    """Certificates for one run: for each identity of `names`, its existing key of `cert_dir`
    certified again by that directory's CA, naming its usual hosts and the given addresses (the
    emulated hosts' addresses, chosen when a run starts), written to `out/<identity>.pem`. No
    key is made or copied; the certificates live as long as the run's folder (`days`)."""
    d, out = Path(cert_dir), Path(out)
    issuer = _Issuer(d, days, CertsReport(), create=False)
    hosts = read_roster(d).get("hosts", [])
    out.mkdir(parents=True, exist_ok=True)
    made: dict[str, Path] = {}
    for cn, addrs in names.items():
        key = issuer._key(d / f"{cn}.key", cn, create=False)
        cert = issuer._sign(cn, key, _sans([*hosts, *check_hosts(addrs)]))
        made[cn] = out / f"{cn}.pem"
        _write_cert(made[cn], cert.public_bytes(issuer.ser.Encoding.PEM))
    return made
