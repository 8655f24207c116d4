"""A fleet's credentials on disk: its certificate authority, a certificate and key per
member, and each member's Zenoh config (:mod:`omnican.zenoh.security` says what is in
it). What ``omnican zenoh credentials`` makes, and what a session reads back.

The folder::

    DIR/omnican-fleet.json        the members by role, and the ROS domain
    DIR/ca.pem                    the CA's certificate: every member has a copy
    DIR/ca.key                    the CA's key: stays with whoever makes certificates
    DIR/<role>/<name>/cert.pem    a member's certificate (common name: its name)
    DIR/<role>/<name>/key.pem     its private key: that member's machine only
    DIR/<role>/<name>/zenoh.json5 its Zenoh config

Run again with more members, the CA and the certificates made before are kept and every
config is written anew (a base's and a router's list who may do what). Keys are ECDSA
P-256, signed with SHA-256; files holding a key are readable by their owner only.
``cryptography`` (the zenoh-security extra) is needed to make them, never to use them:
a session's TLS is Zenoh's own.
"""

from __future__ import annotations

import datetime
import os
import tempfile
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from omnican.errors import ConfigError
from omnican.zenoh import security
from omnican.zenoh.security import Identity, Roster

CA_DAYS = 3650
MEMBER_DAYS = 730
_SKEW = datetime.timedelta(hours=1)  # clocks of robots that are a little behind


@dataclass(frozen=True)
class Files:
    """Where one member's files are (and the CA's certificate it trusts)."""

    ca: Path
    cert: Path
    key: Path
    config: Path

    @staticmethod
    def of(root: Path, who: Identity) -> Files:
        folder = root / who.folder
        return Files(root / security.CA_CERT, folder / security.CERT, folder / security.KEY,
                     folder / security.CONFIG)

    def missing(self) -> list[Path]:
        return [p for p in (self.ca, self.cert, self.key, self.config) if not p.is_file()]


def files_for(credentials: str | Path, identity: str) -> tuple[Identity, Files]:
    """The identity ``ROLE/NAME`` and its files under ``credentials``; ConfigError, one
    line naming what is not there, when they are not all there."""
    try:
        who = Identity.parse(identity)
    except ValueError as exc:
        raise ConfigError(f"zenoh: {exc}") from None
    root = Path(credentials).expanduser()
    if not root.is_dir():
        raise ConfigError(f"Zenoh credentials {root}: no such folder (make it with "
                          "'omnican zenoh credentials')")
    files = Files.of(root, who)
    missing = files.missing()
    if missing:
        raise ConfigError(f"Zenoh credentials {root}: no {missing[0].relative_to(root)} for "
                          f"{who}" + ("" if (root / who.folder).is_dir() else
                                      f" (no {who.folder} there: is it one of its members?)"))
    return who, files


# ------------------------------------------------------------ making them


@dataclass
class Report:
    """What :func:`make` did: the lines it said, the members made and kept."""

    root: Path
    roster: Roster
    made: list[Identity] = field(default_factory=list)
    kept: list[Identity] = field(default_factory=list)
    removed: list[Identity] = field(default_factory=list)
    ca_made: bool = False


def _write(path: Path, data: bytes, secret: bool = False) -> None:
    """``data`` into ``path`` at once (a temporary file renamed): readable by its owner
    only when ``secret``."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.")
    try:
        with os.fdopen(fd, "wb") as out:
            out.write(data)
        os.chmod(tmp, 0o600 if secret else 0o644)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def _now() -> datetime.datetime:
    return datetime.datetime.now(datetime.timezone.utc)


def _key() -> Any:
    from cryptography.hazmat.primitives.asymmetric import ec

    return ec.generate_private_key(ec.SECP256R1())


def _key_pem(key: Any) -> bytes:
    from cryptography.hazmat.primitives import serialization

    pem: bytes = key.private_bytes(serialization.Encoding.PEM,
                                   serialization.PrivateFormat.PKCS8,
                                   serialization.NoEncryption())
    return pem


def _cert_pem(cert: Any) -> bytes:
    from cryptography.hazmat.primitives import serialization

    pem: bytes = cert.public_bytes(serialization.Encoding.PEM)
    return pem


def _usage(ca: bool) -> Any:
    from cryptography import x509

    return x509.KeyUsage(digital_signature=not ca, content_commitment=False,
                         key_encipherment=False, data_encipherment=False, key_agreement=False,
                         key_cert_sign=ca, crl_sign=ca, encipher_only=False,
                         decipher_only=False)


def _make_ca(days: int) -> tuple[Any, Any]:
    from cryptography import x509
    from cryptography.hazmat.primitives import hashes
    from cryptography.x509.oid import NameOID

    key = _key()
    ski = x509.SubjectKeyIdentifier.from_public_key(key.public_key())
    name = x509.Name([x509.NameAttribute(NameOID.ORGANIZATION_NAME, "omnican fleet"),
                      x509.NameAttribute(NameOID.COMMON_NAME,
                                         f"omnican fleet CA {ski.digest.hex()[:8]}")])
    now = _now()
    cert = (x509.CertificateBuilder().subject_name(name).issuer_name(name)
            .public_key(key.public_key()).serial_number(x509.random_serial_number())
            .not_valid_before(now - _SKEW).not_valid_after(now + datetime.timedelta(days=days))
            .add_extension(x509.BasicConstraints(ca=True, path_length=0), critical=True)
            .add_extension(_usage(ca=True), critical=True)
            .add_extension(ski, critical=False)
            .sign(key, hashes.SHA256()))
    return key, cert


def _make_member(who: Identity, ca_key: Any, ca_cert: Any, days: int) -> tuple[Any, Any]:
    from cryptography import x509
    from cryptography.hazmat.primitives import hashes
    from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

    key = _key()
    now = _now()
    name = x509.Name([x509.NameAttribute(NameOID.ORGANIZATION_NAME, "omnican fleet"),
                      x509.NameAttribute(NameOID.ORGANIZATIONAL_UNIT_NAME, who.role),
                      x509.NameAttribute(NameOID.COMMON_NAME, who.name)])
    cert = (x509.CertificateBuilder().subject_name(name).issuer_name(ca_cert.subject)
            .public_key(key.public_key()).serial_number(x509.random_serial_number())
            .not_valid_before(now - _SKEW).not_valid_after(now + datetime.timedelta(days=days))
            .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
            .add_extension(_usage(ca=False), critical=True)
            # both: a member listens (a server) and connects (a client)
            .add_extension(x509.ExtendedKeyUsage([ExtendedKeyUsageOID.SERVER_AUTH,
                                                  ExtendedKeyUsageOID.CLIENT_AUTH]),
                           critical=False)
            .add_extension(x509.SubjectAlternativeName([x509.DNSName(who.name)]),
                           critical=False)
            .add_extension(x509.AuthorityKeyIdentifier.from_issuer_public_key(
                ca_key.public_key()), critical=False)
            .sign(ca_key, hashes.SHA256()))
    return key, cert


def _load_ca(root: Path) -> tuple[Any, Any]:
    """The CA's key and certificate kept in ``root``; ConfigError when they do not match
    or cannot be read."""
    from cryptography import x509
    from cryptography.hazmat.primitives import serialization

    cert_path, key_path = root / security.CA_CERT, root / security.CA_KEY
    if not key_path.is_file():
        raise ConfigError(f"{key_path}: not there, and new certificates need the CA's key "
                          "(run this where it is kept)")
    try:
        cert = x509.load_pem_x509_certificate(cert_path.read_bytes())
        key = serialization.load_pem_private_key(key_path.read_bytes(), password=None)
    except (ValueError, TypeError, OSError) as exc:
        raise ConfigError(f"{root}: cannot read the CA ({exc})") from None
    raw = serialization.Encoding.DER, serialization.PublicFormat.SubjectPublicKeyInfo
    if key.public_key().public_bytes(*raw) != cert.public_key().public_bytes(*raw):
        raise ConfigError(f"{key_path} is not the key of {cert_path}")
    return key, cert


def read_roster(root: Path) -> Roster | None:
    """The roster in ``root`` (None: none there); ConfigError naming the file when it is
    not one."""
    path = root / security.ROSTER_FILE
    if not path.is_file():
        return None
    try:
        return Roster.from_json(path.read_text())
    except (ValueError, OSError) as exc:
        raise ConfigError(f"{path}: {exc}") from None


def make(root: Path, add: list[Identity], *, domain_id: int | None = None,
         remove: tuple[str, ...] = (), days: int = MEMBER_DAYS,
         installed_at: Path | None = None,
         say: Callable[[str], None] = lambda line: None) -> Report:
    """Make (or extend) the credentials in ``root``: the CA if there is none, a key and
    certificate for each member of ``add`` that has none, the members of ``remove``
    taken out; then every member's ``zenoh.json5`` and the roster written anew. ``say``
    hears a line per step. ``installed_at``: where the folder will be on the members'
    machines (the paths other programs read in the configs); default ``root``.
    ConfigError (one line) for what cannot be done; nothing is written then."""
    root = root.expanduser().resolve()
    if root.exists() and not root.is_dir():
        raise ConfigError(f"{root}: not a folder")
    roster = read_roster(root)
    ca_there = (root / security.CA_CERT).is_file()
    if roster is None and ca_there:
        raise ConfigError(f"{root}: a ca.pem but no {security.ROSTER_FILE}: not a folder "
                          "this command made")
    if roster is None and root.is_dir() and any(root.iterdir()):
        raise ConfigError(f"{root}: not empty, and not a folder this command made")
    if roster is not None and domain_id is not None and domain_id != roster.domain_id:
        raise ConfigError(f"{root} is the fleet of domain {roster.domain_id}, not "
                          f"{domain_id}: its access control names domain {roster.domain_id}")
    report = Report(root, roster or Roster(domain_id or 0))
    for name in remove:
        role = report.roster.role_of(name)
        if role is None:
            raise ConfigError(f"--remove {name}: no member of {root} is called so")
        members = {r: tuple(n for n in report.roster.names(r) if n != name)
                   for r in security.ROLES}
        report.roster = Roster(report.roster.domain_id, members)
        report.removed.append(Identity(role, name))
    for who in add:
        try:
            report.roster = report.roster.adding(who.role, who.name)
        except ValueError as exc:
            raise ConfigError(str(exc)) from None

    if ca_there:
        ca_key, ca_cert = _load_ca(root)
        say(f"CA: kept {root / security.CA_CERT} ({_common_name(ca_cert)})")
    else:
        ca_key, ca_cert = _make_ca(CA_DAYS)
        _write(root / security.CA_KEY, _key_pem(ca_key), secret=True)
        _write(root / security.CA_CERT, _cert_pem(ca_cert))
        report.ca_made = True
        say(f"CA: made {root / security.CA_CERT} ({_common_name(ca_cert)}, valid "
            f"{CA_DAYS} days); its key {root / security.CA_KEY} stays here, off the robots")
    for who in report.removed:
        _forget(root / who.folder)
        say(f"{who.role} {who.name}: removed (its certificate opens no door now that no "
            "base or router names it)")
    for who in report.roster.identities():
        files = Files.of(root, who)
        if files.cert.is_file() and files.key.is_file():
            report.kept.append(who)
            continue
        key, cert = _make_member(who, ca_key, ca_cert, days)
        _write(files.key, _key_pem(key), secret=True)
        _write(files.cert, _cert_pem(cert))
        report.made.append(who)
        say(f"{who.role} {who.name}: made {files.cert.parent}/ (cert.pem, key.pem; valid "
            f"{days} days)")
    where = (installed_at or root)
    made_on = _now().strftime("%Y-%m-%d")
    for who in report.roster.identities():
        there = Files.of(where, who)
        _write(Files.of(root, who).config, security.config_text(
            report.roster, who, str(there.ca), str(there.cert), str(there.key),
            made_on).encode())
    _write(root / security.ROSTER_FILE, report.roster.to_json().encode())
    return report


def _common_name(cert: Any) -> str:
    from cryptography.x509.oid import NameOID

    return str(cert.subject.get_attributes_for_oid(NameOID.COMMON_NAME)[0].value)


def _forget(folder: Path) -> None:
    """A removed member's folder (its key, certificate and config) deleted."""
    for path in sorted(folder.glob("*"), reverse=True):
        if path.is_file():
            path.unlink()
    if folder.is_dir() and not any(folder.iterdir()):
        folder.rmdir()
