"""Signed trade messages and bounded network fields, without a network: a forged, replayed,
misaddressed or tampered envelope is refused with its reason; out-of-bounds fields (huge
sender strings, incarnations, trade ids) never decode; logs are truncated."""

from __future__ import annotations

import json
import logging

import msgspec
import pytest
from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey

from agent.protocol.machine import Mask, TradeMachine
from agent.wire.codec import Codec, RateLimitedLogger
from agent.wire.peer import (
    AgentState,
    Counters,
    Offer,
    Publication,
    Refused,
    Request,
    pack,
    parse_trade_id,
)
from agent.wire.signed import (
    REASON_FORGED,
    REASON_REPLAY,
    REASON_STALE,
    REASON_UNSIGNED,
    Opened,
    Refusal,
    SigningKeys,
    TradeSeal,
    parse_team,
    public_key_text,
)

KEYS = {d: Ed25519PrivateKey.generate() for d in "ABC"}
TEAM = {d: k.public_key() for d, k in KEYS.items()}
P, V = (0.0, 0.0, 0.0), (1.0, 0.0, 0.0)


class FakeClock:
    """A settable wall clock [ns]."""

    def __init__(self) -> None:
        self.ns = 1_700_000_000 * 10**9

    def __call__(self) -> int:
        """The time [ns]."""
        return self.ns


def seal(me: str, clock: FakeClock, mission: str = "m") -> TradeSeal:
    """Drone ``me``'s seal on ``mission`` with the fake clock."""
    return TradeSeal(SigningKeys(me, KEYS[me], TEAM), mission, clock)


def reason(r: object) -> str:
    """The reason of refusal ``r`` (which the test expects to be a :class:`Refusal`)."""
    assert isinstance(r, Refusal), r
    return r.reason


def never_decide(*_: object) -> tuple[Mask, Mask]:
    """A decide function for an offer the machine refuses before deciding anything."""
    raise AssertionError("decide called for a refused offer")


def knows(a: TradeSeal, *others: TradeSeal) -> TradeSeal:
    """``a``, knowing the incarnation tokens of ``others`` (as after a first contact)."""
    for o in others:
        a.know(o.keys.me, o.boot)
    return a


def test_request_and_reply_round_trip() -> None:
    clock = FakeClock()
    b = seal("B", clock)
    a = knows(seal("A", clock), b)
    data, nonce = a.seal_request(b"offer", "B")
    opened = b.open_request(data)
    assert opened == Opened("A", b"offer", nonce)
    reply = b.seal_reply(b"accept", "A", nonce)
    assert a.open_reply(reply, "B", nonce) == b"accept"


def test_forgeries_are_refused_with_reasons() -> None:
    clock = FakeClock()
    b, c = seal("B", clock), seal("C", clock)
    a = knows(seal("A", clock), b)
    data, nonce = a.seal_request(b"offer", "B")
    env = msgspec.msgpack.decode(data)
    tampered = list(env)
    tampered[9] = b"other offer"  # body changed after signing
    cases = {
        "tampered": msgspec.msgpack.encode(tampered),
        "renamed": msgspec.msgpack.encode([*env[:3], "C", *env[4:]]),  # claims C signed it
        "not an envelope": b"\x93\x01\x02\x03",
        "junk": b"\xc1",
    }
    got = {k: b.open_request(v) for k, v in cases.items()}
    assert reason(got["tampered"]) == REASON_FORGED
    assert reason(got["renamed"]) == REASON_FORGED
    assert reason(got["not an envelope"]) == REASON_UNSIGNED
    assert reason(got["junk"]) == REASON_UNSIGNED
    # Addressed to B: C cannot use it; another mission cannot either.
    assert isinstance(c.open_request(data), Refusal)
    assert reason(seal("B", clock, "other").open_request(data)) == REASON_FORGED
    # A signer outside the team.
    outsider = TradeSeal(SigningKeys("Z", Ed25519PrivateKey.generate(), TEAM), "m", clock)
    assert reason(b.open_request(outsider.seal_request(b"x", "B")[0])) == REASON_FORGED
    # A reply from someone else, or bound to another request.
    assert reason(a.open_reply(c.seal_reply(b"r", "A", nonce), "B", nonce)) == REASON_FORGED
    assert reason(a.open_reply(b.seal_reply(b"r", "A", b"\x00" * 64), "B", nonce)) == REASON_REPLAY
    assert reason(a.open_reply(data, "B", nonce)) == REASON_UNSIGNED


def test_replayed_and_older_requests_are_refused() -> None:
    clock = FakeClock()
    b = seal("B", clock)
    a = knows(seal("A", clock), b)
    first, _ = a.seal_request(b"1", "B")
    second, _ = a.seal_request(b"2", "B")
    assert isinstance(b.open_request(second), Opened)
    assert reason(b.open_request(second)) == REASON_REPLAY
    assert reason(b.open_request(first)) == REASON_REPLAY  # older


def test_a_restarted_receiver_refuses_what_its_earlier_process_was_sent() -> None:
    """B restarts (a new seal, a new token): A's recording is stale, answered only with B's
    new token (bound to it: useless to anyone else); A learns it and is accepted again."""
    clock = FakeClock()
    b = seal("B", clock)
    a = knows(seal("A", clock), b)
    recorded, _ = a.seal_request(b"offer", "B")
    assert isinstance(b.open_request(recorded), Opened)
    b2 = seal("B", clock)  # B restarted: no memory of A, a new token
    stale = b2.open_request(recorded)
    assert isinstance(stale, Refusal) and stale.reason == REASON_STALE and stale.answer
    data, nonce = a.seal_request(b"offer", "B")  # A still names B's old token
    answer = b2.open_request(data)
    assert isinstance(answer, Refusal) and answer.reason == REASON_STALE
    c = knows(seal("C", clock), b)  # the answer is A's: C cannot use it
    assert reason(c.open_reply(answer.answer, "B", nonce)) == REASON_FORGED
    assert reason(a.open_reply(stale.answer, "B", nonce)) == REASON_REPLAY
    assert reason(a.open_reply(answer.answer, "B", nonce)) == REASON_STALE
    assert isinstance(b2.open_request(a.seal_request(b"offer", "B")[0]), Opened)
    assert reason(b2.open_request(recorded)) == REASON_STALE


def test_no_clock_is_compared() -> None:
    """A sender's clock an hour off either way, or stepped back by a restart, is no reason to
    refuse it: freshness is the receiver's token and memory."""
    early, late = FakeClock(), FakeClock()
    late.ns += 3600 * 10**9
    b = seal("B", late)
    for clock in (early, late):
        a = knows(seal("A", clock), b)  # a new process of A each time (a new token)
        assert isinstance(b.open_request(a.seal_request(b"x", "B")[0]), Opened)


def test_team_file_parsing() -> None:
    text = json.dumps({"signing_keys": {"A": public_key_text(KEYS["A"])}})
    assert list(parse_team(text)) == ["A"]
    for bad in ('{"signing_keys": {"A": "not base64!"}}', '{"signing_keys": {"a/b": "AAAA"}}',
                '{"x": 1}', '{"signing_keys": {"A": "AAAA"}}'):
        with pytest.raises(ValueError):
            parse_team(bad)


def test_network_fields_are_bounded() -> None:
    pub: Codec[Publication] = Codec(Publication)
    req: Codec[Request] = Codec(Request)
    enc = msgspec.msgpack.Encoder()
    state = AgentState(sender="A", incarnation=1, seq=1, t=0.0, p=P, v=V, phase="converged",
                       owned=pack({}), held=pack({}), vision=0.0, counters=Counters(),
                       partners=[], pending=[], trades_with={})
    assert pub.decode(enc.encode(state)) is not None
    for bad in (msgspec.structs.replace(state, incarnation=2**62),
                msgspec.structs.replace(state, sender="A" * 1_000_000),
                msgspec.structs.replace(state, seq=-1),
                msgspec.structs.replace(state, partners=["B/../C"]),
                msgspec.structs.replace(state, pending=["A:1"]),
                msgspec.structs.replace(state, trades_with={"B": -5})):
        n = pub.counter.total
        assert pub.decode(enc.encode(bad)) is None
        assert pub.counter.total == n + 1
    offer = Offer(sender="A", trade_id="A:1:1", p=P, v=V, owned=pack({}))
    assert req.decode(enc.encode(offer)) is not None
    for tid in ("A:1:1:1", "A" * 40 + ":1:1", "A:1234567890123:1", "A:x:1"):
        assert req.decode(enc.encode(msgspec.structs.replace(offer, trade_id=tid))) is None
    # A trade id within the pattern but beyond the incarnation bound is refused by the
    # machine (it would otherwise make every later real offer from A look stale).
    assert parse_trade_id("A:999999999:1") is None and parse_trade_id("A:2:3") == ("A", 2, 3)
    m = TradeMachine("B", [1, 2])
    step = m.on_offer(msgspec.structs.replace(offer, trade_id="A:999999999:1"), P, V, None,
                      never_decide)
    assert isinstance(step.message, Refused) and step.message.reason == "bad_trade_id"


def test_rejection_logs_are_truncated(caplog: pytest.LogCaptureFixture) -> None:
    logger = logging.getLogger("viscover.test.truncate")
    codec: Codec[Request] = Codec(Request, log=RateLimitedLogger(logger, interval_s=0.0))
    with caplog.at_level(logging.WARNING, logger="viscover.test.truncate"):
        codec.reject("forged", "k" * 100_000, "sender " + "x" * 1_000_000)
    (line,) = [r.getMessage() for r in caplog.records]
    assert len(line) < 400 and "chars)" in line
    assert codec.counter.total == 1
