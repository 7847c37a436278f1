"""What an agent can honestly say of itself and the mission at one step, as one snapshot
(:class:`Standing`, :meth:`agent.runtime.shell.runtime.AgentRuntime.standing`): its phase, ledger,
counters and fence rounds, which of its landmarks it does not see (eq. 3.1 is 0 at its pose;
in an inspection: which capturable landmarks nobody captured, in its view), which landmarks
were left with agents that departed before the mission was complete (their owner's liveliness
is gone and nobody owns them: orphaned), and how an inspection ended in its view (complete,
or every capturable landmark not captured with why it was given up,
:mod:`agent.protocol.inspection_end`). Part of the agent core: pure, made under the turn; the
runners print it, nothing else of the core."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from agent.core.inspection import REASONS
from agent.core.vision import per_landmark_cols
from agent.protocol.inspection_end import InspectionEnd, captured_line, end_line
from agent.protocol.records import FencedRec, PoseRec
from agent.runtime.core.shared import Phase, Shared
from agent.runtime.core.vehicle import VehicleView
from agent.runtime.ends.membership import Membership
from agent.runtime.moves.inspecting import Inspecting
from agent.wire.peer import unpack


@dataclass(frozen=True)
class InspectionStanding:
    """An inspection's part: landmarks captured in this agent's view and capturable, those it
    captured itself, how it ended (at ``completed_at``) and its one line; the peers' capture
    claims it refused, by reason (agent.protocol.captures)."""

    captured: int
    capturable: int
    captured_by_me: list[int]
    end: InspectionEnd
    line: str
    refused_claims: dict[str, int] = field(default_factory=dict)


@dataclass(frozen=True)
class Seen:
    """What the agent sees and the mission's end in its view (costs a vision evaluation):
    eq. 3.4 over its landmarks at its pose, the landmarks unseen, those orphaned, and an
    inspection's part."""

    vision: float
    unseen: list[int]
    orphaned: dict[str, list[int]] = field(default_factory=dict)
    inspection: InspectionStanding | None = None


@dataclass(frozen=True)
class Standing:
    """One agent at one step (see the module docstring). Times [s mission]."""

    phase: Phase
    complete: bool
    completed_at: float | None
    incarnation: int
    owned: list[int]  #: landmark ids it owns
    fenced: list[str]  #: agents the team fenced out, as it knows
    fenced_out: FencedRec | None  #: the team fenced this agent out (None: not)
    adopted: int  #: landmarks it adopted from fenced agents
    fence_rounds: list[dict[str, object]]  #: rounds it coordinated to the end
    final_word_gave_up: str | None  #: why it cannot report complete (the bound was hit)
    last_pose: PoseRec | None  #: its journal's last pose
    ok: int
    failed: int
    requests: int
    published: int
    bytes_out: int
    timeouts: int
    rejected: int
    tour_m: float | None  #: an inspection: the length of the rest of its tour [m]
    seen: Seen | None = None  #: asked for (a vision evaluation), else None


def unseen_owned(s: Shared, pose: VehicleView, ins: Inspecting | None) -> list[int]:
    """Ids of the agent's landmarks with zero vision (eq. 3.1) from its pose; in an
    inspection mission, the capturable landmarks not captured in its view (any owner's)."""
    if ins is not None:
        return sorted(int(i) for i in ins.ids[~ins.cap & ins.table.capturable])
    p, v, _ = pose.current()
    ids = s.machine.owned_arrays()[0]
    if ids.size == 0:
        return []
    each = per_landmark_cols(p, v, s.geo.subset(s.geo.rows(ids)), s.geo.term)
    return sorted(int(i) for i in ids[each <= 0.0])


def orphaned(s: Shared, members: Membership) -> dict[str, list[int]]:
    """{departed agent: ids it owned in its last state that nobody owns now}: the landmarks
    nobody will inspect unless that agent comes back. Owners are this agent, the live agents,
    and the agents that left the completed mission (their last state said complete): those
    left normally, orphan nothing, and what they adopted from a lost agent stays theirs. A
    fenced agent's claims are void: the fence round adopted its landmarks, even where this
    agent never heard the adopters (it restarted after they left)."""
    mine = set(s.machine.owned_arrays()[0].tolist())
    states = {a: st for a, (st, _t) in members.states.items() if a not in s.machine.fenced}
    live = set(members.live)
    claimed = set(mine)
    for a, st in states.items():
        if a in live or (st.complete and not st.fenced_out):
            got = unpack(st.owned)
            if got is not None:
                claimed.update(got[0].tolist())
    out: dict[str, list[int]] = {}
    for a, st in states.items():
        if a in live or a == s.id or st.complete:  # left a completed mission: not orphaning
            continue
        got = unpack(st.owned)
        if got is None:
            continue
        left = np.setdiff1d(got[0], np.fromiter(claimed, dtype=np.int64, count=len(claimed)))
        if left.size:
            out[a] = [int(i) for i in left]
    return out


def inspection_standing(s: Shared, ins: Inspecting, completed_at: float | None
                        ) -> InspectionStanding:
    """An inspection's end in this agent's view: ``captured N/M at <spec>; K uncapturable
    (...); complete at t = X s`` (or ``INCOMPLETE: G given up (...)``), as ``viscover
    simulate`` says it."""
    end = ins.end(completed_at)
    reason, cap = ins.table.reason, ins.cap
    left = np.flatnonzero((reason != 0) & ~cap)  # an uncapturable one captured counts
    uncapturable = {int(ins.ids[j]): REASONS[int(reason[j])] for j in left}
    line = end_line(captured_line(int(cap.sum()), int(ins.ids.size - left.size),
                                  ins.spec.describe(), uncapturable), end)
    return InspectionStanding(int(cap.sum()), int(ins.table.capturable.sum()),
                              sorted(s.machine.captured), end, line,
                              dict(sorted(ins.judge.refused.items())))


def standing(s: Shared, members: Membership, pose: VehicleView, ins: Inspecting | None,
             vision: float | None, rejected: int, complete: bool, completed_at: float | None,
             rounds: list[dict[str, object]], gave_up: str | None) -> Standing:
    """The :class:`Standing` of the agent of ``s`` now (its parts' values passed in; with
    its ``vision``, what it sees too)."""
    m, c = s.machine, s.counters
    return Standing(
        phase=s.phase, complete=complete, completed_at=completed_at,
        incarnation=m.incarnation, owned=m.owned_arrays()[0].tolist(),
        fenced=sorted(m.fenced), fenced_out=m.fenced_out, adopted=m.adopted,
        fence_rounds=list(rounds), final_word_gave_up=gave_up, last_pose=m.last_pose,
        ok=m.ok, failed=m.failed, requests=c.requests, published=c.published,
        bytes_out=c.bytes_out, timeouts=c.timeouts, rejected=rejected,
        tour_m=None if ins is None else float(ins.tour.length),
        seen=None if vision is None else Seen(
            vision, unseen_owned(s, pose, ins), orphaned(s, members),
            None if ins is None else inspection_standing(s, ins, completed_at)))
