"""Fence rounds given up without a proof, as one agent takes part (:mod:`agent.protocol.
fencing`, "Abandoned rounds"; part of :class:`~agent.runtime.fencing.adoption.Adoption`):

* as a coordinator it releases the voters of a round it gives up
  (:meth:`AbandonedRounds.release`) and says where each of its rounds stands
  (:meth:`AbandonedRounds.status`): running, proven (with the proof) or abandoned;
* as a voter, for each round its unproven fences come from, it asks that round's
  coordinator (:meth:`AbandonedRounds.settle`, in the core's tick) and lifts the fences of
  an abandoned one (:meth:`AbandonedRounds.lift`, which the coordinator also calls for its
  own vote when it gives a round up), or keeps the proof of a proven one.

Part of the agent core: called by one step at a time.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Mapping

import numpy as np

from agent.protocol.fencing import FenceVoter, RoundId
from agent.runtime.core.events import Asking
from agent.runtime.core.shared import Shared
from agent.runtime.ends.membership import Membership
from agent.runtime.ends.trade_client import TradeClient
from agent.runtime.fencing.fence_claims import FenceClaims
from agent.wire.codec import Codec
from agent.wire.peer import (
    AdoptOrder,
    FenceProposal,
    FenceVote,
    Request,
    RoundQuery,
    RoundStatus,
    pack_arrays,
)

_log = logging.getLogger(f"viscover.{__name__}")


class AbandonedRounds:
    """Rounds given up without a proof (see the module docstring).

    Args:
        shared: the agent's shared state.
        members: its view of the peers (who is live; partners again once lifted).
        client: asks a coordinator (:meth:`TradeClient.request`).
        c_req: the request codec.
        voter: its side of fence rounds (lifts the fences).
        claims: the proofs it accepted (a proven round's proof is learned there).
        running: the epoch of the round this agent coordinates now, if any.
    """

    def __init__(self, shared: Shared, members: Membership, client: TradeClient,
                 c_req: Codec[Request], voter: FenceVoter, claims: FenceClaims,
                 running: Callable[[], int | None]) -> None:
        self.s, self.members, self.client, self.c_req = shared, members, client, c_req
        self.voter, self.claims, self.running = voter, claims, running
        #: when we last asked a coordinator about a round our unproven fences come from
        self._asked: dict[RoundId, float] = {}

    def status(self, q: RoundQuery) -> RoundStatus:
        """Where our round ``q.epoch`` stands: running, proven (with its proof), or
        abandoned (not running and no proof: a round is never resumed, and we order no
        adoption without its proof journaled, so none ever will be)."""
        s = self.s
        if self.running() == q.epoch:
            return RoundStatus(sender=s.id, epoch=q.epoch, status="running")
        proof = self.claims.book.proofs.get((q.epoch, s.id))
        if proof is not None:
            return RoundStatus(sender=s.id, epoch=q.epoch, status="proven", proof=proof)
        return RoundStatus(sender=s.id, epoch=q.epoch, status="abandoned")

    def settle(self, now: float) -> Asking[None]:
        """Ask the coordinator of each round our unproven fences come from where it stands
        (once per half a freeze period, while it is live): lift the fences of a round
        abandoned, keep the proof of one proven. Our own rounds we answer ourselves."""
        s, m = self.s, self.s.machine
        for rid in sorted(m.unproven_rounds()):  # a loop over rounds, a few at most
            epoch, coordinator = rid
            if self.voter.freeze is not None and self.voter.freeze.rid == rid:
                continue  # still voting in it
            if coordinator == s.id:
                if self.running() != epoch:
                    self.lift(rid)
                continue
            if coordinator not in self.members.live or coordinator in m.fenced \
                    or now < self._asked.get(rid, -math.inf) + s.cfg.freeze_s / 2:
                continue
            self._asked[rid] = now
            req = self.c_req.encode(RoundQuery(sender=s.id, epoch=epoch))
            reply = yield from self.client.request(coordinator, req)
            if not isinstance(reply, RoundStatus) or reply.sender != coordinator \
                    or reply.epoch != epoch:
                continue
            if reply.status == "abandoned":
                self.lift(rid)
            elif reply.status == "proven" and reply.proof is not None:
                self.claims.learn(reply.proof, coordinator)

    def release(self, prop: FenceProposal, votes: Mapping[str, FenceVote]) -> Asking[None]:
        """Unfreeze the voters of our round ``prop``, given up (one try each; their freeze
        expires anyway)."""
        none = pack_arrays(np.zeros(0, np.int64), np.zeros(0, np.int64))
        # Fenced list naming someone the voters do not fence: refused, so nothing changes.
        empty = AdoptOrder(sender=self.s.id, epoch=prop.epoch, fenced=[self.s.id], owned=none,
                           drop=none)
        for v in votes:
            if v != self.s.id:
                yield from self.client.request(v, self.c_req.encode(empty))

    def lift(self, rid: RoundId) -> None:
        """Round ``rid`` ended without a proof: lift the fences we took only by voting in it
        (journaled, fsynced before we trade with them) and try those agents again."""
        s = self.s
        before = set(s.machine.fenced)
        s.journal(self.voter.abandon(rid))
        self._asked.pop(rid, None)
        if lifted := sorted(before - s.machine.fenced):
            _log.warning("agent %s: fence round %d of %s ended without a proof: %s no longer "
                         "fenced here", s.id, rid[0], rid[1], ", ".join(lifted))
            for aid in lifted:
                if aid in self.members.live:
                    self.members.partner_joined(aid)
