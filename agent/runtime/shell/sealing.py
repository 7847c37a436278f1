"""The runtime's end of the secured profile (:mod:`agent.wire.signed`): it seals the core's
trade asks, opens the replies before they are stepped back in, opens the queries addressed to
the agent and seals the core's replies to them. The seal draws its incarnation token from
:mod:`secrets`, stamps with the wall clock and keeps a replay memory under a lock: all of it
outside the agent core, which sees only opened messages and refusals
(:class:`~agent.runtime.core.events.Query`, :class:`~agent.runtime.core.events.Answer`).
"""

from __future__ import annotations

from agent.net.contract import HedgedReply, HedgingTransport, Transport
from agent.runtime.core.events import Answer, Ask, AskHedged, Query
from agent.runtime.core.shared import AgentConfig
from agent.wire import keys
from agent.wire.signed import Refusal, TradeSeal


def trade_seal(cfg: AgentConfig, agent_id: str) -> TradeSeal | None:
    """The seal of ``cfg.signing`` for agent ``agent_id`` (None: unsigned, open profile)."""
    if cfg.signing is None:
        return None
    if cfg.signing.me != agent_id:
        raise ValueError(f"agent {agent_id!r} given the signing key of {cfg.signing.me!r}")
    return TradeSeal(cfg.signing, cfg.mission)


def open_query(seal: TradeSeal | None, payload: bytes, selector: str, now: float
               ) -> tuple[Query, tuple[str, bytes] | None]:
    """The :class:`Query` to step for a query received (opened, or refused), and the (signer,
    nonce) its reply is to be sealed to (None: unsigned, or refused)."""
    if seal is None:
        return Query(payload, selector, now), None
    opened = seal.open_request(payload)
    if isinstance(opened, Refusal):
        return Query(b"", selector, now, refusal=opened), None
    return Query(opened.body, selector, now, signer=opened.sender,
                 evicted=opened.evicted), (opened.sender, opened.nonce)


def seal_reply(seal: TradeSeal | None, reply: bytes | None,
               to: tuple[str, bytes] | None) -> bytes | None:
    """The core's ``reply`` as sent: sealed to the signer of the request (``to``)."""
    if reply is None or seal is None or to is None:
        return reply
    return seal.seal_reply(reply, to[0], to[1])


def ask_sealed(seal: TradeSeal | None, tp: Transport, ask: Ask | AskHedged,
               now: float) -> Answer:
    """Send the core's ``ask`` (each copy sealed on its own: a repeated envelope would be
    refused as a replay) and open the reply; the :class:`Answer` to step back in at mission
    time ``now`` [s]."""
    trade = seal is not None and keys.kind_of(ask.key) == "trade"  # a peer's queryable
    partner = keys.try_agent_of(ask.key) if trade else None
    if isinstance(ask, Ask):
        if seal is None or partner is None:
            return Answer(tp.request(ask.key, ask.payload, ask.timeout, kind=ask.kind), now)
        data, nonce = seal.seal_request(ask.payload, partner)
        raw = tp.request(ask.key, data, ask.timeout, kind=ask.kind)
        return _opened(seal, raw, partner, nonce, now)
    assert isinstance(tp, HedgingTransport)
    copies = ask.copies
    if seal is None or partner is None:
        got = tp.request_hedged(ask.key, lambda k: copies[k], ask.offsets, ask.timeout,
                                kind=ask.kind)
        return Answer(got, now)
    nonces: dict[int, bytes] = {}

    def sealed(k: int) -> bytes:
        data, nonces[k] = seal.seal_request(copies[k], partner)
        return data

    got = tp.request_hedged(ask.key, sealed, ask.offsets, ask.timeout, kind=ask.kind)
    answer = _opened(seal, got.payload, partner, nonces.get(got.copy, b""), now)
    body = answer.reply if isinstance(answer.reply, bytes) else None
    return Answer(replace_payload(got, body), now, answer.refusal)


def replace_payload(got: HedgedReply, payload: bytes | None) -> HedgedReply:
    """``got`` with its reply payload replaced (the opened body)."""
    return got._replace(payload=payload)


def _opened(seal: TradeSeal, raw: bytes | None, partner: str, nonce: bytes,
            now: float) -> Answer:
    """The :class:`Answer` of reply ``raw`` to our request ``nonce``: its inner reply, or why
    its envelope is refused."""
    if raw is None:
        return Answer(None, now)
    body = seal.open_reply(raw, partner, nonce)
    if isinstance(body, Refusal):
        return Answer(None, now, body)
    return Answer(body, now)


__all__ = ["ask_sealed", "open_query", "seal_reply", "trade_seal"]
