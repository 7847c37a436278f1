"""MemoryTransport / MemoryNetwork: the in-process double of the Zenoh transport."""

from __future__ import annotations

import pytest

from agent.net.faults import FaultConfig, FaultInjector
from agent.net.memory import MemoryNetwork, intersects
from agent.net.transport import Transport
from agent.wire import keys


@pytest.mark.parametrize(
    ("a", "b", "expected"),
    [
        ("a/b/c", "a/b/c", True),
        ("a/*/c", "a/b/c", True),
        ("a/*", "a/b/c", False),
        ("a/**", "a/b/c", True),
        ("a/**", "a", True),
        ("**", "x/y", True),
        ("a/**/c", "a/c", True),
        ("a/**/c", "a/x/y/c", True),
        ("a/**/c", "a/x/y/d", False),
        ("a/*/c", "a/**", True),
        ("a/b", "a/c", False),
        ("viscover/m1/pose/*", "viscover/m2/pose/a", False),
    ],
)
def test_intersects(a: str, b: str, expected: bool) -> None:
    assert intersects(a, b) is expected
    assert intersects(b, a) is expected


def test_is_a_transport() -> None:
    net = MemoryNetwork()
    assert isinstance(net.transport("a"), Transport)


def test_pub_sub_wildcards_and_missions() -> None:
    net = MemoryNetwork()
    a, b = net.transport("a"), net.transport("b")
    got: list[tuple[str, bytes]] = []
    b.subscribe(keys.all_agents("m1", "pose"), lambda k, p: got.append((k, p)))
    other: list[str] = []
    b.subscribe("viscover/m2/**", lambda k, _p: other.append(k))
    a.publish(keys.pose_key("m1", "a"), b"p1")
    a.publish(keys.state_key("m1", "a"), b"s1")
    a.publish(keys.pose_key("m2", "a"), b"p2")
    assert got == [("viscover/m1/pose/a", b"p1")]
    assert other == ["viscover/m2/pose/a"]


def test_order_kept_and_reentrant_publish() -> None:
    net = MemoryNetwork()
    a = net.transport("a")
    seen: list[bytes] = []

    def echo(key: str, payload: bytes) -> None:
        seen.append(payload)
        if payload.startswith(b"x"):
            a.publish("t/echo", b"echo-" + payload)

    a.subscribe("t/**", echo)
    for i in range(3):
        a.publish("t/in", b"x%d" % i)
    assert seen == [b"x0", b"echo-x0", b"x1", b"echo-x1", b"x2", b"echo-x2"]


def test_undeclare_stops_delivery() -> None:
    net = MemoryNetwork()
    a = net.transport("a")
    got: list[bytes] = []
    sub = a.subscribe("k", lambda _k, p: got.append(p))
    a.publish("k", b"1")
    sub.undeclare()
    sub.undeclare()
    a.publish("k", b"2")
    assert got == [b"1"]


def test_query_round_trip_and_no_queryable() -> None:
    net = MemoryNetwork()
    a, b = net.transport("a"), net.transport("b")
    calls: list[tuple[bytes, str]] = []

    def handler(payload: bytes, selector: str) -> bytes | None:
        calls.append((payload, selector))
        return None if payload == b"ignore" else payload[::-1]

    b.declare_queryable(keys.trade_key("m", "b"), handler)
    assert a.request(keys.trade_key("m", "b"), b"abc", timeout=0.5) == b"cba"
    assert a.request(keys.trade_key("m", "b"), b"ignore", timeout=0.5) is None
    assert a.request(keys.trade_key("m", "zz"), b"abc", timeout=0.5) is None
    assert calls[0] == (b"abc", "viscover/m/trade/b")


def test_query_timeout_by_virtual_latency() -> None:
    net = MemoryNetwork()
    a = net.transport("a", FaultInjector(FaultConfig(delay_s=0.3), seed=1))
    b = net.transport("b", FaultInjector(FaultConfig(delay_s=0.3), seed=2))
    b.declare_queryable("svc/b", lambda p, _s: p)
    assert a.request("svc/b", b"x", timeout=1.0) == b"x"  # 0.3 + 0.3 < 1.0
    assert a.request("svc/b", b"x", timeout=0.5) is None  # 0.6 >= 0.5: reply too late


def test_query_dropped_by_faults() -> None:
    net = MemoryNetwork()
    a = net.transport("a", FaultInjector(FaultConfig(drop_out={"trade": 1.0}), seed=1))
    b = net.transport("b")
    b.declare_queryable(keys.trade_key("m", "b"), lambda p, _s: p)
    assert a.request(keys.trade_key("m", "b"), b"x", timeout=0.5) is None
    assert a.request(keys.trade_key("m", "b"), b"x", timeout=0.5, kind="other") == b"x"


def test_reply_dropped_by_server_faults() -> None:
    net = MemoryNetwork()
    a = net.transport("a")
    b = net.transport("b", FaultInjector(FaultConfig(drop_out={"trade.reply": 1.0}), seed=1))
    b.declare_queryable(keys.trade_key("m", "b"), lambda p, _s: p)
    assert a.request(keys.trade_key("m", "b"), b"x", timeout=0.5) is None


def test_liveliness_join_leave_and_kill() -> None:
    net = MemoryNetwork()
    a, b, w = net.transport("a"), net.transport("b"), net.transport("w")
    a.declare_liveliness(keys.alive_key("m", "a"))
    events: list[tuple[str, str]] = []
    w.watch_liveliness(
        keys.all_agents("m", "alive"),
        lambda k: events.append(("join", k)),
        lambda k: events.append(("leave", k)),
    )
    assert events == [("join", "viscover/m/alive/a")]  # history
    tok = b.declare_liveliness(keys.alive_key("m", "b"))
    tok.undeclare()
    a.close()
    assert events[1:] == [
        ("join", "viscover/m/alive/b"),
        ("leave", "viscover/m/alive/b"),
        ("leave", "viscover/m/alive/a"),
    ]
    c = net.transport("c")
    c.declare_liveliness(keys.alive_key("m", "c"))
    c.declare_queryable("svc/c", lambda p, _s: p)
    net.kill("c")
    assert events[-1] == ("leave", "viscover/m/alive/c")
    assert w.request("svc/c", b"x", timeout=0.1) is None


def test_delays_need_advance_and_reorder_deterministically() -> None:
    def run(seed: int) -> list[bytes]:
        net = MemoryNetwork()
        inj = FaultInjector(FaultConfig(jitter_s=0.1, duplicate=0.3), seed=seed)
        a, b = net.transport("a", inj), net.transport("b")
        got: list[bytes] = []
        b.subscribe("k", lambda _k, p: got.append(p))
        for i in range(50):
            a.publish("k", b"%d" % i)
        assert net.pending > 0
        net.advance(0.2)
        assert net.pending == 0
        return got

    first = run(5)
    assert first == run(5)
    assert len(first) > 50  # duplicates
    assert first != sorted(first, key=int)  # jitter reorders
    assert set(first) == {b"%d" % i for i in range(50)}


def test_incoming_drop_and_partition() -> None:
    net = MemoryNetwork()
    a, c = net.transport("a"), net.transport("c")
    b = net.transport("b", FaultInjector(FaultConfig(drop_in={"pose": 1.0}, partition=["c"]), 0))
    got: list[bytes] = []
    b.subscribe("viscover/m/**", lambda _k, p: got.append(p))
    a.publish(keys.pose_key("m", "a"), b"pose")
    a.publish(keys.state_key("m", "a"), b"state")
    c.publish(keys.state_key("m", "c"), b"from-c")
    assert got == [b"state"]


def test_closed_transport() -> None:
    net = MemoryNetwork()
    a = net.transport("a")
    a.close()
    a.close()
    assert a.request("x", b"", 0.1) is None
    with pytest.raises(RuntimeError):
        a.publish("x", b"")
    net.transport("a")  # the id can be reused after close
