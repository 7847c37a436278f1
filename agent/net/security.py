"""The secured profile: mutual TLS, access control by certificate common name, signed trades.

A *team directory* (``deploy/make-certs.py`` writes one; ``--tls-dir`` or ``$VISCOVER_TLS_DIR``
names it) holds, per identity, a certificate and key signed by the team's CA:

=======================  ==================================================================
file                     what it is
=======================  ==================================================================
``ca.pem``               the team CA's certificate (on every machine; ``ca.key`` stays offline)
``router.pem/.key``      the router (its SANs: the names and addresses clients connect to)
``drone-<id>.pem/.key``  drone ``<id>``'s TLS identity (common name ``drone-<id>``)
``drone-<id>.sign``      drone ``<id>``'s Ed25519 key signing its trade messages
``ground.pem/.key``      the ground station: mocap, clock, landmarks, mission commands
``observer.pem/.key``    read-only: ``viscover observe``, ``viscover launch``'s observer
``team.json``            the drone ids and their signing public keys
=======================  ==================================================================

:func:`access_control` is the router's rule set, derived from the wire contract's key table
(:data:`agent.wire.keys.KEY_TABLE`): default deny; a drone may publish only its own pose,
state, status, departure and command acknowledgements, declare only its own trade queryable
and liveliness token, reply only on its own trade key, query any drone's trade key, and read
the mission; the ground station may publish mocap, clock, landmarks and mission commands;
observers only read. A trade query's sender cannot be checked by the router (any drone may ask
any drone): the receiver checks its signature (:mod:`agent.wire.signed`).
"""

from __future__ import annotations

import json
import os
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Final

import zenoh

from agent.errors import UsageError
from agent.wire import keys

if TYPE_CHECKING:  # imported when used: `viscover router` needs no cryptography
    from agent.wire.signed import SigningKeys

#: Environment variable naming the team directory when ``--tls-dir`` is not given.
ENV_TLS_DIR: Final = "VISCOVER_TLS_DIR"
GROUND: Final = "ground"
OBSERVER: Final = "observer"
ROUTER: Final = "router"
#: Default secured router endpoint (the router certificate's SANs include localhost).
DEFAULT_TLS_ENDPOINT: Final = "tls/localhost:7447"
#: Every message kind Zenoh's access control knows.
ALL_MESSAGES: Final = ("put", "delete", "declare_subscriber", "query", "declare_queryable",
                       "reply", "liveliness_token", "declare_liveliness_subscriber",
                       "liveliness_query")
_READ: Final = ("declare_subscriber", "declare_liveliness_subscriber", "liveliness_query")


def drone_name(agent_id: str) -> str:
    """Certificate common name of drone ``agent_id``: ``drone-<id>``."""
    return f"drone-{keys.validate_id(agent_id)}"


@dataclass(frozen=True)
class TeamDir:
    """A team directory (layout in the module docstring)."""

    path: Path

    @property
    def ca(self) -> Path:
        """The CA certificate."""
        return self.path / "ca.pem"

    def cert(self, name: str) -> Path:
        """Certificate of identity ``name``."""
        return self.path / f"{name}.pem"

    def key(self, name: str) -> Path:
        """TLS private key of identity ``name``."""
        return self.path / f"{name}.key"

    def sign_key(self, agent_id: str) -> Path:
        """Ed25519 signing key of drone ``agent_id``."""
        return self.path / f"{drone_name(agent_id)}.sign"

    @property
    def team_file(self) -> Path:
        """The drone ids and their signing public keys."""
        return self.path / "team.json"

    def require(self, *files: Path) -> None:
        """A :class:`UsageError` naming the first missing file and how to make it."""
        for f in files:
            if not f.is_file():
                raise UsageError(f"--tls-dir {self.path}: {f.name} missing; make the team's "
                                 "certificates with deploy/make-certs.py (README: Securing "
                                 "the mesh)")

    def drones(self) -> list[str]:
        """The drone ids of ``team.json``."""
        from agent.wire.signed import parse_team

        self.require(self.team_file)
        try:
            return sorted(parse_team(self.team_file.read_text(encoding="utf-8")))
        except (OSError, ValueError) as e:
            raise UsageError(f"--tls-dir {self.path}: team.json: {e}") from None


def team_dir(tls_dir: str | Path | None) -> TeamDir | None:
    """The team directory of ``--tls-dir`` (else ``$VISCOVER_TLS_DIR``), or None: open
    profile. A :class:`UsageError` if it is named but not a directory."""
    name = tls_dir if tls_dir else os.environ.get(ENV_TLS_DIR) or None
    if name is None:
        return None
    path = Path(name)
    if not path.is_dir():
        raise UsageError(f"--tls-dir {path}: not a directory (make one with "
                         "deploy/make-certs.py)")
    return TeamDir(path.resolve())


# -- router --------------------------------------------------------------------------------------


def _rule(rid: str, flow: str, messages: Iterable[str], key_exprs: Iterable[str]) -> dict[str, Any]:
    """One allow rule of the access-control block."""
    return {"id": rid, "permission": "allow", "flows": [flow], "messages": list(messages),
            "key_exprs": list(key_exprs)}


def _grouped(writer: str) -> dict[tuple[str, ...], list[keys.KeyKind]]:
    """The kinds of :data:`agent.wire.keys.KEY_TABLE` ``writer`` writes, by message kinds."""
    out: dict[tuple[str, ...], list[keys.KeyKind]] = {}
    for k in keys.KEY_TABLE:
        if k.writer == writer:
            out.setdefault(k.writes, []).append(k)
    return out


def _expr(k: keys.KeyKind, agent: str = "*") -> str:
    """Key expression of kind ``k`` in every mission (of drone ``agent``, if per agent)."""
    return f"{keys.ROOT}/*/{k.kind}/{agent}" if k.per_agent else f"{keys.ROOT}/*/{k.kind}"


def access_control(drones: Sequence[str], routers: bool = True) -> dict[str, Any]:
    """The router's ``access_control`` block for a team of ``drones`` (module docstring),
    derived from the wire contract's key table (:data:`agent.wire.keys.KEY_TABLE`): each
    kind is written only by its writer (a drone only on its own keys); ``routers``: a
    linked router (common name ``router``) may carry everything."""
    root = keys.ROOT
    everything = [f"{root}/**"]
    rules = [
        _rule("deliver", "egress", ALL_MESSAGES, everything),
        _rule("read", "ingress", _READ, everything),
        _rule("ask-trades", "ingress", ["query"],
              [_expr(k) for k in keys.KEY_TABLE if k.asked_by == keys.DRONE]),
    ]
    ground_rules = []
    for writes, kinds in _grouped(keys.GROUND).items():
        rid = f"ground-{'-'.join(writes)}"
        rules.append(_rule(rid, "ingress", writes, [_expr(k) for k in kinds]))
        ground_rules.append(rid)
    subjects: list[dict[str, Any]] = [
        {"id": "drones", "cert_common_names": [drone_name(d) for d in drones]},
        {"id": GROUND, "cert_common_names": [GROUND]},
        {"id": OBSERVER, "cert_common_names": [OBSERVER]},
    ]
    policies: list[dict[str, Any]] = [
        {"id": "drones", "rules": ["deliver", "read", "ask-trades"], "subjects": ["drones"]},
        {"id": GROUND, "rules": ["deliver", "read", *ground_rules], "subjects": [GROUND]},
        {"id": OBSERVER, "rules": ["deliver", "read"], "subjects": [OBSERVER]},
    ]
    own_kinds = _grouped(keys.DRONE)
    for d in drones:
        own: list[str] = []
        for writes, kinds in own_kinds.items():
            own.append(f"own-{d}-{'-'.join(writes)}")
            rules.append(_rule(own[-1], "ingress", writes, [_expr(k, d) for k in kinds]))
        subjects.append({"id": drone_name(d), "cert_common_names": [drone_name(d)]})
        policies.append({"id": f"own-{d}", "rules": own, "subjects": [drone_name(d)]})
    if routers:
        rules.append(_rule("link-in", "ingress", ALL_MESSAGES, everything))
        subjects.append({"id": ROUTER, "cert_common_names": [ROUTER]})
        policies.append({"id": ROUTER, "rules": ["deliver", "link-in"], "subjects": [ROUTER]})
    return {"enabled": True, "default_permission": "deny", "rules": rules,
            "subjects": subjects, "policies": policies}


def router_config(team: TeamDir, listen: Sequence[str], connect: Sequence[str] = (),
                  drones: Sequence[str] | None = None, lease_ms: int = 1000,
                  paths_dir: Path | None = None) -> dict[str, Any]:
    """The secured router's config: TLS only, clients must present a team certificate, the
    :func:`access_control` of ``drones`` (default: ``team.json``'s). ``paths_dir``: where
    the files will be on the router's machine (default: the team directory)."""
    base = paths_dir or team.path
    ids = list(drones) if drones is not None else team.drones()
    return {
        "mode": "router",
        "listen": {"endpoints": list(listen)},
        "connect": {"endpoints": list(connect)},
        "scouting": {"multicast": {"enabled": False}, "gossip": {"enabled": False}},
        "transport": {"link": {
            "protocols": ["tls"],
            "tx": {"lease": lease_ms, "keep_alive": 4},
            "tls": {"root_ca_certificate": str(base / "ca.pem"),
                    "listen_certificate": str(base / f"{ROUTER}.pem"),
                    "listen_private_key": str(base / f"{ROUTER}.key"),
                    "connect_certificate": str(base / f"{ROUTER}.pem"),
                    "connect_private_key": str(base / f"{ROUTER}.key"),
                    "enable_mtls": True},
        }},
        "access_control": access_control(ids),
    }


# -- clients -------------------------------------------------------------------------------------


def tls_block(team: TeamDir, identity: str) -> dict[str, Any]:
    """``transport.link.tls`` of a client presenting identity ``identity``."""
    team.require(team.ca, team.cert(identity), team.key(identity))
    return {"root_ca_certificate": str(team.ca),
            "connect_certificate": str(team.cert(identity)),
            "connect_private_key": str(team.key(identity)),
            "enable_mtls": True}


def check_endpoints(endpoints: Iterable[str]) -> list[str]:
    """``endpoints`` if all are ``tls/``; else a :class:`UsageError` saying so."""
    eps = list(endpoints)
    for ep in eps:
        if not ep.startswith("tls/"):
            raise UsageError(f"--connect {ep}: the secured profile (--tls-dir) connects over "
                             "TLS; write tls/HOST:PORT, e.g. tls/localhost:7447")
    return eps


def client_config(team: TeamDir, endpoints: Sequence[str], identity: str,
                  lease_ms: int = 1000) -> zenoh.Config:
    """A client ``zenoh.Config`` connecting over mutual TLS as ``identity``."""
    cfg = {
        "mode": "client",
        "connect": {"endpoints": check_endpoints(endpoints)},
        "scouting": {"multicast": {"enabled": False}, "gossip": {"enabled": False}},
        "transport": {"link": {"tx": {"lease": lease_ms, "keep_alive": 4},
                               "tls": tls_block(team, identity)}},
    }
    return zenoh.Config.from_json5(json.dumps(cfg))


def secure_file_config(config: zenoh.Config, team: TeamDir, identity: str) -> zenoh.Config:
    """``config`` (a ``--zenoh`` file) with ``identity``'s TLS block inserted."""
    config.insert_json5("transport/link/tls", json.dumps(tls_block(team, identity)))
    return config


def load_signing(team: TeamDir, agent_id: str) -> SigningKeys:
    """Drone ``agent_id``'s signing key and the team's public keys (a :class:`UsageError`
    naming the file if one is missing or not a key, or the drone is not in the team)."""
    from agent.wire.signed import SigningKeys, load_private_key, parse_team

    path = team.sign_key(agent_id)
    team.require(path, team.team_file)
    try:
        private = load_private_key(path.read_bytes())
    except (OSError, ValueError) as e:
        raise UsageError(f"--tls-dir {team.path}: {path.name}: {e}") from None
    try:
        members = parse_team(team.team_file.read_text(encoding="utf-8"))
    except (OSError, ValueError) as e:
        raise UsageError(f"--tls-dir {team.path}: team.json: {e}") from None
    if agent_id not in members:
        raise UsageError(f"--tls-dir {team.path}: drone {agent_id} is not in team.json; add it "
                         "with deploy/make-certs.py --drones ... (README: Securing the mesh)")
    return SigningKeys(agent_id, private, members)


# -- viscover launch -----------------------------------------------------------------------------


@dataclass(frozen=True)
class LaunchSecurity:
    """What ``viscover launch`` needs to run a whole mission on the secured profile."""

    team: TeamDir

    def child_args(self) -> list[str]:
        """Options for every child ``viscover`` process (each picks its identity)."""
        return ["--tls-dir", str(self.team.path)]

    def client_config(self, endpoint: str) -> zenoh.Config:
        """The launcher's own (observer) session."""
        return client_config(self.team, [endpoint], OBSERVER)


def launch_security(tls_dir: str | Path | None = None) -> LaunchSecurity | None:
    """The secured profile of a launch (``tls_dir`` else ``$VISCOVER_TLS_DIR``), or None."""
    team = team_dir(tls_dir)
    return None if team is None else LaunchSecurity(team)
