"""The secured router's access control follows the wire contract's key table (issue "No single
peer, disk or file can lose a landmark", item 6): every key the code writes (found in the
source: each ``publish`` / ``declare_queryable`` / ``declare_liveliness`` of a key builder) is
allowed for the role that writes it and for no other; a drone's departure reaches the mesh."""

from __future__ import annotations

import ast
import time
from typing import Any

import pytest
import zenoh

from agent.net.pki import TeamPlan, make_team
from agent.net.security import GROUND, OBSERVER, TeamDir, access_control, drone_name
from agent.net.security import client_config as secure_config
from agent.wire import keys
from tests.conftest import ROOT, wait_until

#: Modules whose writes are the ground station's (``ground`` certificate: the station, its
#: clock, and the operator's land / stop commands); every other module under agent/ is drone
#: code, run with the drone's own certificate.
GROUND_CODE = ("groundstation/", "agent/net/clocksync.py", "agent/mission/operator.py")
#: Transport methods that write, and the access-control message kind each needs.
WRITES = {"publish": "put", "_put": "put", "put": "put",
          "declare_queryable": "declare_queryable", "declare_liveliness": "liveliness_token"}


def _kind(node: ast.expr, names: dict[str, str]) -> str | None:
    """The key kind an expression builds (``keys.pose_key(...)`` -> ``pose``), directly or
    through a name assigned from a builder in the same module."""
    if isinstance(node, ast.Call):
        f = node.func
        name = f.attr if isinstance(f, ast.Attribute) else f.id if isinstance(f, ast.Name) \
            else ""
        return name[:-4] if name.endswith("_key") else None
    if isinstance(node, ast.Name):
        return names.get(node.id)
    if isinstance(node, ast.Attribute):
        return names.get(node.attr)
    return None


def written_keys() -> set[tuple[str, str, str]]:
    """{(role, kind, message kind)} of every write of a key builder in the code."""
    out: set[tuple[str, str, str]] = set()
    for path in [*ROOT.glob("agent/**/*.py"), *ROOT.glob("groundstation/**/*.py")]:
        rel = path.relative_to(ROOT).as_posix()
        if rel == "agent/wire/keys.py":
            continue
        tree = ast.parse(path.read_text(encoding="utf-8"))
        names: dict[str, str] = {}
        for node in ast.walk(tree):
            if isinstance(node, ast.Assign) and (k := _kind(node.value, {})) is not None:
                for t in node.targets:
                    if isinstance(t, ast.Name | ast.Attribute):
                        names[t.id if isinstance(t, ast.Name) else t.attr] = k
        role = GROUND if rel.startswith(GROUND_CODE) else "drone"
        for node in ast.walk(tree):
            if (isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute)
                    and node.func.attr in WRITES and node.args
                    and (k := _kind(node.args[0], names)) is not None):
                out.add((role, k, WRITES[node.func.attr]))
    return out


def allowed(acl: dict[str, Any], cn: str, message: str, key: str) -> bool:
    """Whether the router's ``acl`` lets the client with certificate ``cn`` send ``message``
    on ``key`` (ingress; default deny, allow rules only)."""
    assert acl["default_permission"] == "deny"
    assert all(r["permission"] == "allow" for r in acl["rules"])
    subjects = {s["id"] for s in acl["subjects"] if cn in s.get("cert_common_names", [])}
    rules = {r["id"]: r for r in acl["rules"]}
    want = zenoh.KeyExpr(key)
    return any(
        "ingress" in rules[rid]["flows"] and message in rules[rid]["messages"]
        and any(zenoh.KeyExpr(k).includes(want) for k in rules[rid]["key_exprs"])
        for pol in acl["policies"] if subjects & set(pol["subjects"]) for rid in pol["rules"])


def test_every_written_key_is_allowed_for_its_writer_and_no_other() -> None:
    written = written_keys()
    # The scan finds the writes it must (a sanity check of the scan itself).
    assert {("drone", "departure", "put"), ("drone", "command_ack", "put"),
            ("drone", "trade", "declare_queryable"), ("drone", "alive", "liveliness_token"),
            (GROUND, "clock", "put"), (GROUND, "command", "put")} <= written, written
    acl = access_control(["A", "B"])
    everyone = [drone_name("A"), drone_name("B"), GROUND, OBSERVER]
    for role, kind, message in sorted(written):
        per_agent = kind in keys.AGENT_KINDS
        key = f"viscover/m/{kind}/A" if per_agent else f"viscover/m/{kind}"
        owner = drone_name("A") if role == "drone" else GROUND
        messages = [message, "reply"] if message == "declare_queryable" else [message]
        for msg in messages:
            for cn in everyone:
                assert allowed(acl, cn, msg, key) == (cn == owner), (cn, msg, key)


@pytest.fixture(scope="module")
def team(tmp_path_factory: pytest.TempPathFactory) -> TeamDir:
    """A team directory for drones A, B."""
    return make_team(TeamPlan(tmp_path_factory.mktemp("team"), ["A", "B"]))


def test_a_departure_reaches_the_mesh(team: TeamDir, secured_router: str) -> None:
    """Drone A's departure announcement passes the secured router; B's forgery of it does
    not."""
    got: list[bytes] = []
    with (zenoh.open(secure_config(team, [secured_router], drone_name("A"))) as a,
          zenoh.open(secure_config(team, [secured_router], drone_name("B"))) as b,
          zenoh.open(secure_config(team, [secured_router], OBSERVER)) as obs):
        obs.declare_subscriber("viscover/m/departure/*", lambda s: got.append(
            s.payload.to_bytes()))
        time.sleep(0.3)
        key = keys.departure_key("m", "A")
        b.put(key, b"forged by B")
        assert wait_until(lambda: bool(got), 3.0, 0.1, lambda: a.put(key, b"A leaves")), \
            "the router refused A's departure"
        time.sleep(0.2)
        assert set(got) == {b"A leaves"}

