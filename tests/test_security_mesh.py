"""The secured profile against a real router (mutual TLS, access control by certificate name):
who may connect, who may publish, declare and answer what, and what a signed agent does with
forged, replayed and fuzzed trade messages."""

from __future__ import annotations

import contextlib
import functools
import json
import random
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import zenoh

from agent.clock import ManualClock
from agent.net.pki import TeamPlan, make_team
from agent.net.router import client_config
from agent.net.security import GROUND, OBSERVER, TeamDir, drone_name, load_signing
from agent.net.security import client_config as secure_config
from agent.net.transport import ZenohTransport
from agent.runners.orders import Orders
from agent.runtime.shell.runtime import AgentConfig, AgentRuntime
from agent.storage.journal import Journal
from agent.wire import keys
from agent.wire.codec import Codec
from agent.wire.peer import Commit, Decision, Offer, Reply, Request, StatusQuery, pack
from agent.wire.signed import SigningKeys, TradeSeal
from tests.agent_helpers import thesis
from tests.conftest import wait_until

M = "sec"
SC = thesis("hexagon_5_3")  # A owns 3, 6; B owns 2, 4; C owns 1, 5
REQ: Codec[Request] = Codec(Request)
REP: Codec[Reply] = Codec(Reply)
P, V = (0.0, 0.0, 0.0), (1.0, 0.0, 0.0)


def open_as(team: TeamDir, endpoint: str, identity: str) -> zenoh.Session:
    """A Zenoh session presenting ``identity``'s certificate."""
    return zenoh.open(secure_config(team, [endpoint], identity))


def raw_config(endpoint: str, tls: dict[str, Any]) -> zenoh.Config:
    """A client config with a hand-made TLS block."""
    return zenoh.Config.from_json5(json.dumps({
        "mode": "client", "connect": {"endpoints": [endpoint]},
        "scouting": {"multicast": {"enabled": False}, "gossip": {"enabled": False}},
        "transport": {"link": {"tls": tls}}}))


def test_only_team_certificates_connect(team: TeamDir, secured_router: str,
                                        tmp_path: Path) -> None:
    other = make_team(TeamPlan(tmp_path / "other", ["A"]))  # another CA, same names
    port = secured_router.rsplit(":", 1)[1]
    attempts = {
        "plain tcp": client_config([f"tcp/127.0.0.1:{port}"]),
        "tls, no certificate": raw_config(secured_router, {"root_ca_certificate": str(team.ca)}),
        "certificate of another CA": raw_config(secured_router, {
            "root_ca_certificate": str(team.ca), "enable_mtls": True,
            "connect_certificate": str(other.cert("drone-A")),
            "connect_private_key": str(other.key("drone-A"))}),
        "router not trusted": raw_config(secured_router, {
            "root_ca_certificate": str(other.ca), "enable_mtls": True,
            "connect_certificate": str(team.cert("drone-A")),
            "connect_private_key": str(team.key("drone-A"))}),
    }
    for what, cfg in attempts.items():
        with pytest.raises(zenoh.ZError), zenoh.open(cfg):
            pytest.fail(f"{what}: connected")
    with open_as(team, secured_router, drone_name("A")):  # the team's own certificate does
        pass


def test_keys_belong_to_their_owners(team: TeamDir, secured_router: str) -> None:
    """Drone B cannot publish A's pose/state/status, the ground station's mocap, clock,
    landmarks or commands, declare A's liveliness token or A's trade queryable; observers
    publish and query nothing. What is allowed still flows."""
    # obs listens; obs2, another observer, tries to write (a session hears its own puts).
    got: list[tuple[str, bytes]] = []
    live: list[str] = []  # "key kind" of every liveliness event
    with contextlib.ExitStack() as sessions:
        obs, obs2, a, b, c, ground = (
            sessions.enter_context(open_as(team, secured_router, n)) for n in (
                OBSERVER, OBSERVER, drone_name("A"), drone_name("B"), drone_name("C"), GROUND))
        obs.declare_subscriber(f"viscover/{M}/**",
                               lambda s: got.append((str(s.key_expr), s.payload.to_bytes())))
        obs.liveliness().declare_subscriber(
            f"viscover/{M}/alive/*", lambda s: live.append(f"{s.key_expr} {s.kind}"),
            history=True)
        probe = f"viscover/{M}/landmarks"  # the subscription works end to end: start
        assert wait_until(lambda: bool(got), 5.0, 0.05, lambda: ground.put(probe, b"probe"))
        time.sleep(0.1)
        got.clear()
        forged = [keys.pose_key(M, "A"), keys.state_key(M, "A"), keys.status_key(M, "A"),
                  keys.command_ack_key(M, "A"), keys.mocap_key(M, "A"), keys.clock_key(M),
                  keys.landmarks_key(M), keys.command_key(M)]
        for k in forged:
            b.put(k, b"forged by B")
            obs2.put(k, b"forged by an observer")
        a.put(keys.pose_key(M, "A"), b"A")
        b.put(keys.pose_key(M, "B"), b"B")
        ground.put(keys.clock_key(M), b"ground")
        b.liveliness().declare_token(keys.alive_key(M, "A"))
        b.liveliness().declare_token(keys.alive_key(M, "C"))
        b.declare_queryable(keys.trade_key(M, "A"), functools.partial(reply_as_a, b"B"))
        a.declare_queryable(keys.trade_key(M, "A"), functools.partial(reply_as_a, b"A"))
        with a.liveliness().declare_token(keys.alive_key(M, "A")):
            assert wait_until(lambda: len(got) >= 3 and live, 3.0)
            time.sleep(0.3)  # anything forged would have arrived by now
            assert sorted(got) == sorted([(keys.pose_key(M, "A"), b"A"),
                                          (keys.pose_key(M, "B"), b"B"),
                                          (keys.clock_key(M), b"ground")])
            assert set(live) == {f"{keys.alive_key(M, 'A')} SampleKind.PUT"}
        # A leaves (its token undeclared): gone for everyone, although B still holds its
        # forged A and C tokens.
        assert wait_until(lambda: any("DELETE" in x for x in live), 3.0)
        assert [r for r in obs.liveliness().get(f"viscover/{M}/alive/*", timeout=1.0)] == []

        def answers(session: zenoh.Session) -> list[bytes]:
            """The replies ``session`` gets from A's trade key."""
            return [r.ok.payload.to_bytes() for r in
                    session.get(keys.trade_key(M, "A"), timeout=1.0) if r.ok is not None]

        assert wait_until(lambda: answers(c) == [b"A"], 3.0)  # only A answers A's trades
        assert answers(c) == [b"A"]
        assert answers(obs) == []  # observers do not query


def reply_as_a(answer: bytes, query: zenoh.Query) -> None:
    """Answer a query on A's trade key with ``answer``, then finalise it."""
    with query:
        query.reply(keys.trade_key(M, "A"), answer)


def signed_agent(team: TeamDir, endpoint: str, aid: str, tmp: Path) -> AgentRuntime:
    """A started, converged agent ``aid`` on the secured profile (manual clock)."""
    tp = ZenohTransport(secure_config(team, [endpoint], drone_name(aid)), None, aid)
    rt = AgentRuntime(aid, SC, tp, Journal(tmp / aid), ManualClock(),
                      config=AgentConfig(mission=M, signing=load_signing(team, aid)))
    rt.start()
    rt.core.shared.converge()
    return rt


def close_agent(rt: AgentRuntime) -> None:
    """Stop an agent of :func:`signed_agent` and close its session and journal."""
    rt.stop()
    rt.tp.close()
    assert isinstance(rt.journal, Journal)
    rt.journal.close()


@pytest.fixture
def agent_b(team: TeamDir, secured_router: str, tmp_path: Path) -> Iterator[AgentRuntime]:
    """Drone B, signed and converged, on the secured router."""
    rt = signed_agent(team, secured_router, "B", tmp_path)
    yield rt
    close_agent(rt)


def test_forged_and_replayed_queries_take_nothing(team: TeamDir, secured_router: str,
                                                  agent_b: AgentRuntime) -> None:
    """Drone C, authenticated, tries to take B's landmark 4 in A's name: unsigned, signed by
    itself with A's name inside, for another mission, and A's genuine request replayed. B
    answers none, counts each, and its ledger is untouched; a genuine request is still answered."""
    owned = agent_b.core.machine.owned
    evil = ZenohTransport(secure_config(team, [secured_router], drone_name("C")), None, "C")
    a_keys, c_keys = load_signing(team, "A"), load_signing(team, "C")
    offer = REQ.encode(Offer(sender="A", trade_id="A:1:1", p=P, v=V, owned=pack({4: 0})))
    commit = REQ.encode(Commit(sender="A", trade_id="A:1:1"))
    seal = agent_b.seal
    assert seal is not None  # B signs
    boot = seal.boot

    def sealer(k: SigningKeys, mission: str = M) -> TradeSeal:
        """A seal that knows B's incarnation (as after a first contact)."""
        out = TradeSeal(k, mission)
        out.know("B", boot)
        return out

    attempts = [
        ("unsigned", offer), ("unsigned", commit),
        ("forged", sealer(c_keys).seal_request(offer, "B")[0]),  # C signs "A"'s offer
        ("forged", sealer(SigningKeys("A", c_keys.private, c_keys.team))
         .seal_request(offer, "B")[0]),  # C's key, A's name: bad signature
        ("forged", sealer(a_keys, "other").seal_request(offer, "B")[0]),  # other mission
    ]
    key = keys.trade_key(M, "B")
    a_seal = sealer(a_keys)
    status = REQ.encode(StatusQuery(sender="A", trade_id="B:1:1"))
    try:  # B's queryable is reachable (a genuine signed question is answered): start
        assert wait_until(lambda: evil.request(key, a_seal.seal_request(status, "B")[0], 0.5)
                          is not None, 5.0)
        for reason, payload in attempts:
            before = agent_b.core.rejects.by_reason[reason]
            assert evil.request(key, payload, 1.0) is None, reason
            assert agent_b.core.rejects.by_reason[reason] == before + 1, reason
        # A's genuine request, relayed once, is answered (refused: A does not own 4) ...
        genuine, _ = a_seal.seal_request(offer, "B")
        assert evil.request(key, genuine, 1.0) is not None
        assert evil.request(key, genuine, 1.0) is None  # ... and refused when replayed
        assert agent_b.core.rejects.by_reason["replay"] == 1
    finally:
        evil.close()
    assert agent_b.core.machine.owned == owned and not agent_b.core.machine.prepared


def test_signed_agents_trade_over_the_secured_router(team: TeamDir, secured_router: str,
                                                     agent_b: AgentRuntime,
                                                     tmp_path: Path) -> None:
    a = signed_agent(team, secured_router, "A", tmp_path)
    try:
        assert wait_until(lambda: "B" in a.core.members.live, 5.0)
        query = REQ.encode(StatusQuery(sender="A", trade_id="B:1:9"))
        reply = a.drive(a.core.client.request("B", query))
        assert isinstance(reply, Decision) and reply.sender == "B"
        a.core.shared.partners.reset()
        a.core.client.maybe_offer(0.0)
        a.drive(a.core.client.attempt_offer(0.0))
        a.drive(a.core.client.service_pending(0.0))
        # Algorithm 7 moves landmarks between A and B at their start poses: a whole trade.
        assert a.core.machine.ok == 1 and agent_b.core.machine.ok == 1
        assert not a.core.machine.pending_ids
        assert a.core.rejects.total == 0 and agent_b.core.rejects.total == 0
    finally:
        close_agent(a)


def mutate(rng: random.Random, data: bytes) -> bytes:
    """``data`` with a few bytes changed, cut, or replaced by random bytes."""
    b = bytearray(data)
    op = rng.randrange(3)
    if op == 0 and b:
        for _ in range(rng.randint(1, 4)):
            b[rng.randrange(len(b))] = rng.randrange(256)
        return bytes(b)
    if op == 1:
        return bytes(b[: rng.randrange(len(b) + 1)])
    return rng.randbytes(rng.randint(0, 300))


def ignore(_reply: Any) -> None:
    """A reply handler that drops every reply."""


def test_fuzzed_payloads_on_every_key_crash_nothing(team: TeamDir, secured_router: str,
                                                    agent_b: AgentRuntime) -> None:
    """Junk from authenticated peers on every key B listens to (peers' pose, state, status,
    its trade queryable; the ground station's command key): counted, never applied."""
    rng = random.Random(14)
    orders = Orders(agent_b.tp, M, "B")
    sessions = contextlib.ExitStack()  # C's and the ground station's, closed at the end
    c = sessions.enter_context(open_as(team, secured_router, drone_name("C")))
    ground = sessions.enter_context(open_as(team, secured_router, GROUND))
    a_seal = TradeSeal(load_signing(team, "A"), M)
    b_seal = agent_b.seal
    assert b_seal is not None  # B signs
    a_seal.know("B", b_seal.boot)
    owned = agent_b.core.machine.owned
    seeds = [a_seal.seal_request(REQ.encode(StatusQuery(sender="A", trade_id="B:1:1")), "B")[0],
             REQ.encode(Offer(sender="C", trade_id="C:1:1", p=P, v=V, owned=pack({5: 0})))]
    try:
        time.sleep(0.2)
        before = agent_b.core.rejects.total
        for i in range(200):
            payload = mutate(rng, seeds[i % 2])
            c.get(keys.trade_key(M, "B"), ignore, payload=payload, timeout=1.0)
            c.put(keys.pose_key(M, "C"), payload)
            c.put(keys.state_key(M, "C"), payload)
            ground.put(keys.command_key(M), payload)
        assert wait_until(lambda: agent_b.core.rejects.total - before >= 400, 5.0)
        assert orders.received is None and orders.rejects.total > 0
        assert agent_b.core.machine.owned == owned and not agent_b.core.machine.prepared
        # B still answers a genuine signed query.
        tp = ZenohTransport(secure_config(team, [secured_router], drone_name("A")), None, "A")
        try:
            body = REQ.encode(StatusQuery(sender="A", trade_id="B:1:2"))
            data, nonce = a_seal.seal_request(body, "B")
            raw = tp.request(keys.trade_key(M, "B"), data, 1.0)
            assert raw is not None
            inner = a_seal.open_reply(raw, "B", nonce)
            assert isinstance(inner, bytes) and isinstance(REP.decode(inner), Decision)
        finally:
            tp.close()
    finally:
        orders.close()
        sessions.close()
