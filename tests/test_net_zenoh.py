"""ZenohTransport against real routers started on free loopback ports."""

from __future__ import annotations

import subprocess
import sys
import textwrap
import threading
import time
from collections.abc import Callable, Iterator

import pytest
import zenoh

from agent.net.faults import FaultConfig, FaultInjector
from agent.net.router import client_config, start_router_process, stop_router_process
from agent.net.transport import Transport, ZenohTransport
from agent.wire import keys
from tests.conftest import ROOT, repo_env, wait_until

MakeTransport = Callable[..., ZenohTransport]


def wait_for(
    pred: Callable[[], object], timeout_s: float = 5.0, poke: Callable[[], object] | None = None
) -> None:
    """:func:`wait_until`, failing the test after ``timeout_s``."""
    if not wait_until(pred, timeout_s, poke=poke):
        pytest.fail(f"condition not met within {timeout_s} s")


@pytest.fixture
def make_transport(router: str) -> Iterator[MakeTransport]:
    made: list[ZenohTransport] = []

    def make(
        node_id: str = "n", faults: FaultInjector | None = None, endpoint: str | None = None
    ) -> ZenohTransport:
        t = ZenohTransport(client_config(endpoint or router), faults, node_id=node_id)
        made.append(t)
        return t

    yield make
    for t in made:
        t.close()


def test_is_a_transport(make_transport: MakeTransport) -> None:
    assert isinstance(make_transport(), Transport)


def test_pub_sub(make_transport: MakeTransport) -> None:
    a, b = make_transport("a"), make_transport("b")
    got: list[tuple[str, bytes]] = []
    threads: set[str] = set()

    def on_pose(key: str, payload: bytes) -> None:
        threads.add(threading.current_thread().name)
        got.append((key, payload))

    b.subscribe(keys.all_agents("m", "pose"), on_pose)
    wait_for(lambda: got, poke=lambda: a.publish(keys.pose_key("m", "a"), b"probe"))
    for i in range(200):
        a.publish(keys.pose_key("m", "a"), b"%d" % i)
    a.publish(keys.pose_key("other", "a"), b"not for us")

    def data() -> list[bytes]:
        return [p for _, p in got if p != b"probe"]

    wait_for(lambda: len(data()) >= 200)
    assert data() == [b"%d" % i for i in range(200)]
    assert {k for k, _ in got} == {"viscover/m/pose/a"}
    assert all(name.startswith("zenoh-events-b") for name in threads)


def _serve_echo(t: ZenohTransport, key: str) -> list[str]:
    threads: list[str] = []

    def handler(payload: bytes, selector: str) -> bytes | None:
        threads.append(threading.current_thread().name)
        return None if payload == b"ignore" else b"re:" + payload

    t.declare_queryable(key, handler)
    return threads


def test_query_round_trip(make_transport: MakeTransport) -> None:
    a, b = make_transport("a"), make_transport("b")
    key = keys.trade_key("m", "b")
    threads = _serve_echo(b, key)
    wait_for(lambda: a.request(key, b"hello", timeout=0.5) == b"re:hello")
    assert a.request(key, b"x" * 100_000, timeout=2.0) == b"re:" + b"x" * 100_000
    t0 = time.monotonic()
    assert a.request(key, b"ignore", timeout=2.0) is None  # no reply: ends at once
    assert time.monotonic() - t0 < 1.0
    assert threads and all(n.startswith("zenoh-queries-b") for n in threads)


def test_query_timeout_without_queryable(make_transport: MakeTransport) -> None:
    a = make_transport("a")
    t0 = time.monotonic()
    assert a.request(keys.trade_key("m", "nobody"), b"x", timeout=1.0) is None
    assert time.monotonic() - t0 < 1.0


def test_slow_handler_times_out(make_transport: MakeTransport) -> None:
    a, b = make_transport("a"), make_transport("b")
    release = threading.Event()

    def slow(payload: bytes, _selector: str) -> bytes | None:
        release.wait(5.0)
        return payload

    key = keys.trade_key("m", "slow")
    b.declare_queryable(key, slow)
    fast = keys.trade_key("m", "b")
    _serve_echo(b, fast)
    wait_for(lambda: a.request(fast, b"1", timeout=0.5) is not None)
    t0 = time.monotonic()
    assert a.request(key, b"x", timeout=0.3) is None
    assert 0.25 < time.monotonic() - t0 < 2.0
    release.set()


def test_liveliness_leave_on_close(make_transport: MakeTransport) -> None:
    a, w = make_transport("a"), make_transport("w")
    events: list[tuple[str, str]] = []
    a.declare_liveliness(keys.alive_key("m", "a"))
    w.watch_liveliness(
        keys.all_agents("m", "alive"),
        lambda k: events.append(("join", k)),
        lambda k: events.append(("leave", k)),
    )
    wait_for(lambda: ("join", "viscover/m/alive/a") in events)
    a.close()
    wait_for(lambda: ("leave", "viscover/m/alive/a") in events, timeout_s=3.0)


PEER_SCRIPT = textwrap.dedent(
    """
    import sys, time
    from agent.net.router import client_config
    from agent.net.transport import ZenohTransport
    t = ZenohTransport(client_config(sys.argv[1]), node_id="peer")
    t.declare_queryable(sys.argv[2], lambda payload, selector: b"peer:" + payload)
    t.declare_liveliness(sys.argv[3])
    print("ready", flush=True)
    time.sleep(60)
    """
)


def test_query_to_killed_peer_returns_none(router: str, make_transport: MakeTransport) -> None:
    key, alive = keys.trade_key("m", "peer"), keys.alive_key("m", "peer")
    env = repo_env()
    proc = subprocess.Popen(
        [sys.executable, "-c", PEER_SCRIPT, router, key, alive], stdout=subprocess.PIPE, env=env
    )
    try:
        assert proc.stdout is not None
        assert proc.stdout.readline().strip() == b"ready"
        a = make_transport("a")
        left = threading.Event()
        a.watch_liveliness(alive, lambda _k: None, lambda _k: left.set())
        wait_for(lambda: a.request(key, b"x", timeout=0.5) == b"peer:x")
        proc.kill()
        proc.wait(5.0)
        assert left.wait(3.0), "liveliness did not report the killed peer"
        t0 = time.monotonic()
        assert a.request(key, b"x", timeout=1.0) is None
        assert time.monotonic() - t0 < 1.5
    finally:
        if proc.poll() is None:
            proc.kill()
        proc.wait(5.0)
        if proc.stdout is not None:
            proc.stdout.close()


def test_two_linked_routers(router: str, make_transport: MakeTransport) -> None:
    proc_b, endpoint_b = start_router_process(connect=[router])
    try:
        a = make_transport("a", endpoint=router)
        b = make_transport("b", endpoint=endpoint_b)
        ka, kb = keys.trade_key("m", "a"), keys.trade_key("m", "b")
        _serve_echo(a, ka)
        _serve_echo(b, kb)
        wait_for(lambda: a.request(kb, b"from-a", timeout=0.5) == b"re:from-a", timeout_s=10.0)
        wait_for(lambda: b.request(ka, b"from-b", timeout=0.5) == b"re:from-b", timeout_s=10.0)
        got: list[bytes] = []
        a.subscribe(keys.all_agents("m", "state"), lambda _k, p: got.append(p))
        wait_for(lambda: got, poke=lambda: b.publish(keys.state_key("m", "b"), b"s"))
    finally:
        stop_router_process(proc_b)


def test_faults_drop_all_queries_of_a_kind(make_transport: MakeTransport) -> None:
    faults = FaultInjector(FaultConfig(drop_out={"trade": 1.0}), seed=0)
    a, b = make_transport("a", faults), make_transport("b")
    key = keys.trade_key("m", "b")
    _serve_echo(b, key)
    wait_for(lambda: a.request(key, b"x", timeout=0.5, kind="probe") is not None)
    t0 = time.monotonic()
    assert a.request(key, b"x", timeout=0.3) is None
    assert time.monotonic() - t0 >= 0.29  # a lost query costs the full timeout
    assert faults.records[-1].reason == "drop"


def test_faults_dropped_reply_times_out(make_transport: MakeTransport) -> None:
    faults = FaultInjector(FaultConfig(drop_out={"trade.reply": 1.0}), seed=0)
    a, b = make_transport("a"), make_transport("b", faults)
    key = keys.trade_key("m", "b")
    _serve_echo(b, key)
    wait_for(lambda: a.request(key, b"x", timeout=0.5, kind="probe") is not None)
    t0 = time.monotonic()
    assert a.request(key, b"x", timeout=0.3) is None
    assert time.monotonic() - t0 >= 0.25


def test_faults_delayed_reply_past_timeout_is_lost(make_transport: MakeTransport) -> None:
    faults = FaultInjector(FaultConfig(delay_s=0.4), seed=0)
    a, b = make_transport("a"), make_transport("b", faults)
    key = keys.trade_key("m", "b")
    _serve_echo(b, key)
    wait_for(lambda: a.request(key, b"x", timeout=1.0) is not None)
    assert a.request(key, b"x", timeout=0.2) is None
    assert a.request(key, b"y", timeout=1.5) == b"re:y"


def test_faults_on_publish_and_receive(make_transport: MakeTransport) -> None:
    out_faults = FaultInjector(FaultConfig(drop_out={"pose": 1.0}, duplicate=1.0), seed=0)
    in_faults = FaultInjector(FaultConfig(partition=["c"]), seed=0)
    a, c = make_transport("a", out_faults), make_transport("c")
    b = make_transport("b", in_faults)
    got: list[bytes] = []
    b.subscribe("viscover/m/**", lambda _k, p: got.append(p))
    wait_for(lambda: got, poke=lambda: a.publish(keys.state_key("m", "a"), b"probe"))
    a.publish(keys.pose_key("m", "a"), b"dropped")
    a.publish(keys.state_key("m", "a"), b"dup")
    c.publish(keys.state_key("m", "c"), b"partitioned")

    def data() -> list[bytes]:
        return [p for p in got if p != b"probe"]

    wait_for(lambda: len(data()) >= 2)
    time.sleep(0.1)  # give any wrongly delivered message a chance to show up
    assert data() == [b"dup", b"dup"]


def test_close_is_clean_and_idempotent(make_transport: MakeTransport) -> None:
    a, b = make_transport("a"), make_transport("b")
    key = keys.trade_key("m", "b")
    _serve_echo(b, key)
    b.subscribe("viscover/**", lambda _k, _p: None)
    wait_for(lambda: a.request(key, b"x", timeout=0.5) is not None)
    before = {t.name for t in threading.enumerate()}
    assert any(n.startswith("zenoh-events-b") for n in before)
    b.close()
    b.close()
    after = {t.name for t in threading.enumerate()}
    assert not any(n.endswith("-b") or "-b-" in n for n in after if n.startswith("zenoh-"))
    assert b.session.is_closed()
    assert b.request(key, b"x", timeout=0.1) is None
    with pytest.raises(RuntimeError):
        b.publish(key, b"x")


def test_broker_config_files_parse() -> None:
    for name, mode in [("router", "router"), ("router_b", "router"), ("agent", "client")]:
        cfg = zenoh.Config.from_file(str(ROOT / "broker_config" / f"{name}.json5"))
        assert cfg.get_json("mode") == f'"{mode}"'
        assert cfg.get_json("scouting/multicast/enabled") == "false"
        assert cfg.get_json("transport/link/tx/lease") == "1000"


def test_tokens_reported_before_the_watch_is_registered_are_not_lost(
        make_transport: MakeTransport, monkeypatch: pytest.MonkeyPatch) -> None:
    """The history of existing tokens may be dispatched before ``watch_liveliness`` has
    recorded its handle (a loaded machine): it is sent once, so it must still be delivered."""
    a, w = make_transport("a"), make_transport("w")
    a.declare_liveliness(keys.alive_key("m", "a"))
    wait_for(lambda: keys.alive_key("m", "a") in {
        k for k in _tokens(make_transport("probe"))})
    track = ZenohTransport._track

    def slow_track(self: ZenohTransport, entity: object) -> object:
        time.sleep(0.5)  # the history sample reaches the events worker meanwhile
        return track(self, entity)

    monkeypatch.setattr(ZenohTransport, "_track", slow_track)
    events: list[str] = []
    w.watch_liveliness(keys.all_agents("m", "alive"), events.append, lambda _k: None)
    wait_for(lambda: events == [keys.alive_key("m", "a")], timeout_s=5.0)


def _tokens(tp: ZenohTransport) -> list[str]:
    """Keys of the live tokens under viscover/m/alive/* (a liveliness get)."""
    replies = tp.session.liveliness().get(keys.all_agents("m", "alive"), timeout=2.0)
    return [str(r.ok.key_expr) for r in replies if r.ok is not None]
