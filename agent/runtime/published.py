"""What an agent publishes of itself: its state (:class:`~agent.wire.peer.AgentState`), made
from the core's parts at one step; part of the agent core."""

from __future__ import annotations

from agent.runtime.fence_claims import FenceClaims
from agent.runtime.inspecting import Inspecting
from agent.runtime.shared import Shared, vec3
from agent.runtime.vehicle import VehicleView
from agent.wire.peer import AgentState, Counters, pack_arrays


def agent_state(s: Shared, seq: int, pose: VehicleView, vision: float, rejected: int,
                complete: bool, claims: FenceClaims, ins: Inspecting | None) -> AgentState:
    """The state of the agent of ``s`` now (its ``seq``-th): its pose as last stepped in
    [m; world ENU], ledger, vision (eq. 3.4), counters, fences, stage and captures."""
    p, v, t = pose.current()
    c, m = s.counters, s.machine
    return AgentState(
        sender=s.id, incarnation=m.incarnation, seq=seq, t=float(t),
        p=vec3(p), v=vec3(v), phase=s.phase,
        owned=pack_arrays(*m.owned_arrays()), held=pack_arrays(*m.held_arrays()),
        vision=vision,
        counters=Counters(ok=m.ok, failed=m.failed, busy=c.busy, timeouts=c.timeouts,
                          rejected=rejected),
        partners=list(s.partners.pending), pending=m.pending_ids,
        trades_with=dict(m.trades_with), complete=complete,
        fenced=claims.proven(), fence_epoch=m.fence_epoch, fence_proofs=claims.proofs(),
        contested=int(m.contested_arrays()[0].size),
        members=sorted(m.members - {s.id}),
        fenced_out=m.fenced_out is not None, stage=s.stage,
        stage1_vision=s.stage1_vision, reverting=s.reverting,
        captured=b"" if ins is None else ins.bits(),
        trades=list(m.recent), battery=pose.battery(),
        capturable=b"" if ins is None else ins.capturable_bits,
        given_up=[] if ins is None else list(ins.given_up_bits()),
    )
