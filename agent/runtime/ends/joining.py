"""Drones that join a running mission (beyond the thesis, whose team is fixed): a drone not in
the scenario starts with no landmark, asks the scenario's agents to admit it, and trades once a
strict majority of them has.

Why a majority: a fence round (:mod:`agent.protocol.fencing`) treats every landmark outside
its voters' ledgers as orphaned, so it must hear from every member that can hold landmarks.
Each admitting agent journals :class:`~agent.protocol.records.MemberRec` before it
acknowledges and reports its members in its fence votes; any round's voters are a majority of
the scenario's agents, so at least one of them admitted the joiner and names it, and the round
waits for the joiner's own vote (or fences it too if it is gone).

The joiner asks every live scenario agent (each tick, at most once a state period, one query
each); it trades only with agents that admitted it.
"""

from __future__ import annotations

import logging

from agent.protocol.machine import Step
from agent.protocol.records import MemberRec
from agent.runtime.core.events import Asking
from agent.runtime.core.shared import Shared, vec3
from agent.runtime.ends.membership import Membership
from agent.runtime.ends.trade_client import PoseNow, TradeClient
from agent.wire.codec import Codec
from agent.wire.peer import AgentState, JoinAck, JoinRequest, Refused, Request

_log = logging.getLogger(f"viscover.{__name__}")


class Joining:
    """Admission of joiners: the joiner's side (``joiner``) and every agent's answer."""

    def __init__(self, shared: Shared, members: Membership, client: TradeClient,
                 c_req: Codec[Request], pose_now: PoseNow, joiner: bool) -> None:
        self.s = shared
        self.members = members
        self.client = client
        self.c_req = c_req
        self.pose_now = pose_now
        self.joiner = joiner
        self.acked: set[str] = set()  #: scenario agents that admitted us (joiner)
        self._next_ask = 0.0
        if joiner:
            members.may_trade = lambda aid: aid in self.acked
        members.state_hooks.append(self._on_peer_state)

    def _on_peer_state(self, st: AgentState) -> None:
        """Joiners a peer admitted or heard of become known to us too (journaled; knowing
        one more member only makes fence rounds wait for it): we hear its state, a round
        counts it."""
        s, m = self.s, self.s.machine
        new = sorted(set(st.members) - m.members - {s.id} - set(s.order))
        for aid in new:
            rec = MemberRec(agent=aid)
            m.apply(rec)
            s.journal(Step(records=[rec]))
            self.members.admit(aid, None)

    @property
    def admitted(self) -> bool:
        """A joiner admitted by a strict majority of the scenario's agents (always True for
        a scenario agent)."""
        return not self.joiner or self.s.id in self.s.machine.members

    # -- every agent: answer a joiner (a query) ---------------------------------------------
    def on_request(self, req: JoinRequest) -> Step:
        """Admit ``req.sender`` (journal the step's records before replying)."""
        s, m, step = self.s, self.s.machine, Step()
        if req.sender in s.order or req.sender in m.fenced or m.fenced_out is not None:
            step.message = Refused(sender=s.id, trade_id="", reason="not_a_joiner")
            return step
        if req.sender not in m.members:
            rec = MemberRec(agent=req.sender)
            m.apply(rec)
            step.records.append(rec)
            _log.info("agent %s: admitted %s to the team", s.id, req.sender)
        self.members.admit(req.sender, req.p)
        step.message = JoinAck(sender=s.id, ok=True)
        step.outcome = "admitted"
        return step

    # -- the joiner (the core's tick) -----------------------------------------------------------
    def tick(self, now: float) -> Asking[None]:
        """Ask the live scenario agents that have not admitted us yet (at most once a state
        period); journal our own admission once a majority has."""
        s = self.s
        if not self.joiner or now < self._next_ask:
            return
        self._next_ask = now + s.cfg.state_period_s
        ask = [a for a in s.order if a in self.members.live and a not in self.acked
               and a not in s.machine.fenced]
        p, v, _ = self.pose_now()
        payload = self.c_req.encode(JoinRequest(sender=s.id, p=vec3(p), v=vec3(v)))
        for aid in ask:
            reply = yield from self.client.request(aid, payload)
            if isinstance(reply, JoinAck) and reply.ok and reply.sender == aid:
                self.acked.add(aid)
                if self.admitted:
                    self.members.partner_joined(aid)
        if not self.admitted and 2 * len(self.acked & set(s.order)) > len(s.order):
            rec = MemberRec(agent=s.id)
            s.machine.apply(rec)
            s.journal(Step(records=[rec]))
            for aid in sorted(self.acked):  # until now it had no partner: quiet
                self.members.partner_joined(aid)
            _log.info("agent %s: joined the mission (admitted by %s)", s.id,
                      ", ".join(sorted(self.acked)))
