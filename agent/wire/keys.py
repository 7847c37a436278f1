"""Zenoh key-expression table for viscover.

Every key lives under one mission prefix, ``viscover/<mission>/...``, so that several missions
can share one router without seeing each other's traffic.

=============================================  ===========================  ======================
Key expression                                 Zenoh primitive              Builder
=============================================  ===========================  ======================
``viscover/<m>/pose/<agent_id>``               publication (pose stream)    :func:`pose_key`
``viscover/<m>/state/<agent_id>``              publication (agent state)    :func:`state_key`
``viscover/<m>/trade/<agent_id>``              queryable (landmark trades)  :func:`trade_key`
``viscover/<m>/alive/<agent_id>``              liveliness token             :func:`alive_key`
``viscover/<m>/status/<agent_id>``             publication (mission status) :func:`status_key`
``viscover/<m>/departure/<agent_id>``          publication (leaving early)  :func:`departure_key`
``viscover/<m>/command_ack/<agent_id>``        publication (command acks)   :func:`command_ack_key`
``viscover/<m>/mocap/<agent_id>``              publication (mocap pose)     :func:`mocap_key`
``viscover/<m>/mocap_status/<agent_id>``       publication (mocap health)   :func:`mocap_status_key`
``viscover/<m>/clock``                         publication (sim clock)      :func:`clock_key`
``viscover/<m>/landmarks``                     publication (landmark set)   :func:`landmarks_key`
``viscover/<m>/command``                       publication (land / stop)    :func:`command_key`
``viscover/<m>/fences``                        queryable (the fence record) :func:`fences_key`
=============================================  ===========================  ======================

Who writes each kind is :data:`KEY_TABLE`: the drone the key names, the ground station
(which also carries the operator's commands), or the router process itself (the fence record
it keeps for drones that come back late, :mod:`agent.net.keeper`: answered from the router's
own session, so no client is ever allowed to declare it); the secured router's access
control is derived from it (:func:`agent.net.security.access_control`), so a kind added here
without a writer cannot be forgotten there (``tests/test_security_acl.py`` checks every
write in the code).

Wildcard forms for subscribers and liveliness watchers (``*`` matches one chunk):
``viscover/<m>/pose/*`` (:func:`all_agents`), ``viscover/<m>/**`` (:func:`mission_glob`).

Mission names and agent ids must match ``[A-Za-z0-9_-]{1,32}``: no ``/``, no wildcard
characters, no ``$``, so a key never contains a glob by accident.
"""

from __future__ import annotations

import re
from typing import Final, NamedTuple

ROOT: Final = "viscover"
ID_PATTERN: Final = re.compile(r"[A-Za-z0-9_-]{1,32}")

#: Writers of :data:`KEY_TABLE`: the drone the key names (certificate ``drone-<id>``), the
#: ground station (certificate ``ground``), the router process itself (no client).
DRONE: Final = "drone"
GROUND: Final = "ground"
ROUTER: Final = "router"


class KeyKind(NamedTuple):
    """One kind of key: ``viscover/<m>/<kind>/<agent_id>`` (``per_agent``) or
    ``viscover/<m>/<kind>``; who writes it and with which Zenoh message kinds (access-control
    names); ``asked_by``: who may query it (besides, everyone on the team reads everything)."""

    kind: str
    per_agent: bool
    writer: str
    writes: tuple[str, ...]
    asked_by: str | None = None


#: The wire contract: every key kind, its writer and how it is written.
KEY_TABLE: Final = (
    KeyKind("pose", True, DRONE, ("put",)),
    KeyKind("state", True, DRONE, ("put",)),
    KeyKind("status", True, DRONE, ("put",)),
    KeyKind("departure", True, DRONE, ("put",)),
    KeyKind("command_ack", True, DRONE, ("put",)),
    KeyKind("trade", True, DRONE, ("declare_queryable", "reply"), asked_by=DRONE),
    KeyKind("alive", True, DRONE, ("liveliness_token",)),
    KeyKind("mocap", True, GROUND, ("put",)),
    KeyKind("mocap_status", True, GROUND, ("put",)),
    KeyKind("clock", False, GROUND, ("put",)),
    KeyKind("landmarks", False, GROUND, ("put",)),
    KeyKind("command", False, GROUND, ("put",)),
    KeyKind("fences", False, ROUTER, ("declare_queryable", "reply"), asked_by=DRONE),
)
#: Per-agent key kinds: ``viscover/<m>/<kind>/<agent_id>``.
AGENT_KINDS: Final = frozenset(k.kind for k in KEY_TABLE if k.per_agent)
#: Mission-wide key kinds: ``viscover/<m>/<kind>``.
MISSION_KINDS: Final = frozenset(k.kind for k in KEY_TABLE if not k.per_agent)


class KeyFormatError(ValueError):
    """Raised when a mission name, agent id or key does not follow the table."""


def validate_id(value: str, what: str = "agent id") -> str:
    """Return ``value`` if it matches ``[A-Za-z0-9_-]{1,32}``; raise :class:`KeyFormatError`."""
    if not isinstance(value, str) or ID_PATTERN.fullmatch(value) is None:
        raise KeyFormatError(f"invalid {what} {value!r}: must match [A-Za-z0-9_-]{{1,32}}")
    return value


def _agent_key(kind: str, mission: str, agent_id: str) -> str:
    validate_id(mission, "mission")
    validate_id(agent_id)
    return f"{ROOT}/{mission}/{kind}/{agent_id}"


def pose_key(mission: str, agent_id: str) -> str:
    """Key of an agent's pose publications."""
    return _agent_key("pose", mission, agent_id)


def state_key(mission: str, agent_id: str) -> str:
    """Key of an agent's state publications."""
    return _agent_key("state", mission, agent_id)


def trade_key(mission: str, agent_id: str) -> str:
    """Key of an agent's trade queryable."""
    return _agent_key("trade", mission, agent_id)


def alive_key(mission: str, agent_id: str) -> str:
    """Key of an agent's liveliness token."""
    return _agent_key("alive", mission, agent_id)


def status_key(mission: str, agent_id: str) -> str:
    """Key of an agent's mission-status publications."""
    return _agent_key("status", mission, agent_id)


def departure_key(mission: str, agent_id: str) -> str:
    """Key of an agent's departure announcement (:mod:`agent.wire.departure`)."""
    return _agent_key("departure", mission, agent_id)


def mocap_key(mission: str, agent_id: str) -> str:
    """Key of a drone's motion-capture poses, published by the ground station."""
    return _agent_key("mocap", mission, agent_id)


def mocap_status_key(mission: str, agent_id: str) -> str:
    """Key of a drone's motion-capture health (ok / stale / missing), from the ground station."""
    return _agent_key("mocap_status", mission, agent_id)


def command_ack_key(mission: str, agent_id: str) -> str:
    """Key of an agent's acknowledgements of mission commands."""
    return _agent_key("command_ack", mission, agent_id)


def command_key(mission: str) -> str:
    """Key of mission commands (land, stop) to the agents."""
    return f"{ROOT}/{validate_id(mission, 'mission')}/command"


def clock_key(mission: str) -> str:
    """Key of the simulation clock publications."""
    return f"{ROOT}/{validate_id(mission, 'mission')}/clock"


def landmarks_key(mission: str) -> str:
    """Key of the mission's landmark-set publications."""
    return f"{ROOT}/{validate_id(mission, 'mission')}/landmarks"


def fences_key(mission: str) -> str:
    """Key of the fence record the router keeps for mission ``mission``
    (:mod:`agent.wire.record`)."""
    return f"{ROOT}/{validate_id(mission, 'mission')}/fences"


def every_mission(kind: str) -> str:
    """Wildcard key of mission-wide ``kind`` in every mission, e.g. ``viscover/*/fences``."""
    if kind not in MISSION_KINDS:
        raise KeyFormatError(f"unknown mission-wide kind {kind!r}")
    return f"{ROOT}/*/{kind}"


def all_agents(mission: str, kind: str) -> str:
    """Wildcard key matching ``kind`` keys of every agent, e.g. ``viscover/m/pose/*``."""
    if kind not in AGENT_KINDS:
        raise KeyFormatError(
            f"unknown per-agent kind {kind!r}; expected one of {sorted(AGENT_KINDS)}"
        )
    return f"{ROOT}/{validate_id(mission, 'mission')}/{kind}/*"


def mission_glob(mission: str) -> str:
    """Wildcard key matching every key of one mission: ``viscover/<m>/**``."""
    return f"{ROOT}/{validate_id(mission, 'mission')}/**"


def parse_key(key: str) -> tuple[str, str, str | None]:
    """Split a concrete key into ``(mission, kind, agent_id)``.

    ``agent_id`` is None for mission-wide kinds (clock, landmarks). Raises :class:`KeyFormatError`
    if the key is not in the table or an id is invalid.
    """
    parts = str(key).split("/")
    if len(parts) < 3 or parts[0] != ROOT:
        raise KeyFormatError(f"key {key!r} is not under {ROOT}/<mission>/")
    mission, kind = validate_id(parts[1], "mission"), parts[2]
    if kind in AGENT_KINDS and len(parts) == 4:
        return mission, kind, validate_id(parts[3])
    if kind in MISSION_KINDS and len(parts) == 3:
        return mission, kind, None
    raise KeyFormatError(f"key {key!r} does not follow the viscover key table")


def agent_of(key: str) -> str:
    """Return the agent id at the end of a per-agent key; raise :class:`KeyFormatError`."""
    _, kind, agent_id = parse_key(key)
    if agent_id is None:
        raise KeyFormatError(f"key {key!r} ({kind}) names no agent")
    return agent_id


def try_agent_of(key: str) -> str | None:
    """Like :func:`agent_of` but returns None instead of raising."""
    try:
        return agent_of(key)
    except KeyFormatError:
        return None


def kind_of(key: str) -> str | None:
    """Return the kind chunk (``pose``, ``trade``, ``clock``...) of a key, or None."""
    try:
        return parse_key(key)[1]
    except KeyFormatError:
        return None
