"""Saying on the mesh that this agent leaves the mission, and why
(:class:`~agent.wire.departure.AgentDeparture`), before its liveliness token goes."""

from __future__ import annotations

import logging

from agent.runtime.agent import AgentRuntime
from agent.wire import keys
from agent.wire.departure import DEPARTURE_CODEC, MAX_DETAIL, AgentDeparture, DepartureReason

_log = logging.getLogger(f"viscover.{__name__}")


def announce_departure(rt: AgentRuntime, reason: DepartureReason, detail: str = "",
                       repeats: int = 3) -> AgentDeparture:
    """Publish ``rt``'s departure ``repeats`` times (a lossy link still delivers one); never
    raises (a closed transport is logged). Returns the message sent."""
    with rt.turn:
        owned = int(rt.machine.owned_arrays()[0].size)
        incarnation = rt.machine.incarnation
    msg = AgentDeparture(sender=rt.id, incarnation=incarnation, t=float(rt.clock.now()),
                         reason=reason, detail=detail[:MAX_DETAIL], owned=owned)
    payload = DEPARTURE_CODEC.encode(msg)
    key = keys.departure_key(rt.cfg.mission, rt.id)
    for _ in range(max(1, repeats)):
        try:
            rt.tp.publish(key, payload, kind="status")
        except RuntimeError:  # transport already closed
            _log.debug("departure not sent: transport closed")
            break
    return msg
