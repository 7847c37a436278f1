"""A team's certificates and keys (``deploy/make-certs.py`` is the command line).

:func:`make_team` writes a team directory (layout in :mod:`agent.net.security`): a CA (ECDSA
P-256, made once and reused: adding a drone or renewing certificates keeps it), a TLS
certificate and key per identity (router with its SANs, ``drone-<id>``, ``ground``,
``observer``), an Ed25519 signing key per drone, ``team.json`` with the drones' signing public
keys, and ``router.json5``, the secured router configuration for this team. Private keys are
written with mode 0600; existing files are kept unless renewal is asked for. A removed drone
leaves ``team.json`` and the router's access control (its certificate then opens a session
that may do nothing, and its signatures are refused), and its files are deleted.
"""

from __future__ import annotations

import datetime as dt
import ipaddress
import json
import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

from cryptography import x509
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import ec
from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey
from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

from agent.net.security import GROUND, OBSERVER, ROUTER, TeamDir, drone_name, router_config
from agent.wire.signed import load_private_key, private_key_pem, public_key_text

DEFAULT_HOSTS = ("localhost", "127.0.0.1")


@dataclass
class TeamPlan:
    """What :func:`make_team` makes (times in days)."""

    out: Path
    drones: Sequence[str]
    hosts: Sequence[str] = DEFAULT_HOSTS  #: the router's DNS names and IP addresses (SANs)
    days: int = 365  #: validity of leaf certificates
    ca_days: int = 3650  #: validity of a new CA
    renew: bool = False  #: reissue every leaf certificate (same CA)
    remove: Sequence[str] = ()  #: drones leaving the team (their files are deleted)
    listen: Sequence[str] = ("tls/0.0.0.0:7447",)  #: the router's listen endpoints
    paths_dir: Path | None = None  #: where the files will live on the router (router.json5)
    made: list[str] = field(default_factory=list)  #: files written (filled in)


def _write(path: Path, data: bytes, secret: bool) -> None:
    """Write ``data`` to ``path`` (mode 0600 if ``secret``, created so from the start)."""
    mode = 0o600 if secret else 0o644
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, mode)
    with os.fdopen(fd, "wb") as fh:
        fh.write(data)
    os.chmod(path, mode)


def _name(cn: str) -> x509.Name:
    """The X.509 name with common name ``cn``."""
    return x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, cn)])


def _pem_key(key: ec.EllipticCurvePrivateKey) -> bytes:
    """PKCS#8 PEM of an EC private key (unencrypted: the file is mode 0600)."""
    return key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8,
                             serialization.NoEncryption())


def _ca(team: TeamDir, plan: TeamPlan) -> tuple[ec.EllipticCurvePrivateKey, x509.Certificate]:
    """The team's CA key and certificate: read if present, else made and written."""
    key_path = team.path / "ca.key"
    if key_path.is_file() and team.ca.is_file():
        key = serialization.load_pem_private_key(key_path.read_bytes(), password=None)
        if not isinstance(key, ec.EllipticCurvePrivateKey):
            raise ValueError(f"{key_path}: not an EC private key")
        return key, x509.load_pem_x509_certificate(team.ca.read_bytes())
    key = ec.generate_private_key(ec.SECP256R1())
    now = dt.datetime.now(dt.UTC)
    usage = x509.KeyUsage(digital_signature=True, key_cert_sign=True, crl_sign=True,
                          content_commitment=False, key_encipherment=False,
                          data_encipherment=False, key_agreement=False, encipher_only=False,
                          decipher_only=False)
    cert = (x509.CertificateBuilder().subject_name(_name("viscover team CA"))
            .issuer_name(_name("viscover team CA")).public_key(key.public_key())
            .serial_number(x509.random_serial_number())
            .not_valid_before(now - dt.timedelta(minutes=5))
            .not_valid_after(now + dt.timedelta(days=plan.ca_days))
            .add_extension(x509.BasicConstraints(ca=True, path_length=0), critical=True)
            .add_extension(usage, critical=True)
            .add_extension(x509.SubjectKeyIdentifier.from_public_key(key.public_key()),
                           critical=False)
            .sign(key, hashes.SHA256()))
    _write(key_path, _pem_key(key), secret=True)
    _write(team.ca, cert.public_bytes(serialization.Encoding.PEM), secret=False)
    plan.made += ["ca.key", "ca.pem"]
    return key, cert


def _sans(hosts: Sequence[str]) -> list[x509.GeneralName]:
    """DNS names and IP addresses of ``hosts`` as subject alternative names."""
    out: list[x509.GeneralName] = []
    for h in hosts:
        try:
            out.append(x509.IPAddress(ipaddress.ip_address(h)))
        except ValueError:
            out.append(x509.DNSName(h))
    return out


def _leaf(team: TeamDir, plan: TeamPlan, ca: tuple[ec.EllipticCurvePrivateKey, x509.Certificate],
          cn: str, hosts: Sequence[str]) -> None:
    """Issue identity ``cn``'s key and certificate (unless present and not renewing)."""
    if team.cert(cn).is_file() and team.key(cn).is_file() and not plan.renew:
        return
    ca_key, ca_cert = ca
    key = ec.generate_private_key(ec.SECP256R1())
    now = dt.datetime.now(dt.UTC)
    cert = (x509.CertificateBuilder().subject_name(_name(cn)).issuer_name(ca_cert.subject)
            .public_key(key.public_key()).serial_number(x509.random_serial_number())
            .not_valid_before(now - dt.timedelta(minutes=5))
            .not_valid_after(now + dt.timedelta(days=plan.days))
            .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
            .add_extension(x509.ExtendedKeyUsage([ExtendedKeyUsageOID.SERVER_AUTH,
                                                  ExtendedKeyUsageOID.CLIENT_AUTH]),
                           critical=False)
            .add_extension(x509.SubjectAlternativeName(_sans(hosts)), critical=False)
            .add_extension(x509.AuthorityKeyIdentifier.from_issuer_public_key(
                ca_key.public_key()), critical=False)
            .sign(ca_key, hashes.SHA256()))
    _write(team.key(cn), _pem_key(key), secret=True)
    _write(team.cert(cn), cert.public_bytes(serialization.Encoding.PEM), secret=False)
    plan.made += [team.key(cn).name, team.cert(cn).name]


def _signing_key(team: TeamDir, plan: TeamPlan, agent_id: str) -> str:
    """Drone ``agent_id``'s signing public key (base64), its private key made if missing."""
    path = team.sign_key(agent_id)
    if path.is_file() and not plan.renew:
        return public_key_text(load_private_key(path.read_bytes()))
    key = Ed25519PrivateKey.generate()
    _write(path, private_key_pem(key), secret=True)
    plan.made.append(path.name)
    return public_key_text(key)


def make_team(plan: TeamPlan) -> TeamDir:
    """Write (or complete) the team directory of ``plan`` (see the module docstring)."""
    plan.out.mkdir(parents=True, exist_ok=True)
    os.chmod(plan.out, 0o750)
    team = TeamDir(plan.out.resolve())
    ca = _ca(team, plan)
    _leaf(team, plan, ca, ROUTER, list(plan.hosts))
    for cn in (GROUND, OBSERVER):
        _leaf(team, plan, ca, cn, [cn])
    keys: dict[str, str] = {}
    previous = team.drones() if team.team_file.is_file() else []
    for d in plan.remove:
        for f in (team.cert(drone_name(d)), team.key(drone_name(d)), team.sign_key(d)):
            f.unlink(missing_ok=True)
    for d in sorted((set(previous) | set(plan.drones)) - set(plan.remove)):
        _leaf(team, plan, ca, drone_name(d), [drone_name(d)])
        keys[d] = _signing_key(team, plan, d)
    _write(team.team_file, (json.dumps({"signing_keys": keys}, indent=1) + "\n").encode(),
           secret=False)
    cfg = router_config(team, list(plan.listen), drones=sorted(keys), paths_dir=plan.paths_dir)
    _write(team.path / "router.json5", (json.dumps(cfg, indent=1) + "\n").encode(),
           secret=False)
    plan.made += ["team.json", "router.json5"]
    return team
