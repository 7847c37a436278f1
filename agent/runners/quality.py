"""What an agent can honestly say about the mission when it ends: which of its landmarks it
does not see (eq. 3.1 is 0 at its final pose; in an inspection mission: which capturable
landmarks nobody captured, in its view) and which landmarks were left with agents that
departed before the mission was complete (their owner's liveliness is gone and nobody owns
them: no live agent, nor one that left the completed mission: orphaned); and, for an inspection,
how it ended in its view (:func:`inspection_end_line`: complete, or every capturable landmark
not captured with why it was given up, :mod:`agent.protocol.inspection_end`)."""

from __future__ import annotations

import numpy as np

from agent.core.inspection import REASONS
from agent.core.vision import per_landmark_cols
from agent.protocol.inspection_end import InspectionEnd, captured_line, end_line
from agent.runtime.agent import AgentRuntime
from agent.wire.peer import unpack


def unseen_owned(rt: AgentRuntime) -> list[int]:
    """Ids of ``rt``'s landmarks with zero vision (eq. 3.1) from its current pose; in an
    inspection mission, the capturable landmarks not captured in its view (any owner's)."""
    s = rt.shared
    ins = rt.planning.inspecting
    if ins is not None:
        return sorted(int(i) for i in ins.ids[~ins.cap & ins.table.capturable])
    p, v, _ = rt.pose.current()
    with rt.turn:
        ids = s.machine.owned_arrays()[0]
    if ids.size == 0:
        return []
    each = per_landmark_cols(p, v, s.geo.subset(s.geo.rows(ids)), s.geo.term)
    return sorted(int(i) for i in ids[each <= 0.0])


def orphaned(rt: AgentRuntime) -> dict[str, list[int]]:
    """{departed agent: ids it owned in its last state that nobody owns now}: the landmarks
    nobody will inspect unless that agent comes back. Owners are ``rt``, the live agents, and
    the agents that left the completed mission (their last state said complete): those left
    normally, orphan nothing, and what they adopted from a lost agent stays theirs. A fenced
    agent's claims are void: the fence round adopted its landmarks, even where this agent
    never heard the adopters (it restarted after they left)."""
    s, members = rt.shared, rt.members
    with rt.turn:
        mine = set(s.machine.owned_arrays()[0].tolist())
        states = {a: st for a, (st, _t) in members.states.items()
                  if a not in s.machine.fenced}
        live = set(members.live)
    claimed = set(mine)
    for a, st in states.items():
        if a in live or (st.complete and not st.fenced_out):
            got = unpack(st.owned)
            if got is not None:
                claimed.update(got[0].tolist())
    out: dict[str, list[int]] = {}
    for a, st in states.items():
        if a in live or a == rt.id or st.complete:  # left a completed mission: not orphaning
            continue
        got = unpack(st.owned)
        if got is None:
            continue
        left = np.setdiff1d(got[0], np.fromiter(claimed, dtype=np.int64, count=len(claimed)))
        if left.size:
            out[a] = [int(i) for i in left]
    return out


def inspection_end_of(rt: AgentRuntime) -> InspectionEnd | None:
    """How ``rt``'s inspection ended in its view, once the team stopped or the time ran out:
    complete (at the mission time it reported completion), or what was given up and why;
    None in a coverage mission."""
    ins = rt.planning.inspecting
    if ins is None:
        return None
    with rt.turn:
        return ins.end(rt.completed_at)


def inspection_end_line(rt: AgentRuntime) -> str | None:
    """``captured N/M at <spec>; K uncapturable (...); complete at t = X s`` (or
    ``INCOMPLETE: G given up (...)``) in ``rt``'s view, as ``viscover simulate`` says it;
    None in a coverage mission."""
    ins = rt.planning.inspecting
    end = inspection_end_of(rt)
    if ins is None or end is None:
        return None
    with rt.turn:
        reason, cap = ins.table.reason, ins.cap.copy()
    left = np.flatnonzero((reason != 0) & ~cap)  # an uncapturable one captured counts
    uncapturable = {int(ins.ids[j]): REASONS[int(reason[j])] for j in left}
    return end_line(captured_line(int(cap.sum()), int(ins.ids.size - left.size),
                                  ins.spec.describe(), uncapturable), end)
