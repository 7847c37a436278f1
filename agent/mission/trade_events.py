"""The events of one agent between two of its successive states (:func:`state_events`:
``first_state``, ``restart``, ``phase``, ``trade``, ``trade_gap``, ``no_trade``, ``fault``,
``complete``; Structs of :mod:`agent.storage.events`), for the mission watch
(:mod:`agent.mission.watch`) and so the recorder's ``events.jsonl``.

An agent's state carries the terms of its newest committed trades
(:class:`~agent.wire.peer.TradeTerms`: the initiator's commit record, the responder's prepared
record at its commit; the journal's own records), so each trade is reported once per side,
with its trade id and role, and the two sides' events of one trade agree: the initiator's
``gained`` is the responder's ``given`` and vice versa.

The landmarks a trade moved cannot be read off the difference of two states' owned sets: the
responder's outgoing landmarks leave its owned set when it *prepares* (they are held), while
the trade counts when it *commits*; a state published in between (the Commit lost, retried,
or just late) makes the difference at the commit say "gave []". Several trades between two
states, or a lost state, mix their landmarks too. That difference is used only for states of
builds that do not report their trades' terms (``trades`` empty while a trade counted).

A gap (more trades between two states heard than a state reports: many states lost) is one
``trade_gap`` event with the number of trades not reported.
"""

from __future__ import annotations

from typing import Final

from agent.storage.events import (
    Complete,
    Event,
    Fault,
    FaultWhat,
    FirstState,
    NoTrade,
    PhaseChange,
    Restart,
    Trade,
    TradeGap,
)
from agent.wire.peer import AgentState, TradeTerms, unpack

#: the counters of an agent's state whose rise is a ``fault`` event
FAULT_COUNTERS: Final[tuple[FaultWhat, ...]] = ("timeouts", "rejected")


def landmark_ids(terms: TradeTerms) -> tuple[list[int], list[int]] | None:
    """(gained, given) landmark ids of one trade's terms, ascending; None if malformed."""
    gained, given = unpack(terms.gained), unpack(terms.given)
    if gained is None or given is None:
        return None
    return sorted(gained[0].tolist()), sorted(given[0].tolist())


def trade_events(prev: AgentState, prev_owned: set[int], cur: AgentState,
                 cur_owned: set[int]) -> list[Event]:
    """The ``trade`` (and ``trade_gap``) events of agent ``cur.sender`` from its state
    ``prev`` (owned ids ``prev_owned``) to its next state heard ``cur`` (``cur_owned``)."""
    a = cur.sender
    if not cur.trades:  # a build that does not report terms: the ledger's difference
        return legacy_trade_events(prev, prev_owned, cur, cur_owned)
    out: list[Event] = []
    reported = 0
    for t in cur.trades:
        ids = landmark_ids(t) if t.n > prev.counters.ok else None
        if ids is None:
            continue
        reported += 1
        gained, given = ids
        out.append(Trade(source=a, level="info", text=f"{a}: trade {t.count} with "
                         f"{t.partner} ({t.trade_id}, {t.role}; gained {gained}, gave "
                         f"{given})", partner=t.partner, count=t.count, gained=gained,
                         given=given, trade=t.trade_id, role=t.role, n=t.n))
    missed = cur.counters.ok - prev.counters.ok - reported
    if missed > 0:
        out.append(TradeGap(source=a, level="info", text=f"{a}: {missed} trade(s) not "
                            "reported (states lost)", count=missed))
    return out


def legacy_trade_events(prev: AgentState, prev_owned: set[int], cur: AgentState,
                        cur_owned: set[int]) -> list[Event]:
    """Trade events of a state without terms: one per partner whose count rose, with the
    difference of the owned sets (see the module docstring for why it may be wrong)."""
    a = cur.sender
    gained, given = sorted(cur_owned - prev_owned), sorted(prev_owned - cur_owned)
    return [Trade(source=a, level="info", text=f"{a}: trade {n} with {b} (gained {gained}, "
                  f"gave {given})", partner=b, count=n, gained=gained, given=given)
            for b, n in sorted(cur.trades_with.items()) if n > prev.trades_with.get(b, 0)]


def state_events(prev: AgentState | None, prev_owned: set[int], cur: AgentState,
                 cur_owned: set[int]) -> list[Event]:
    """Events between two successive states of one agent (``prev`` None: its first)."""
    a = cur.sender
    if prev is None:
        return [FirstState(source=a, level="info", text=f"{a}: first state, incarnation "
                           f"{cur.incarnation}, {cur.phase}, {len(cur_owned)} landmarks",
                           incarnation=cur.incarnation)]
    out: list[Event] = []
    if cur.incarnation != prev.incarnation:
        out.append(Restart(source=a, level="warning", text=f"{a}: restarted (incarnation "
                           f"{prev.incarnation} -> {cur.incarnation})",
                           incarnation=cur.incarnation))
    if cur.phase != prev.phase:
        out.append(PhaseChange(source=a, level="info", text=f"{a}: {prev.phase} -> "
                               f"{cur.phase}", phase=cur.phase, previous=prev.phase))
    out += trade_events(prev, prev_owned, cur, cur_owned)  # the journaled terms
    c, pc = cur.counters, prev.counters
    if c.failed > pc.failed:
        out.append(NoTrade(source=a, level="info", text=f"{a}: {c.failed - pc.failed} "
                           "offer(s) moved nothing", count=c.failed))
    for what in FAULT_COUNTERS:
        now, before = int(getattr(c, what)), int(getattr(pc, what))
        if now > before:
            out.append(Fault(source=a, level="warning", text=f"{a}: {now - before} more "
                             f"{what} ({now} in all)", what=what, count=now))
    if cur.complete and not prev.complete:
        out.append(Complete(source=a, level="info", text=f"{a}: sees the mission complete"))
    return out
