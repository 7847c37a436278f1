"""Saying on the mesh that this agent leaves the mission, and why
(:class:`~agent.wire.departure.AgentDeparture`), before its liveliness token goes: a
:class:`~agent.runtime.core.events.Depart` event stepped into the agent's core, which publishes it
(repeated: a lossy link still delivers one)."""

from __future__ import annotations

from agent.runtime.core.events import Depart
from agent.runtime.shell.runtime import AgentRuntime
from agent.wire.departure import DepartureReason


def announce_departure(rt: AgentRuntime, reason: DepartureReason, detail: str = "") -> None:
    """Step ``rt``'s departure in at once (no hand-over); never raises (a closed transport
    is logged, a failed journal does not hold it back)."""
    rt.step(Depart(rt.clock.now(), reason, detail))
