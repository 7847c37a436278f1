"""The pure trade state machine (agent.protocol.machine): one exchange step by step."""

from __future__ import annotations

from typing import TypeVar

import numpy as np
import pytest

from agent.protocol.machine import (
    CommitRec,
    DecideFn,
    IntArray,
    Mask,
    PreparedRec,
    Rec,
    Step,
    TradeMachine,
    Vec3,
)
from agent.wire.codec import Codec
from agent.wire.peer import (
    Accept,
    AgentState,
    Busy,
    Commit,
    CommitAck,
    Counters,
    Decision,
    NoTrade,
    Offer,
    Publication,
    Refused,
    Reply,
    Request,
    StatusQuery,
    pack,
    parse_trade_id,
    to_dict,
)

P = (0.0, 0.0, 0.0)
V = (1.0, 0.0, 0.0)
IDS = list(range(1, 11))


T = TypeVar("T")


def give(i_moves: list[int], r_moves: list[int]) -> DecideFn:
    """A decide function moving the given landmark ids (whatever the poses)."""

    def decide(_pi: Vec3, _vi: Vec3, ids_i: IntArray, _pr: Vec3, _vr: Vec3,
               ids_r: IntArray) -> tuple[Mask, Mask]:
        return np.isin(ids_i, i_moves), np.isin(ids_r, r_moves)

    return decide


def msg(step: Step, kind: type[T]) -> T:
    """The message of ``step``, which the test expects to be a ``kind``."""
    assert isinstance(step.message, kind), step.message
    return step.message


def reply(step: Step) -> Reply:
    """The message of ``step``, which the test expects to be a reply."""
    assert isinstance(step.message, Reply), step.message
    return step.message


def pair() -> tuple[TradeMachine, TradeMachine]:
    a, b = TradeMachine("A", IDS), TradeMachine("B", IDS)
    from agent.protocol.machine import GenesisRec, StartRec

    a.apply(GenesisRec(agent="A", owned=pack({1: 0, 2: 0, 3: 0})))
    b.apply(GenesisRec(agent="B", owned=pack({4: 0, 5: 0})))
    a.apply(StartRec(incarnation=1))
    b.apply(StartRec(incarnation=1))
    return a, b


def claims(*ms: TradeMachine) -> dict[int, list[tuple[str, int, str]]]:
    out: dict[int, list[tuple[str, int, str]]] = {}
    for m in ms:
        for k, v in m.owned.items():
            out.setdefault(k, []).append((m.me, v, "owned"))
        for k, (v, _t) in m.held.items():
            out.setdefault(k, []).append((m.me, v, "held"))
    return out


def test_happy_path_versions_and_records() -> None:
    a, b = pair()
    s = a.new_offer("B", P, V)
    offer = s.message
    assert isinstance(offer, Offer) and parse_trade_id(offer.trade_id) == ("A", 1, 1)
    r = b.on_offer(offer, P, V, None, give([1], [4]))
    assert r.outcome == "prepared" and isinstance(r.records[0], PreparedRec)
    acc = r.message
    assert isinstance(acc, Accept) and to_dict(acc.i_to_r) == {1: 0}
    assert to_dict(acc.r_to_i) == {4: 0}
    assert b.held == {4: (0, offer.trade_id)} and 4 not in b.owned
    c = a.on_offer_reply(offer.trade_id, acc)
    assert c.outcome == "commit" and isinstance(c.records[0], CommitRec)
    assert a.owned[4] == 1 and a.held[1] == (0, offer.trade_id)
    # In between: landmark 4 owned by A at v1, held by B at v0; landmark 1 held by A only.
    cl = claims(a, b)
    assert cl[4] == [("A", 1, "owned"), ("B", 0, "held")] and cl[1] == [("A", 0, "held")]
    ack = b.on_commit(msg(c, Commit))
    assert isinstance(ack.message, CommitAck) and b.owned[1] == 1 and not b.held
    assert a.on_commit_reply(offer.trade_id, ack.message).outcome == "done"
    assert not a.held and not a.pending_ids and not b.pending_ids
    assert a.trades_with == {"B": 1} and b.trades_with == {"A": 1}
    # Idempotent commit.
    again = b.on_commit(Commit(sender="A", trade_id=offer.trade_id))
    assert isinstance(again.message, CommitAck) and not again.records


def test_repeated_offer_gets_same_answer_and_stale_refused() -> None:
    a, b = pair()
    o1 = msg(a.new_offer("B", P, V), Offer)
    r1 = b.on_offer(o1, P, V, None, give([2], []))
    r2 = b.on_offer(o1, P, V, None, give([], []))
    assert r2.message == r1.message and not r2.records
    a.abort_offer(o1.trade_id, "timeout")
    # Late Accept for an aborted offer is ignored.
    assert a.on_offer_reply(o1.trade_id, reply(r1)).outcome == "ignored"
    o2 = msg(a.new_offer("B", P, V), Offer)
    assert b.on_offer(o2, P, V, None, give([], [])).outcome == "busy"  # in doubt
    # B asks A: aborted -> restore.
    d = a.on_status_query(StatusQuery(sender="B", trade_id=o1.trade_id))
    assert d.message == Decision(sender="A", trade_id=o1.trade_id, status="aborted")
    assert b.on_decision(o1.trade_id, msg(d, Decision)).outcome == "restored"
    assert b.owned == {4: 0, 5: 0} and not b.held
    # The older offer o1 arriving again now is stale (o2 is newer).
    o3 = msg(a.new_offer("B", P, V), Offer)
    assert b.on_offer(o3, P, V, None, give([], [])).outcome == "no_trade"
    assert b.on_offer(o1, P, V, None, give([1], [])).outcome == "stale"


def test_status_query_answers() -> None:
    a, b = pair()
    o = msg(a.new_offer("B", P, V), Offer)
    tid = o.trade_id
    assert msg(a.on_status_query(StatusQuery(sender="B", trade_id=tid)),
               Decision).status == "pending"
    acc = reply(b.on_offer(o, P, V, None, give([1], [])))
    a.on_offer_reply(tid, acc)
    assert msg(a.on_status_query(StatusQuery(sender="B", trade_id=tid)),
               Decision).status == "committed"
    assert msg(a.on_status_query(StatusQuery(sender="B", trade_id="A:9:9")),
               Decision).status == "aborted"
    assert isinstance(a.on_status_query(StatusQuery(sender="B", trade_id="B:1:1")).message, Refused)
    assert isinstance(a.on_status_query(StatusQuery(sender="C", trade_id=tid)).message, Refused)
    dec = Decision(sender="A", trade_id=tid, status="committed")
    assert b.on_decision(tid, dec).outcome == "committed"
    assert b.owned[1] == 1


@pytest.mark.parametrize("answer,outcome", [
    (Busy(sender="B", trade_id="", reason="optimising"), "drop"),
    (Busy(sender="B", trade_id="", reason="trading"), "retry_later"),
    (NoTrade(sender="B", trade_id=""), "drop_both"),
    (Refused(sender="B", trade_id="", reason="x"), "drop"),
])
def test_negative_answers(answer: Busy | NoTrade | Refused, outcome: str) -> None:
    a, _b = pair()
    tid = a.new_offer("B", P, V).trade_id
    assert tid is not None
    answer.trade_id = tid
    s = a.on_offer_reply(tid, answer)
    assert s.outcome == outcome and not a.pending_ids and a.owned == {1: 0, 2: 0, 3: 0}


def test_bad_accepts_are_refused() -> None:
    a, _b = pair()
    tid = a.new_offer("B", P, V).trade_id
    assert tid is not None
    bad = [
        # wrong sender: ignored
        Accept(sender="C", trade_id=tid, i_to_r=pack({1: 0}), r_to_i=pack({})),
        Accept(sender="B", trade_id=tid, i_to_r=pack({1: 5}), r_to_i=pack({})),  # wrong version
    ]
    assert a.on_offer_reply(tid, bad[0]).outcome == "ignored"
    assert a.on_offer_reply(tid, bad[1]).outcome == "drop"
    tid = a.new_offer("B", P, V).trade_id
    assert tid is not None
    assert a.on_offer_reply(tid, Accept(sender="B", trade_id=tid, i_to_r=pack({}),
                                        r_to_i=pack({99: 0}))).outcome == "drop"  # unknown id
    tid = a.new_offer("B", P, V).trade_id
    assert tid is not None
    assert a.on_offer_reply(tid, Accept(sender="B", trade_id=tid, i_to_r=pack({}),
                                        r_to_i=pack({2: 0}))).outcome == "drop"  # already mine
    assert a.owned == {1: 0, 2: 0, 3: 0}


def test_offer_validation() -> None:
    _a, b = pair()
    d = give([1], [])
    assert b.on_offer(Offer(sender="A", trade_id="X:1:1", p=P, v=V, owned=pack({})), P, V,
                      None, d).outcome == "invalid"
    assert b.on_offer(Offer(sender="A", trade_id="A:1:1", p=P, v=V, owned=pack({77: 0})), P, V,
                      None, d).outcome == "invalid"
    assert b.on_offer(Offer(sender="A", trade_id="A:1:2", p=P, v=V, owned=pack({4: 0})), P, V,
                      None, d).outcome == "conflict"
    assert b.on_offer(Offer(sender="A", trade_id="A:1:3", p=P, v=V, owned=pack({1: -1})), P, V,
                      None, d).outcome == "invalid"
    assert msg(b.on_offer(Offer(sender="A", trade_id="A:1:4", p=P, v=V, owned=pack({1: 0})),
                          P, V, "optimising", d), Busy).reason == "optimising"


def test_replay_rebuilds_state() -> None:
    a, b = pair()
    recs_a: list[Rec] = []
    recs_b: list[Rec] = []
    for _ in range(3):
        s = a.new_offer("B", P, V)
        recs_a += s.records
        offer = msg(s, Offer)
        r = b.on_offer(offer, P, V, None, give(list(a.owned)[:1], list(b.owned)[:1]))
        recs_b += r.records
        c = a.on_offer_reply(offer.trade_id, reply(r))
        recs_a += c.records
        k = b.on_commit(msg(c, Commit))
        recs_b += k.records
    for m, recs in ((a, recs_a), (b, recs_b)):
        from agent.protocol.machine import GenesisRec, StartRec

        fresh = TradeMachine(m.me, IDS)
        fresh.apply(GenesisRec(agent=m.me, owned=pack({1: 0, 2: 0, 3: 0} if m.me == "A"
                                                    else {4: 0, 5: 0})))
        fresh.apply(StartRec(incarnation=1))
        for rec in recs:
            fresh.apply(rec)
        assert fresh.owned == m.owned and fresh.held == m.held
        assert fresh.trades_with == m.trades_with and fresh.pending_ids == m.pending_ids
    # A has 3 unacked commits (acks never delivered): recovery keeps them, bumps incarnation.
    assert len(a.unacked_commits()) == 3
    recs = a.recover()
    assert a.incarnation == 2 and len(recs) == 1 and len(a.unacked_commits()) == 3


def test_wire_round_trip_and_schema() -> None:
    req: Codec[Request] = Codec(Request)
    rep: Codec[Reply] = Codec(Reply)
    pub: Codec[Publication] = Codec(Publication)
    o = Offer(sender="A", trade_id="A:1:1", p=P, v=V, owned=pack({1: 0}))
    assert req.decode(req.encode(o)) == o
    bad = Offer(sender="A", trade_id="A:1:1", p=P, v=V, owned=pack({1: 0}), schema=2)
    assert req.decode(req.encode(bad)) is None and req.counter.by_reason["schema"] == 1
    nan = Offer(sender="A", trade_id="A:1:1", p=(float("nan"), 0.0, 0.0), v=V, owned=pack({}))
    assert req.decode(req.encode(nan)) is None and req.counter.by_reason["nonfinite"] == 1
    a = Accept(sender="B", trade_id="A:1:1", i_to_r=pack({1: 0}), r_to_i=pack({}))
    assert rep.decode(rep.encode(a)) == a
    st = AgentState(sender="A", incarnation=1, seq=1, t=0.0, p=P, v=V, phase="converged",
                    owned=pack({1: 0}), held=pack({}), vision=1.0, counters=Counters(),
                    partners=[],
                    pending=[], trades_with={})
    assert pub.decode(pub.encode(st)) == st
    assert req.decode(pub.encode(st)) is None  # a state is not a request
