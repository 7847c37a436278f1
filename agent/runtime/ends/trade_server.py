"""The responder's side of the trade protocol: this agent's trade queryable
(``viscover/<m>/trade/<id>``). Offers are judged by Algorithm 7 at both agents' current poses,
Commits and StatusQueries are answered from the journal-backed state machine. Every record is
journaled before the reply that depends on it leaves this function.

With a signing key (the secured profile) a query is answered only if a team member signed it
for this process of ours (its incarnation token), never before, and the message inside names
that member as its sender (a query for another incarnation only gets the current token back);
the reply is signed and bound to the query. Anything else is rejected, counted and logged
(truncated), and never reaches the ledger.

**Every offer is checked the same way**, whatever move claims its terms (Algorithm 7, a
re-split leg, taking work, a hand-over, a revert pull): its pose against the evidence of where
the initiator is (:mod:`agent.runtime.ends.pose_check`), then the set it offers against the
ledgers the team publishes (:meth:`TradeServer._check_ledger`): every landmark offered must be
in the initiator's latest published ledger at the version offered, and in no other peer's
(fenced ones aside). A mismatch is answered Busy (a published state lags its ledger by up to
a state period: an honest initiator asks again and passes) and counted (``unconfirmed`` in
the agent's counters, per reason); the responder's own ledger is checked by the trade machine
(a conflict is refused). So a drone cannot hand away landmarks it does not hold, nor take
landmarks from a pose it is not at, with a re-split any more than with a transfer.
"""

from __future__ import annotations

from collections.abc import Callable, Collection, Mapping
from typing import TYPE_CHECKING

import numpy as np

from agent.core.coverage_moves import Goal
from agent.protocol.machine import DecideFn, Step
from agent.runtime.core.events import Query
from agent.runtime.core.shared import Shared, unit_ok, vec3
from agent.runtime.ends.membership import REASON_IMPOSSIBLE, REASON_UNKNOWN_AGENT, Membership
from agent.runtime.ends.pose_check import REASON_POSE, PoseCheck
from agent.runtime.ends.trade_client import PoseNow, TradeClient
from agent.wire.codec import Codec
from agent.wire.peer import (
    AdoptOrder,
    AgentState,
    Busy,
    Commit,
    Fenced,
    FenceProposal,
    JoinRequest,
    Offer,
    Refused,
    Reply,
    Request,
    RoundQuery,
    unpack,
)
from agent.wire.signing import REASON_FORGED, REASON_UNSIGNED

if TYPE_CHECKING:
    from agent.runtime.ends.joining import Joining
    from agent.runtime.fencing.adoption import Adoption


class TradeServer:
    """Answers trade queries addressed to this agent."""

    def __init__(self, shared: Shared, members: Membership, client: TradeClient,
                 adoption: Adoption, joining: Joining, c_req: Codec[Request],
                 c_rep: Codec[Reply], pose_now: PoseNow,
                 regroup_terms: Callable[[Offer], DecideFn]) -> None:
        self.s = shared
        self.members = members
        self.client = client
        self.adoption = adoption  #: fence rounds
        self.joining = joining  #: joiners' admission
        self.c_req, self.c_rep = c_req, c_rep
        self.pose_now = pose_now
        self.poses = PoseCheck(shared, members)  #: the check of offered poses
        #: the decision for a re-split offer: the strategy's moves' (agent.runtime.moves)
        self.regroup_terms = regroup_terms

    def on_query(self, q: Query) -> bytes | None:
        """The reply to one query (None: no reply, the request was rejected and counted, or
        the journal failed: then nothing is answered any more). On the secured profile the
        runtime opened the envelope: ``q.signer`` is its signer, or ``q.refusal`` why it was
        refused (a stale request is answered with the refusal's signed answer)."""
        if self.s.failed is not None:
            return None
        self.s.counters.evicted += q.evicted
        # counted per key expression, not per selector: a query's parameters are the
        # sender's to choose, and the reject counter's table must stay bounded
        key = q.selector.split("?", 1)[0]
        if q.refusal is not None:
            if q.refusal.answer:  # made for another incarnation of us: say which is current
                return q.refusal.answer
            self.c_req.reject(q.refusal.reason, key, q.refusal.detail)
            return None
        if self.s.cfg.signing is not None and q.signer is None:  # never opened: refused
            self.c_req.reject(REASON_UNSIGNED, key, "not opened by the runtime")
            return None
        return self._answer(q.payload, key, q.signer)

    def _answer(self, payload: bytes, selector: str, signer: str | None) -> bytes | None:
        """The reply to a request (``signer``: its authenticated sender, if signed)."""
        s = self.s
        req = self.c_req.decode(payload, selector)
        if req is None:
            return None
        if signer is not None and req.sender != signer:
            self.c_req.reject(REASON_FORGED, selector,
                              f"request names {req.sender!r}, signed by {signer!r}")
            return None
        if isinstance(req, JoinRequest):
            if not unit_ok(req.v):
                self.c_req.reject(REASON_IMPOSSIBLE, selector, "join direction not unit")
                return None
            step = self.joining.on_request(req)
            s.journal(step)
            return self.c_rep.encode(step.reply())
        if not self.members.knows(req.sender):
            self.c_req.reject(REASON_UNKNOWN_AGENT, selector, f"sender {req.sender!r}")
            return None
        if req.sender in s.machine.fenced:  # lost to the team: tell it, change nothing
            return self.c_rep.encode(Fenced(sender=s.id, epoch=s.machine.fence_epoch))
        if isinstance(req, RoundQuery):  # a read: nothing to journal
            return self.c_rep.encode(self.adoption.on_round_query(req))
        if isinstance(req, FenceProposal | AdoptOrder):
            step = self._on_fence_round(req)
        elif isinstance(req, JoinRequest):  # pragma: no cover - answered above
            return None
        elif isinstance(req, Offer):
            if not unit_ok(req.v):
                self.c_req.reject(REASON_IMPOSSIBLE, selector, "offer direction not unit")
                return self.c_rep.encode(
                    Refused(sender=s.id, trade_id=req.trade_id, reason="bad_pose"))
            step = self._on_offer(req, selector)
        elif isinstance(req, Commit):
            step = s.machine.on_commit(req)
            s.journal(step)
            if step.outcome == "committed":
                self.client.forget(req.trade_id)
                s.committed(req.trade_id)
                s.success()
        else:
            step = s.machine.on_status_query(req)
        out = self.c_rep.encode(step.reply())
        if step.records:
            s.changed()
        return out

    def _check_pose(self, req: Offer, selector: str) -> Reply | None:
        """The answer to an offer from a pose its initiator is not at (Refused, counted), or
        whose initiator's pose is not known yet (Busy: ask again); None if it may be judged
        (:mod:`agent.runtime.ends.pose_check`): every offer, a re-split's too (whose terms
        do not use the pose, but a thief's re-split would come from where the thief is); a
        prepared offer keeps its answer."""
        s = self.s
        if req.trade_id in s.machine.prepared:
            return None
        why = self.poses.verdict(req.sender, req.p, req.v, s.now)
        if why is None:
            return None
        if why == "unknown":
            return Busy(sender=s.id, trade_id=req.trade_id, reason="trading")
        self.c_req.reject(REASON_POSE, selector, why)
        return Refused(sender=s.id, trade_id=req.trade_id, reason=REASON_POSE)

    def _check_ledger(self, req: Offer) -> Reply | None:
        """Busy (counted by reason) if the set ``req`` offers is not, landmark for landmark
        and version for version, in the initiator's latest published ledger, or is in
        another live or absent peer's (not fenced); None if it agrees (see the module
        docstring). A malformed set is left to the trade machine (refused there)."""
        s = self.s
        if req.trade_id in s.machine.prepared:
            return None
        got = unpack(req.owned)
        if got is None or got[0].size == 0:
            return None
        why = ledger_mismatch(req.sender, got[0], got[1], self.members.states,
                              s.machine.fenced)
        if why is None:
            return None
        s.counters.unconfirmed_offer(why)
        return Busy(sender=s.id, trade_id=req.trade_id, reason="trading")

    def _on_fence_round(self, req: FenceProposal | AdoptOrder) -> Step:
        """Vote in a fence round, or adopt the orphans it hands us."""
        ad = self.adoption
        if isinstance(req, FenceProposal):
            step = ad.on_proposal(req)
            self.s.journal(step)
        else:
            step = ad.on_adopt(req)
            self.s.journal(step)
            ad.after_adopt(step)
        return step

    def _on_offer(self, req: Offer, selector: str) -> Step:
        s = self.s
        att = s.attempt
        if (att is not None and att.partner == req.sender and s.id > req.sender
                and not s.machine.prepared):
            # Both offered to each other: the larger id yields (its offer cannot have been
            # prepared by a partner that is itself offering), else both would answer
            # Busy("trading") and back off together.
            s.journal(s.machine.abort_offer(att.trade_id, "yield"))
            att.outcome = "yield"
            s.forget_goal(att.trade_id)
            s.end_offer()
            s.counters.count("yield")
        phase = s.phase
        busy = None if phase == "converged" else (
            "optimising" if phase == "optimising" else "trading")
        if req.regroup is not None and busy == "optimising":
            busy = None  # a re-split leg names our set exactly and does not use our pose
        if busy is None:  # to be judged: checked first, whatever move claims its terms
            checked = self._check_pose(req, selector) or self._check_ledger(req)
            if checked is not None:
                return Step(message=checked)
        p, v, _ = self.pose_now()
        # a re-split, a leg or a pull: judged by the move that claims it (agent.runtime.moves)
        decide = s.geo.decide if req.regroup is None else self.regroup_terms(req)
        step = s.machine.on_offer(req, vec3(p), vec3(v), busy, decide)
        s.journal(step)
        if step.outcome == "prepared" and req.regroup is not None and not req.regroup.pull:
            g = req.regroup
            s.expect_goal(req.trade_id, Goal(np.asarray(g.goal_p, dtype=np.float64),
                                             np.asarray(g.goal_v, dtype=np.float64), 0.0))
        if step.outcome == "no_trade":
            s.partners.drop(req.sender)
            s.publish_soon()
        elif step.outcome == "invalid" or step.outcome == "conflict":
            self.c_req.reject(REASON_IMPOSSIBLE, selector, f"offer {step.outcome}")
        return step


def ledger_mismatch(sender: str, ids: np.ndarray, vers: np.ndarray,
                    states: Mapping[str, tuple[AgentState, float]],
                    fenced: Collection[str]) -> str | None:
    """Why landmarks ``ids`` at versions ``vers`` offered by ``sender`` do not agree with the
    published ledgers ``states`` (each peer's latest state): ``unpublished`` (no state of the
    sender, or a landmark missing from its ledger or at another version), ``claimed`` (another
    peer not in ``fenced`` owns one); None if they agree. Vectorised: a sort and a search per
    published ledger."""
    entry = states.get(sender)
    pub = None if entry is None else unpack(entry[0].owned)
    if pub is None:
        return "unpublished"
    p_ids, p_vers = pub
    order = np.argsort(p_ids, kind="stable")
    s_ids, s_vers = p_ids[order], p_vers[order]
    pos = np.minimum(np.searchsorted(s_ids, ids), max(0, s_ids.size - 1))
    if s_ids.size == 0 or not bool(((s_ids[pos] == ids) & (s_vers[pos] == vers)).all()):
        return "unpublished"
    for aid, (st, _t) in states.items():
        if aid == sender or aid in fenced or st.fenced_out:
            continue
        other = unpack(st.owned)
        if other is not None and other[0].size and bool(np.isin(ids, other[0]).any()):
            return "claimed"
    return None
