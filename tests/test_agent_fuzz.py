"""Fuzzing every key and queryable of a live agent: random bytes, mutated valid messages and
crafted impossible ones. The agent never raises, counts every rejection and keeps working."""

from __future__ import annotations

import random
import time
from collections.abc import Iterator
from pathlib import Path

import msgspec
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from agent.clock import ManualClock
from agent.net.memory import MemoryNetwork
from agent.net.router import client_config, start_router_process, stop_router_process
from agent.net.transport import ZenohTransport
from agent.runtime.core.events import Sample
from agent.runtime.shell.runtime import AgentConfig, AgentRuntime
from agent.storage.journal import Journal
from agent.wire import keys
from agent.wire.codec import Codec
from agent.wire.peer import (
    AgentState,
    Commit,
    Counters,
    Decision,
    LmSet,
    MissionStatus,
    Offer,
    Pose,
    Publication,
    Reply,
    Request,
    StatusQuery,
    pack,
)
from tests.agent_helpers import thesis

M = "fz"
SC = thesis("hexagon_5_3")
REQ: Codec[Request] = Codec(Request)
PUB: Codec[Publication] = Codec(Publication)
P = (0.0, 0.0, 0.0)
V = (1.0, 0.0, 0.0)


def valid_payloads() -> list[tuple[str, bytes]]:
    """(target, payload) pairs of well-formed messages; target is pose|state|trade."""
    state = AgentState(sender="B", incarnation=1, seq=5, t=1.0, p=P, v=V, phase="converged",
                       owned=pack({2: 0, 4: 0}), held=pack({}), vision=1.0, counters=Counters(),
                       partners=["A"], pending=[], trades_with={"A": 1})
    return [
        ("trade", REQ.encode(Offer(sender="B", trade_id="B:1:1", p=P, v=V, owned=pack({2: 0})))),
        ("trade", REQ.encode(Commit(sender="B", trade_id="B:1:1"))),
        ("trade", REQ.encode(StatusQuery(sender="B", trade_id="A:1:1"))),
        ("pose", PUB.encode(Pose(sender="B", seq=1, t=0.0, p=P, v=V))),
        ("state", PUB.encode(state)),
        ("state", PUB.encode(MissionStatus(sender="B", t=0.0, complete=True, coverage=1.0,
                                           agents=["A"]))),
    ]


def impossible_payloads() -> list[tuple[str, bytes]]:
    """Well-formed msgpack that must be rejected (schema, NaN, ids, sender, versions...)."""
    enc = msgspec.msgpack.Encoder()
    nan = float("nan")
    return [
        ("trade", REQ.encode(Offer(sender="B", trade_id="B:1:9", p=P, v=V, owned=pack({2: 0}),
                                   schema=7))),
        ("trade", REQ.encode(Offer(sender="B", trade_id="B:1:9", p=(nan, 0.0, 0.0), v=V,
                                   owned=pack({2: 0})))),
        ("trade", REQ.encode(Offer(sender="Z", trade_id="Z:1:1", p=P, v=V, owned=pack({2: 0})))),
        ("trade", REQ.encode(Offer(sender="B", trade_id="B:1:10", p=P, v=(3.0, 0.0, 0.0),
                                   owned=pack({2: 0})))),
        ("trade", enc.encode({"kind": "offer", "sender": "B"})),
        ("trade", enc.encode([1, 2, 3])),
        ("pose", PUB.encode(Pose(sender="C", seq=1, t=0.0, p=P, v=V))),  # wrong key
        ("pose", PUB.encode(Pose(sender="B", seq=1, t=float("inf"), p=P, v=V))),
        ("pose", PUB.encode(Pose(sender="B", seq=1, t=0.0, p=P, v=(0.0, 0.0, 0.0)))),
        ("state", PUB.encode(AgentState(
            sender="B", incarnation=1, seq=9, t=1.0, p=P, v=V, phase="converged",
            owned=pack({999: 0}), held=pack({}), vision=1.0, counters=Counters(),
            partners=[], pending=[],
            trades_with={}))),
        ("state", PUB.encode(AgentState(
            sender="B", incarnation=1, seq=9, t=1.0, p=P, v=V, phase="converged",
            owned=LmSet(b"\x02" + bytes(7), b"\x00"), held=pack({}), vision=1.0,
            counters=Counters(), partners=[], pending=[],
            trades_with={}))),
        ("state", PUB.encode(Pose(sender="B", seq=1, t=0.0, p=P, v=V))),  # pose on state key
        ("pose", b""),
        ("state", b"\xc1"),
    ]


def mutate(rng: random.Random, data: bytes) -> bytes:
    b = bytearray(data)
    op = rng.randrange(5)
    if op == 0 and b:
        for _ in range(rng.randint(1, 4)):
            b[rng.randrange(len(b))] = rng.randrange(256)
    elif op == 1:
        b = b[: rng.randrange(len(b) + 1)]
    elif op == 2:
        pos = rng.randrange(len(b) + 1)
        b[pos:pos] = rng.randbytes(rng.randint(1, 8))
    elif op == 3 and len(b) > 2:
        i, j = sorted(rng.sample(range(len(b)), 2))
        b = b[:i] + b[j:] + b[i:j]
    else:
        b = bytearray(rng.randbytes(rng.randint(0, 64)))
    return bytes(b)


@pytest.fixture
def agent(tmp_path: Path) -> Iterator[AgentRuntime]:
    net = MemoryNetwork()
    clock = ManualClock(source=lambda: net.now)
    journal = Journal(tmp_path / "A")
    rt = AgentRuntime("A", SC, net.transport("A"), journal, clock,
                      config=AgentConfig(mission=M))
    rt.start()
    rt.core.shared.converge()  # converged: offers are evaluated, not just answered Busy
    yield rt
    rt.stop()
    journal.close()


def deliver(rt: AgentRuntime, target: str, payload: bytes) -> bytes | None:
    """Deliver ``payload`` through the runtime's one door (its query handler, its samples)."""
    if target == "trade":
        return rt.on_query(payload, keys.trade_key(M, "A"))
    if target == "pose":
        rt.step(Sample("pose", keys.pose_key(M, "B"), payload, 0.0))
    else:
        rt.step(Sample("state", keys.state_key(M, "B"), payload, 0.0))
    return None


def test_impossible_payloads_are_all_rejected(agent: AgentRuntime) -> None:
    before = dict(agent.core.machine.owned)
    for target, payload in impossible_payloads():
        n = agent.core.rejects.total
        deliver(agent, target, payload)
        assert agent.core.rejects.total == n + 1, (target, payload)
    assert agent.core.machine.owned == before and not agent.core.machine.held


def test_thousands_of_mutated_and_random_payloads(agent: AgentRuntime) -> None:
    rng = random.Random(1234)
    seeds = valid_payloads()
    rep: Codec[Reply] = Codec(Reply)
    counted = decoded = 0
    for i in range(4000):
        target, base = seeds[i % len(seeds)]
        payload = mutate(rng, base) if i % 4 else rng.randbytes(rng.randint(0, 200))
        n = agent.core.rejects.total
        out = deliver(agent, target, payload)
        if agent.core.rejects.total > n:
            counted += 1
        else:  # not counted: it must have been a well-formed message
            codec = REQ if target == "trade" else PUB
            assert codec.decode(payload) is not None
            decoded += 1
        if out is not None:
            assert rep.decode(out) is not None
    assert counted > 3000
    # Still answers a proper query.
    answer = agent.on_query(REQ.encode(StatusQuery(sender="B", trade_id="A:1:77")),
                            keys.trade_key(M, "A"))
    assert answer is not None
    reply = rep.decode(answer)
    assert isinstance(reply, Decision) and reply.status == "aborted"


@settings(max_examples=300, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.binary(max_size=300), target=st.sampled_from(["trade", "pose", "state"]))
def test_hypothesis_random_bytes(agent: AgentRuntime, data: bytes, target: str) -> None:
    n = agent.core.rejects.total
    deliver(agent, target, data)
    codec = REQ if target == "trade" else PUB
    assert agent.core.rejects.total > n or codec.decode(data) is not None


def test_fuzz_over_zenoh(tmp_path: Path) -> None:
    """A few hundred bad payloads over a real router on every key and the queryable."""
    proc, ep = start_router_process()
    tp = ZenohTransport(client_config(ep), None, "A")
    evil = ZenohTransport(client_config(ep), None, "B")
    journal = Journal(tmp_path / "A")
    clock = ManualClock()
    rt = AgentRuntime("A", SC, tp, journal, clock, config=AgentConfig(mission=M))
    try:
        rt.start()
        rng = random.Random(5)
        seeds = valid_payloads()
        bad = impossible_payloads()
        sent = 0
        for i in range(300):
            target, base = bad[i % len(bad)] if i % 3 == 0 else seeds[i % len(seeds)]
            payload = base if i % 3 == 0 else mutate(rng, base)
            if target == "trade":
                evil.request(keys.trade_key(M, "A"), payload, 0.2)
            else:
                key = keys.pose_key(M, "B") if target == "pose" else keys.state_key(M, "B")
                evil.publish(key, payload)
                evil.publish(keys.status_key(M, "B"), payload)
            sent += 1
        deadline = time.monotonic() + 5.0
        while rt.core.rejects.total < 100 and time.monotonic() < deadline:
            time.sleep(0.05)
        assert rt.core.rejects.total >= 100
        raw = evil.request(keys.trade_key(M, "A"),
                           REQ.encode(StatusQuery(sender="B", trade_id="A:1:5")), 1.0)
        assert raw is not None and isinstance(Codec(Reply).decode(raw), Decision)
    finally:
        rt.stop()
        tp.close()
        evil.close()
        journal.close()
        stop_router_process(proc)
