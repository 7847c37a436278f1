"""What one agent believes of fences it did not vote for: only what a valid proof shows
(:mod:`agent.protocol.fence_proof`). Part of :class:`~agent.runtime.fencing.adoption.Adoption`.

* A proof it accepts (from a peer's state, or with a coordinator's
  :class:`~agent.wire.peer.AdoptOrder`) is journaled with a
  :class:`~agent.protocol.records.FenceRec`: the agent refuses the fenced agents for good;
  if the proof fences the agent itself, it drops its ledger and leaves
  (:meth:`~agent.protocol.fencing.FenceVoter.learn_fenced`).
* A proof it assembled as coordinator is journaled the same way before any order carries it.
* Its state publishes the proofs it holds (the newest covering each fenced agent) and, as
  ``fenced``, only what they prove: a fence it voted for in a round that never reached a
  majority is refused locally (until the round's coordinator says it was abandoned:
  :meth:`~agent.runtime.fencing.adoption.Adoption.on_round_query`) but claimed to nobody.
* A peer's claim without a valid proof changes nothing: counted (reject reason
  ``unproven_fence``, in the state's ``rejected``) and logged rate-limited.

Part of the agent core: called by one step at a time.
"""

from __future__ import annotations

import logging
from collections.abc import Callable

from agent.protocol.fence_proof import ProofBook, ballot_checker
from agent.protocol.fencing import FenceVoter
from agent.protocol.machine import Step
from agent.protocol.records import FenceRec
from agent.runtime.core.shared import Shared
from agent.runtime.ends.membership import Membership
from agent.wire import keys
from agent.wire.peer import MAX_FENCE_PROOFS, AgentState, FenceProof

_log = logging.getLogger(f"viscover.{__name__}")

#: Reject reason of a peer's fence claim without a valid proof.
REASON_UNPROVEN = "unproven_fence"


class FenceClaims:
    """Fence proofs of one agent (see the module docstring).

    Args:
        shared: the agent's shared state.
        members: its view of the peers (their states' reject counter and log).
        voter: its side of fence rounds (to drop the ledger once fenced out).
        forget_fenced: called after new fences were journaled (partners to drop).
    """

    def __init__(self, shared: Shared, members: Membership, voter: FenceVoter,
                 forget_fenced: Callable[[], None]) -> None:
        self.s = shared
        self.members = members
        self.voter = voter
        self.forget_fenced = forget_fenced
        signing = shared.cfg.signing
        #: the proofs we accepted (the journaled ones first)
        self.book = ProofBook(shared.order, None if signing is None
                              else ballot_checker(signing.team, shared.cfg.mission))
        for proof in shared.machine.fence_proofs:
            self.book.accept(proof)

    def proven(self) -> list[str]:
        """The fences we publish: those the proofs we publish prove (ids ascending)."""
        return sorted({a for p in self.proofs() for a in p.fenced} - {self.s.id})

    def proofs(self) -> list[FenceProof]:
        """The proofs our state carries: the newest covering each agent we know fenced (us
        too, once fenced out)."""
        m = self.s.machine
        mine = {self.s.id} if m.fenced_out is not None else set()
        return self.book.cover(m.fenced | mine, MAX_FENCE_PROOFS)

    def keep(self, proof: FenceProof) -> None:
        """Accept and journal a proof we assembled as coordinator."""
        if self.book.accept(proof):
            rec = FenceRec(epoch=proof.epoch, coordinator=proof.coordinator, fenced=[],
                           proof=proof)
            self.s.machine.apply(rec)
            self.s.journal(Step(records=[rec]))
            self.s.publish_soon()

    def learn(self, proof: FenceProof, by: str) -> None:
        """A proof ``by`` told us of: if valid and new, we refuse the agents it fences
        (journaled with it); if it fences us, we are lost to the team and drop the ledger."""
        s, m = self.s, self.s.machine
        if not self.book.accept(proof):
            return
        s.publish_soon()
        if m.fenced_out is None:
            others = sorted(set(proof.fenced) - m.fenced - {s.id})
            rec = FenceRec(epoch=proof.epoch, coordinator=proof.coordinator, fenced=others,
                           proof=proof)
            m.apply(rec)
            s.journal(Step(records=[rec]))
            if others:
                self.forget_fenced()
        if s.id in proof.fenced and m.fenced_out is None:
            s.journal(self.voter.learn_fenced(proof.epoch, by))
            s.partners.reset(())
            s.end_offer()
            _log.warning("agent %s: the team fenced it out (round %d of %s, %d votes, told by "
                         "%s); its landmarks were adopted", s.id, proof.epoch,
                         proof.coordinator, len(proof.ballots), by)

    def on_peer_state(self, st: AgentState) -> None:
        """A peer's state: the proofs it carries are learned; the fences it names without a
        valid proof are ignored (counted, logged)."""
        for proof in st.fence_proofs:
            self.learn(proof, st.sender)
        claims = set(st.fenced) | ({st.sender} if st.fenced_out else set())
        if unproven := sorted(claims - self.book.proven):
            self.members.codec.reject(
                REASON_UNPROVEN, keys.state_key(self.s.cfg.mission, st.sender),
                f"{st.sender} names {unproven} fenced without a valid proof: ignored")
