"""Issue 13, "Loss should cost little time": the pieces, without timing goals (those live in
``bench.bench_loss``). The round-trip estimator (RFC 6298) and the try schedule it gives; a
hedged request (several copies, the first reply wins) whose every copy reaches the responder
is answered and counted once, signed copies are sealed one by one and a reply is opened with
the nonce of the copy it answers; hedged missions are deterministic for a seed; the Zenoh
transport's hedged request against a real router."""

from __future__ import annotations

import math
import random
import time
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path

import pytest
from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey

from agent.clock import ManualClock
from agent.net.faults import DELIVER_NOW, Decision, Direction, FaultConfig, FaultInjector
from agent.net.memory import MemoryNetwork, MemoryTransport
from agent.net.router import client_config, start_router_process, stop_router_process
from agent.net.rtt import RttEstimator
from agent.net.transport import HedgedReply, HedgingTransport, ZenohTransport
from agent.protocol.records import CommittedRec, PreparedRec
from agent.runtime.shell.runtime import AgentConfig, AgentRuntime
from agent.storage.journal import Journal
from agent.testing import memsim
from agent.testing.memsim import MemoryMission
from agent.wire.signed import SigningKeys
from tests.agent_helpers import fixed_motion, random_scene

# -- the estimator ----------------------------------------------------------------------------


def test_rto_before_and_after_the_first_sample() -> None:
    est = RttEstimator(0.3, 0.01, 0.3)
    assert est.rto == est.hedge == 0.3  # nothing measured: the configured timeout
    offsets, timeout = est.schedule(6, 0)
    assert offsets == pytest.approx([0.0, 0.1, 0.2]) and timeout == 0.3
    est.sample(0.02)
    assert est.srtt == pytest.approx(0.02) and est.rttvar == pytest.approx(0.01)
    assert est.rto == pytest.approx(0.02 + 4 * 0.01)
    assert est.hedge == pytest.approx(0.02 + 2 * 0.01)
    est.sample(0.04)  # RTTVAR first (with the old SRTT), then SRTT
    assert est.rttvar == pytest.approx(0.75 * 0.01 + 0.25 * 0.02)
    assert est.srtt == pytest.approx(0.875 * 0.02 + 0.125 * 0.04)


def test_steady_round_trips_bring_the_rto_down_to_them() -> None:
    est = RttEstimator(0.3, 0.001, 0.3)
    for _ in range(200):
        est.sample(0.005)
    assert est.rttvar < 1e-6
    assert est.rto == pytest.approx(0.005, rel=1e-3)


@pytest.mark.parametrize("seed", range(5))
def test_rto_stays_within_its_bounds_and_hedges_first(seed: int) -> None:
    rng = random.Random(seed)
    est = RttEstimator(0.3, 0.01, 0.25)
    for _ in range(500):
        est.sample(rng.choice([rng.uniform(0.0, 0.004), rng.expovariate(20.0),
                               rng.uniform(0.0, 2.0)]))
        assert 0.01 <= est.hedge <= est.rto <= 0.25
        for failures in range(4):
            offsets, timeout = est.schedule(6, failures)
            assert 1 <= len(offsets) <= 6 and offsets[0] == 0.0
            assert est.rto <= timeout <= 6 * 0.25 and all(o < timeout for o in offsets)


def test_bad_samples_are_ignored() -> None:
    est = RttEstimator(0.3, 0.01, 0.3)
    for bad in (-0.1, math.nan, math.inf):
        est.sample(bad)
    assert est.samples == 0 and est.srtt is None and est.rto == 0.3
    with pytest.raises(ValueError):
        RttEstimator(0.3, 0.0, 0.3)


def test_schedule_spaces_copies_by_the_hedge_delay_and_backs_off() -> None:
    est = RttEstimator(0.3, 0.005, 0.3)
    for _ in range(50):
        est.sample(0.01)
    offsets, timeout = est.schedule(6, 0)
    gap = est.hedge
    assert offsets == pytest.approx([k * gap for k in range(6)])
    assert timeout == pytest.approx(5 * gap + est.rto)  # one RTO after the last copy
    # each try without a reply: half the copies (rounded up), delays doubled up to the cap
    for failures, n in enumerate([6, 3, 2, 1, 1, 1, 1, 1, 1], start=0):
        offs, t = est.schedule(6, failures)
        step = min(0.3, gap * 2**failures)
        assert offs == pytest.approx([k * step for k in range(n)])
        assert t == pytest.approx((n - 1) * step + min(0.3, est.rto * 2**failures))
        assert all(o < t for o in offs)
    assert est.schedule(6, 40) == ([0.0], 0.3)  # an unreachable partner: one copy, the cap
    assert est.schedule(1, 0) == ([0.0], est.rto)


def test_copies_go_out_two_or_three_at_a_time_while_many_are_lost() -> None:
    est = RttEstimator(0.3, 0.005, 0.3)
    for _ in range(20):
        est.sample(0.01)
    assert est.loss == 0.0 and est.width == 1
    rng = random.Random(3)
    for _ in range(400):  # each copy lost with probability 0.5; the first one not lost answers
        lost = 0
        while rng.random() < 0.5:
            lost += 1
        est.copies_lost(lost + 1, lost)
    assert 0.35 < est.loss < 0.6 and est.width == 2
    gap = est.hedge
    offsets, timeout = est.schedule(3, 0)
    assert offsets == pytest.approx([0.0, 0.0, gap, gap, 2 * gap, 2 * gap])
    assert timeout == pytest.approx(2 * gap + est.rto)
    for _ in range(100):
        est.copies_lost(6, None)  # nothing answered at all
    assert est.width == 3
    for _ in range(100):
        est.copies_lost(1, 0)  # loss gone: one copy at a time again
    assert est.width == 1


# -- hedged trades on the in-memory network -----------------------------------------------------


class HedgedMemory(MemoryTransport):
    """A :class:`MemoryTransport` that can hedge: copies go one after another through
    ``request``; with ``every_copy`` each copy reaches the responder, also after one was
    answered (the worst case of a real network, where copies cross); in tries of several
    copies, the replies of the copies in ``lose_replies`` are lost after the responder
    handled them. The round trip of copy k is (k + 1) ms."""

    every_copy = True
    lose_replies: frozenset[int] = frozenset()

    def request_hedged(self, key: str, make_payload: Callable[[int], bytes],
                       offsets_s: Sequence[float], timeout: float,
                       kind: str | None = None) -> HedgedReply:
        first: tuple[int, bytes] | None = None
        sent = nbytes = 0
        for k, off in enumerate(offsets_s):
            if off >= timeout or (first is not None and not self.every_copy):
                break
            payload = make_payload(k)
            sent += 1
            nbytes += len(payload)
            out = self.request(key, payload, timeout - off, kind)
            lost = len(offsets_s) > 1 and k in self.lose_replies
            if out is not None and first is None and not lost:
                first = (k, out)
        if first is None:
            return HedgedReply(None, sent=sent, bytes_out=nbytes)
        return HedgedReply(first[1], first[0], 0.001 * (first[0] + 1), sent, nbytes)


class HedgedNetwork(MemoryNetwork):
    """A :class:`MemoryNetwork` of :class:`HedgedMemory` nodes."""

    def transport(self, node_id: str, faults: FaultInjector | None = None) -> MemoryTransport:
        node = super().transport(node_id, faults)
        node.__class__ = HedgedMemory
        return node


@pytest.fixture
def hedged(monkeypatch: pytest.MonkeyPatch) -> None:
    """Missions of :class:`MemoryMission` run on a :class:`HedgedNetwork`."""
    monkeypatch.setattr(memsim, "MemoryNetwork", HedgedNetwork)


def _mission(tmp: Path, seed: int, faults: FaultConfig | None) -> MemoryMission:
    sc = random_scene(5, 25, seed)
    m = MemoryMission(sc, tmp, faults, seed=seed, motion=fixed_motion(seed),
                      config=AgentConfig(mission="mem", seed=seed))
    assert all(isinstance(t, HedgingTransport) for t in m.transports.values())
    assert all(rt.core.client.hedging for rt in m.agents.values())
    return m


def _records(m: MemoryMission, aid: str) -> list[object]:
    """Every record agent ``aid`` journaled (call after ``m.close()``)."""
    j = Journal(m.root / aid)
    try:
        return list(j.replay())
    finally:
        j.close()


def test_every_copy_reaches_the_responder_yet_each_trade_happens_once(
        hedged: None, tmp_path: Path) -> None:
    m = _mission(tmp_path, 2, None)
    try:
        assert m.run(300.0)
        assert m.violations == [] and m.final_violations() == []
        agents = m.agents.values()
        stats = [rt.core.client.stats for rt in agents]
        # every try went out as several copies, each handled by the responder ...
        assert sum(st.copies for st in stats) > 2 * sum(st.calls for st in stats) > 0
        # ... and counted once
        assert [rt.core.shared.counters.requests for rt in agents] == [st.calls for st in stats]
        assert all(sum(st.answered_by.values()) + st.unanswered == st.calls for st in stats)
    finally:
        m.close()
    # each trade prepared and committed once at its responder, counted once by both
    trades = 0
    for aid in m.agents:
        recs = _records(m, aid)
        prepared = [r.trade_id for r in recs if isinstance(r, PreparedRec)]
        committed = [r.trade_id for r in recs if isinstance(r, CommittedRec)]
        assert len(prepared) == len(set(prepared)) and len(committed) == len(set(committed))
        trades += len(committed)
    assert trades > 0
    assert sum(rt.core.machine.ok for rt in agents) == 2 * trades
    for a, ra in m.agents.items():
        for b, rb in m.agents.items():
            assert ra.core.machine.trades_with.get(b, 0) == rb.core.machine.trades_with.get(a, 0)


def _outcome(m: MemoryMission) -> tuple[object, ...]:
    return (round(m.net.now, 6), sorted(m.owner_of().items()),
            [(c.requests, c.timeouts, c.bytes_out, rt.core.client.stats.copies,
              sorted(rt.core.client.stats.answered_by.items()), rt.core.client.stats.unanswered)
             for rt in m.agents.values() for c in [rt.core.shared.counters]])


def test_hedged_lossy_missions_are_deterministic_for_a_seed(hedged: None,
                                                            tmp_path: Path) -> None:
    HedgedMemory.every_copy = False
    try:
        runs = []
        for i in range(2):
            m = _mission(tmp_path / f"r{i}", 4, FaultConfig(drop_default=0.3))
            try:
                assert m.run(600.0)
                assert m.violations == [] and m.final_violations() == []
                runs.append(_outcome(m))
                assert sum(rt.core.client.stats.unanswered for rt in m.agents.values()) > 0
            finally:
                m.close()
        assert runs[0] == runs[1]
    finally:
        HedgedMemory.every_copy = True


def test_signed_copies_are_sealed_one_by_one_and_opened_by_their_nonce(
        tmp_path: Path) -> None:
    """Secured profile: a repeated envelope would be refused as a replay, so each copy is
    sealed on its own; the reply to copy 0 is lost, copy 1's reply (bound to copy 1's nonce)
    completes the trade."""
    sc = random_scene(2, 12, 1)
    priv = {a.id: Ed25519PrivateKey.generate() for a in sc.agents}
    team = {aid: k.public_key() for aid, k in priv.items()}
    net = HedgedNetwork()
    clock = ManualClock(source=lambda: net.now)
    rts: list[AgentRuntime] = []
    journals: list[Journal] = []
    try:
        for a in sc.agents:
            tp = net.transport(a.id)
            assert isinstance(tp, HedgedMemory)
            tp.lose_replies = frozenset({0})
            journals.append(Journal(tmp_path / a.id))
            rts.append(AgentRuntime(a.id, sc, tp, journals[-1], clock,
                                    config=AgentConfig(mission="m", signing=SigningKeys(
                                        a.id, priv[a.id], team)),
                                    motion=fixed_motion(1, max_ticks=0)(a.id)))
        for rt in rts:
            rt.start()
        while net.now < 120.0 and not all(rt.complete for rt in rts):
            for rt in rts:
                rt.tick()
            net.advance(sc.params.dt)
        assert all(rt.complete for rt in rts)
        assert sum(rt.core.machine.ok for rt in rts) > 0
        assert all(rt.core.rejects.total == 0 for rt in rts)  # no copy refused as a replay
        stats = [rt.core.client.stats for rt in rts]
        assert sum(st.answered_by[1] for st in stats) > 0
    finally:
        for rt in rts:
            rt.stop()
        for j in journals:
            j.close()


# -- the Zenoh transport ------------------------------------------------------------------------


@pytest.fixture(scope="module")
def endpoint() -> Iterator[str]:
    proc, ep = start_router_process()
    yield ep
    stop_router_process(proc)


class DropFirst(FaultInjector):
    """Drops the first ``n`` messages it is asked about, delivers the rest."""

    def __init__(self, n: int) -> None:
        super().__init__(FaultConfig())
        self.n = n

    def decide(self, kind: str, peer: str | None, direction: Direction) -> Decision:
        with self._lock:
            self._seq += 1
            return Decision(delays_s=(), reason="drop") if self._seq <= self.n else DELIVER_NOW


def test_zenoh_hedged_request(endpoint: str) -> None:
    srv = ZenohTransport(client_config(endpoint), None, "b")
    seen: list[bytes] = []

    def echo(payload: bytes, _selector: str) -> bytes:
        seen.append(payload)
        return b"re:" + payload

    srv.declare_queryable("m/trade/b", echo)
    cli = ZenohTransport(client_config(endpoint), None, "a")
    try:
        assert isinstance(cli, HedgingTransport)
        deadline = time.monotonic() + 5.0
        while time.monotonic() < deadline and cli.request("m/trade/b", b"ping", 0.5) is None:
            pass
        seen.clear()
        cli.faults = DropFirst(2)  # copies 0 and 1 are lost on the way, copy 2 arrives
        got = cli.request_hedged("m/trade/b", lambda k: b"copy%d" % k,
                                 [0.0, 0.02, 0.04, 0.06], 2.0, kind="trade")
        assert got.payload == b"re:copy2" and got.copy == 2
        assert got.sent == 3 and got.bytes_out == 5 * 3  # copy 3 was never needed
        assert got.rtt_s is not None and 0.0 <= got.rtt_s < 2.0
        assert seen == [b"copy2"]
        cli.faults = DropFirst(10)  # every copy lost: the whole timeout, then nothing
        t0 = time.monotonic()
        lost = cli.request_hedged("m/trade/b", lambda k: b"x", [0.0, 0.05], 0.2)
        assert lost == HedgedReply(None, sent=2, bytes_out=2)
        assert time.monotonic() - t0 >= 0.19
        # no queryable: every copy sent ends unanswered, so it returns at once
        t0 = time.monotonic()
        none = ZenohTransport(client_config(endpoint), None, "c")
        try:
            out = none.request_hedged("m/trade/nobody", lambda k: b"x", [0.0, 1.0], 3.0)
            assert out.payload is None and out.copy == -1 and out.sent == 1
            assert time.monotonic() - t0 < 1.0
        finally:
            none.close()
    finally:
        cli.close()
        srv.close()
    assert cli.request_hedged("m/trade/b", lambda k: b"x", [0.0], 1.0).payload is None
