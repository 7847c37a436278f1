"""What an agent publishes of itself: its state (:class:`~agent.wire.peer.AgentState`), made
from the core's parts at one step; part of the agent core."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from agent.runtime.core.shared import Shared, vec3
from agent.runtime.core.vehicle import VehicleView
from agent.runtime.fencing.fence_claims import FenceClaims
from agent.wire.peer import PARTNERS_PUBLISHED, AgentState, Counters, pack_arrays


def agent_state(s: Shared, seq: int, pose: VehicleView, vision: float, rejected: int,
                complete: bool, claims: FenceClaims, owned_by_parts: Mapping[str, Any]
                ) -> AgentState:
    """The state of the agent of ``s`` now (its ``seq``-th): its pose as last stepped in
    [m; world ENU], ledger, vision (eq. 3.4), counters, fences and stage, and the fields the
    strategy's moves and an inspection's tours own (``owned_by_parts``: their captures, their
    revert...)."""
    p, v, t = pose.current()
    c, m = s.counters, s.machine
    return AgentState(
        sender=s.id, incarnation=m.incarnation, seq=seq, t=float(t),
        p=vec3(p), v=vec3(v), phase=s.phase,
        owned=pack_arrays(*m.owned_arrays()), held=pack_arrays(*m.held_arrays()),
        vision=vision,
        counters=Counters(ok=m.ok, failed=m.failed, busy=c.busy, timeouts=c.timeouts,
                          rejected=rejected, evicted=c.evicted),
        partners=s.partners.pending[:PARTNERS_PUBLISHED], pending=m.pending_ids,
        trades_with=dict(m.trades_with), complete=complete,
        fenced=claims.proven(), fence_epoch=m.fence_epoch, fence_proofs=claims.proofs(),
        contested=int(m.contested_arrays()[0].size),
        members=sorted(m.members - {s.id}),
        fenced_out=m.fenced_out is not None, stage=s.stage,
        trades=list(m.recent), battery=pose.battery(), **owned_by_parts,
    )
