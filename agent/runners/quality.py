"""What an agent can honestly say about the mission when it ends, read from its standing
(:mod:`agent.runtime.core.standing`, one snapshot made by its core): which of its landmarks it does
not see, which were orphaned by agents that departed, and how an inspection ended in its
view."""

from __future__ import annotations

from agent.protocol.inspection_end import InspectionEnd
from agent.runtime.core.standing import Seen
from agent.runtime.shell.runtime import AgentRuntime


def unseen_owned(rt: AgentRuntime) -> list[int]:
    """Ids of ``rt``'s landmarks with zero vision (eq. 3.1) from its current pose; in an
    inspection mission, the capturable landmarks not captured in its view (any owner's)."""
    return _seen(rt).unseen


def orphaned(rt: AgentRuntime) -> dict[str, list[int]]:
    """{departed agent: ids it owned in its last state that nobody owns now}
    (:func:`agent.runtime.core.standing.orphaned`)."""
    return _seen(rt).orphaned


def inspection_end_of(rt: AgentRuntime) -> InspectionEnd | None:
    """How ``rt``'s inspection ended in its view (None in a coverage mission)."""
    ins = _seen(rt).inspection
    return None if ins is None else ins.end


def inspection_end_line(rt: AgentRuntime) -> str | None:
    """``captured N/M at <spec>; ...; complete at t = X s`` (or ``INCOMPLETE: ...``) in
    ``rt``'s view, as ``viscover simulate`` says it; None in a coverage mission."""
    ins = _seen(rt).inspection
    return None if ins is None else ins.line


def _seen(rt: AgentRuntime) -> Seen:
    """What ``rt`` sees now, from its standing."""
    seen = rt.standing(seen=True).seen
    assert seen is not None
    return seen
