"""Lost agents and their landmarks, as one agent takes part: it notices peers gone for longer
than the scenario's ``lost_after``, coordinates a fence round when it is the lowest live id,
votes in the rounds of others (through its trade queryable), adopts the orphans it is given,
and drops its ledger if it learns that the team fenced it out. The rules and why they are safe
are in :mod:`agent.protocol.fencing`; this module sends and receives its messages.

The coordinator runs its round in the core's tick, like the trade client its offers: a few
queries (asks), each waiting at most ``request_timeout_s``; the core answers its own queries
meanwhile.

Fences are believed only with their proof (:mod:`agent.protocol.fence_proof`): the
coordinator assembles it from the votes (each ballot signed by its voter on the secured
profile), journals it, sends it with its orders; every agent checks a proof before it
refuses the agents it names or, named itself, drops its ledger, and publishes the proofs it
accepted in its state (``fenced`` lists only what they prove). A claim without a valid proof
is ignored, counted (reason ``unproven_fence``) and logged rate-limited
(:mod:`agent.runtime.fencing.fence_claims`).

A round given up without a proof leaves no fence behind (:mod:`agent.runtime.fencing.abandoned`).
(Just over 400 lines, not split: who completion waits for and who a round fences are one
judgement of who is lost.)
"""

from __future__ import annotations

import logging
import random
from collections.abc import Callable

import numpy as np

from agent.protocol.fence_proof import has_majority, make_proof
from agent.protocol.fencing import (
    FenceVoter,
    adoption_versions,
    assign_orphans,
    decide_round,
    has_quorum,
    orphan_ids,
    voters_of,
)
from agent.protocol.machine import Step
from agent.protocol.records import AdoptRec, MemberRec
from agent.runtime.core.events import Asking
from agent.runtime.core.shared import IntArray, Shared, vec3
from agent.runtime.ends.completion import Completion
from agent.runtime.ends.membership import Membership
from agent.runtime.ends.trade_client import PoseNow, TradeClient
from agent.runtime.fencing.abandoned import AbandonedRounds
from agent.runtime.fencing.fence_claims import FenceClaims
from agent.runtime.fencing.final_word import FinalWord
from agent.wire.ballots import sign_ballot
from agent.wire.codec import Codec
from agent.wire.peer import (
    AdoptAck,
    AdoptOrder,
    AgentState,
    FenceProof,
    FenceProposal,
    FenceVote,
    Refused,
    Request,
    RoundQuery,
    RoundStatus,
    pack_arrays,
    unpack,
)

_log = logging.getLogger(f"viscover.{__name__}")

#: Tries of one fence-round query to one voter before the round is given up.
ROUND_TRIES = 4


class Adoption:
    """Fence rounds of one agent (see the module docstring)."""

    def __init__(self, shared: Shared, members: Membership, client: TradeClient,
                 c_req: Codec[Request], pose_now: PoseNow, completion: Completion) -> None:
        self.s = shared
        self.members = members
        self.completion = completion
        self.client = client
        self.c_req = c_req
        self.pose_now = pose_now
        cfg, signing = shared.cfg, shared.cfg.signing
        sign = None if signing is None else (
            lambda epoch, coord, fenced: sign_ballot(signing, cfg.mission, epoch, coord,
                                                     fenced))
        self.voter = FenceVoter(shared.machine, sign)
        #: the fences we believe from others, and the proofs we publish
        self.claims = FenceClaims(shared, members, self.voter, self._forget_fenced)
        #: the team's final word (the router's fence record), heard before completion
        self.final_word = FinalWord(shared, self.claims, completion)
        completion.final_word = self.final_word.waiting
        completion.heard_complete = self.final_word.heard_complete
        self.absent_since: dict[str, float] = {}  #: mission time each peer was last missed
        self.next_round = 0.0
        self._leftover_since: float | None = None
        self._due_since: float | None = None  #: since when a round is due in our view
        self.rounds: list[dict[str, object]] = []  #: rounds this agent coordinated to the end
        self.running: int | None = None  #: the epoch of the round we coordinate now, if any
        #: rounds given up without a proof: ours answered, our votes' fences lifted
        self.abandoned = AbandonedRounds(shared, members, client, c_req, self.voter,
                                         self.claims, lambda: self.running)
        #: called after we adopted landmarks
        self.on_adopted: list[Callable[[], None]] = []
        self._rng = random.Random(f"fence:{shared.cfg.seed}:{shared.id}")
        members.state_hooks.append(self._on_peer_state)

    # -- voter side (the trade queryable) ----------------------------------------------------
    def on_proposal(self, prop: FenceProposal) -> Step:
        """Our vote on ``prop`` (journal the step's records before replying)."""
        s = self.s
        p, v, _ = self.pose_now()
        step = self.voter.on_proposal(prop, set(self.members.live), vec3(p), vec3(v),
                                      s.now, s.cfg.freeze_s)
        if step.records:
            self._forget_fenced()
        return step

    def on_adopt(self, order: AdoptOrder) -> Step:
        """Adopt ``order``'s orphans if still frozen for its round (keeping its proof)."""
        if order.proof is not None:
            self.claims.learn(order.proof, order.sender)
        return self.voter.on_adopt(order, self.s.now)

    def on_round_query(self, q: RoundQuery) -> RoundStatus:
        """Where our round ``q.epoch`` stands (:meth:`AbandonedRounds.status`)."""
        return self.abandoned.status(q)

    def after_adopt(self, step: Step) -> None:
        """Once the adoption is journaled: optimise and trade again with the new landmarks."""
        if step.outcome == "adopted" and any(
                isinstance(r, AdoptRec) and r.owned.ids for r in step.records):
            self.s.success()
            for hook in self.on_adopted:
                hook()
            self.completion.restart()

    def _forget_fenced(self) -> None:
        s = self.s
        for aid in s.machine.fenced:
            s.partners.forget(aid)
        s.publish_soon()

    def _on_peer_state(self, st: AgentState) -> None:
        """A peer's state: believe only the fences it proves (:class:`FenceClaims`)."""
        self.claims.on_peer_state(st)

    # -- who is lost ------------------------------------------------------------------------
    def lost(self, now: float, grace: bool = True, completed: bool = False) -> list[str]:
        """Peers absent for ``lost_after`` [s] (without ``grace``: absent now) that had not
        completed (with ``completed``: those too; a round must count or fence every member,
        but one that left a completed mission orphans nothing and starts no round); call"""
        s, members = self.s, self.members
        out = []
        for aid in self.members.team_order():
            if aid == s.id or aid in s.machine.fenced:
                continue
            if aid in members.live:
                self.absent_since.pop(aid, None)
                continue
            since = self.absent_since.setdefault(aid, now)
            entry = members.states.get(aid)
            if entry is not None and entry[0].complete and not completed:
                continue  # left a completed mission: nothing is orphaned
            if not grace or now - since >= s.sc.lost_after:
                out.append(aid)
        return out

    def orphan_estimate(self) -> IntArray:
        """Landmarks in no ledger we know of (ours, live peers' last states, the last states
        of peers that left a completed mission); only once some agent was fenced."""
        if not self.s.machine.fenced:
            return np.zeros(0, dtype=np.int64)
        return self.unaccounted()

    def unaccounted(self) -> IntArray:
        """Landmarks in no ledger we know of (:meth:`orphan_estimate`, whether or not an
        agent was fenced)."""
        s, m = self.s, self.s.machine
        ledgers = [m.ledger_arrays()[0]]
        for aid, (st, _t) in self.members.states.items():
            if (aid in self.members.live or st.complete) and aid not in m.fenced:
                for lm in (st.owned, st.held):
                    got = unpack(lm)
                    if got is not None:
                        ledgers.append(got[0])
        return orphan_ids(s.geo.sorted_ids, ledgers)

    def unresolved(self) -> int:
        """Landmarks held for trades with fenced agents, ours and the live peers' (a round
        must resolve them)."""
        m = self.s.machine
        n = int(m.contested_arrays()[0].size)
        return n + sum(st.contested for aid, (st, _t) in self.members.states.items()
                       if aid in self.members.live and aid not in m.fenced)

    def _leftovers(self, now: float) -> bool:
        """Orphans or landmarks held for fenced agents are left, in our view, and have been
        for three state periods (a landmark in flight between two peers whose states have not
        caught up is not one)."""
        m = self.s.machine
        if not m.fenced or not (self.orphan_estimate().size or self.unresolved()):
            self._leftover_since = None
            return False
        if self._leftover_since is None:
            self._leftover_since = now
        return now - self._leftover_since >= 3 * self.s.cfg.state_period_s

    def waiting(self, now: float) -> str | None:
        """Why completion must wait for a fence round (None: it need not)."""
        s, m = self.s, self.s.machine
        if s.sc.lost_after <= 0 or m.fenced_out is not None:
            return None
        # Every member absent for lost_after counts against the quorum, those that left a
        # completed mission too (we may have missed another's completion: it cannot vote
        # either). One absent for less (a restart under way) still counts as a voter: a
        # quorum missing for a moment must not leave orphans for good.
        if not has_quorum(s.order, m.fenced, self.lost(now, completed=True)):
            return None  # no majority left to adopt: complete, reporting the orphans
        gone = self.lost(now, grace=False)
        if not (s.cfg.require_all and m.incarnation <= 1):
            # A joiner or a restarted agent may never have heard an agent that left: only
            # those it knows left early hold it back; a restarted one also waits for those
            # it never heard since, while landmarks are in no ledger it knows of and the
            # team's final word did not hear them complete (a team that all restarted after
            # an agent vanished must fence it and adopt before completing).
            heard = self.members.states
            keep: set[str] = set()
            if m.incarnation > 1 and any(a not in heard for a in gone) \
                    and self.unaccounted().size:
                keep = set(gone) - self.final_word.heard_complete()
            gone = [a for a in gone if a in heard or a in keep]
        if gone:  # they come back, or are fenced and their landmarks adopted
            return f"agents {gone} gone before completing: back within " \
                f"{s.sc.lost_after:g} s, or their landmarks are adopted"
        if m.fenced:
            orphans = self.orphan_estimate()
            if orphans.size:
                return f"{orphans.size} orphaned landmarks to adopt"
            if n := self.unresolved():
                return f"{n} landmarks in trades with fenced agents to resolve"
        return None

    # -- coordinator side (the core's tick) -------------------------------------------------
    def tick(self, now: float) -> Asking[None]:
        """Hear the team's final word if wanted; end an expired freeze; run a fence round if
        one is due and we coordinate."""
        yield from self.final_word.tick(now)
        s, m = self.s, self.s.machine
        self.members.sweep(now)  # a token that never speaks holds nothing up for ever
        self.voter.expire(now)
        yield from self.abandoned.settle(now)
        if s.sc.lost_after <= 0 or m.fenced_out is not None or now < self.next_round \
                or self.voter.freeze is not None:
            return
        lost = self.lost(now)
        if not lost and not self._leftovers(now):
            self._due_since = None
            return
        if self._due_since is None:
            self._due_since = now
        live = {a for a in self.members.live if a not in m.fenced}
        lost = self.lost(now, completed=True)  # a round counts or fences every member
        # The lowest live id coordinates; anyone else once a round has been due for two
        # freeze periods (the coordinator may know better, e.g. it heard the lost agent
        # complete, while our view waits): a second coordinator is safe, rounds serialise.
        waited = now - self._due_since > 2 * s.cfg.freeze_s
        if (any(a < s.id for a in live) and not waited) \
                or not has_quorum(s.order, m.fenced, lost):
            return
        voters = voters_of([*self.members.team_order(), s.id], m.fenced, lost)
        epoch = max([m.fence_epoch, *(st.fence_epoch for st, _ in
                                      self.members.states.values())]) + 1
        fenced = sorted(m.fenced | set(lost))
        yield from self._round(FenceProposal(sender=s.id, epoch=epoch, fenced=fenced), voters)

    def _abandon(self, prop: FenceProposal, votes: dict[str, FenceVote], why: str,
                 proof: FenceProof | None) -> Asking[None]:
        """Give our round ``prop`` up: its ``proof`` (a majority of ``votes``) holds the fence,
        else our vote's fences are lifted (the voters' when they ask); voters released."""
        if proof is None:
            self.abandoned.lift((prop.epoch, self.s.id))
        yield from self.abandoned.release(prop, votes)
        self._give_up(why)

    def _give_up(self, why: str) -> None:
        s = self.s
        self.voter.release()
        delay = s.cfg.freeze_s * self._rng.uniform(0.5, 1.5)
        self.next_round = s.now + delay
        _log.info("agent %s: fence round given up (%s); next try in %.1f s", s.id, why, delay)

    def _ask(self, voter: str, req: Request, want: type) -> Asking[object | None]:
        """Query ``voter`` up to :data:`ROUND_TRIES` times; its reply of type ``want``, a
        Refused, or None (no answer)."""
        payload = self.c_req.encode(req)
        for _ in range(ROUND_TRIES):
            reply = yield from self.client.request(voter, payload)
            if isinstance(reply, want | Refused):
                return reply
        return None

    def _round(self, prop: FenceProposal, voters: list[str]) -> Asking[None]:
        """Run fence round ``prop`` with ``voters`` (we among them); running until its end."""
        self.running = prop.epoch
        try:
            yield from self._run_round(prop, voters)
        finally:
            self.running = None

    def _run_round(self, prop: FenceProposal, voters: list[str]) -> Asking[None]:
        s = self.s
        mine = self.on_proposal(prop)
        s.journal(mine)
        if not isinstance(mine.message, FenceVote):
            self._give_up(f"own vote refused: {mine.outcome}")
            return
        votes: dict[str, FenceVote] = {s.id: mine.message}
        allowed = set(s.machine.fenced)
        counted = set(voters) | allowed
        for v in voters:
            if v == s.id:
                continue
            got = yield from self._ask(v, prop, FenceVote)
            if not isinstance(got, FenceVote) or got.sender != v or got.epoch != prop.epoch \
                    or not set(got.fenced) <= allowed or unpack(got.ledger) is None \
                    or unpack(got.contested) is None:
                why = got.reason if isinstance(got, Refused) else "no vote"
                if isinstance(got, FenceVote) and (more := set(got.fenced) - allowed):
                    why = f"its vote fences {', '.join(sorted(more))}, this agent does not"
                yield from self._abandon(prop, votes, f"{v}: {why}",
                                         self._prove(prop, votes))
                return
            votes[v] = got
            if unknown := set(got.members) - counted - {s.id}:
                # A joiner we did not know of: it must vote too (or be lost); next round.
                for aid in sorted(unknown):
                    rec = MemberRec(agent=aid)
                    s.machine.apply(rec)
                    s.journal(Step(records=[rec]))
                yield from self._abandon(prop, votes, f"{v} admitted {sorted(unknown)}",
                                         self._prove(prop, votes))
                return
        yield from self._adopt(prop, votes, sorted(allowed))

    def _prove(self, prop: FenceProposal, votes: dict[str, FenceVote]) -> FenceProof | None:
        """The proof of round ``prop`` if ``votes`` are a strict majority of the team (kept,
        journaled and published); None if not."""
        s = self.s
        if not has_majority(votes, s.order):
            return None
        proof = make_proof(prop.epoch, prop.sender, prop.fenced,
                           {v: vote.sig for v, vote in votes.items()})
        if (why := self.claims.book.verdict(proof)) is not None:  # a voter's ballot did not check
            _log.warning("agent %s: fence round %d: no proof (%s)", s.id, prop.epoch, why)
            return None
        self.claims.keep(proof)
        return proof

    def _adopt(self, prop: FenceProposal, votes: dict[str, FenceVote],
               fenced: list[str]) -> Asking[None]:
        """Every voter voted: decide the contested landmarks, hand each orphan to the voter
        that sees it best."""
        s = self.s
        names = sorted(votes)
        ledgers, contested = [], []
        for n in names:
            got, con = unpack(votes[n].ledger), unpack(votes[n].contested)
            assert got is not None and con is not None  # checked in _round
            ledgers.append(got[0])
            contested.append(con)
        proof = self._prove(prop, votes)
        if proof is None:  # a ballot did not check: no adoption without its proof
            yield from self._abandon(prop, votes, "no proof of the votes", None)
            return
        decision = decide_round(s.geo.sorted_ids, ledgers, contested)
        orphans = decision.orphans
        known = []
        for aid, (st, _t) in self.members.states.items():
            if aid in s.machine.fenced:
                known += [x for x in (unpack(st.owned), unpack(st.held)) if x is not None]
        versions = adoption_versions(orphans, known)
        who = assign_orphans(s.geo.subset(s.geo.rows(orphans)),
                             [(votes[n].p, votes[n].v) for n in names], s.geo.term)
        result: dict[str, int] = {}
        for k, n in enumerate(names):
            share = who == k
            drop = decision.drop[k]
            order = AdoptOrder(sender=s.id, epoch=prop.epoch, fenced=fenced,
                               owned=pack_arrays(orphans[share], versions[share]),
                               drop=pack_arrays(drop, np.zeros(drop.size, np.int64)),
                               proof=proof)
            if n == s.id:
                step = self.on_adopt(order)
                s.journal(step)
                self.after_adopt(step)
                ok = isinstance(step.message, AdoptAck) and step.message.ok
            else:
                ack = yield from self._ask(n, order, AdoptAck)
                ok = isinstance(ack, AdoptAck) and ack.ok
            result[n] = int(share.sum()) if ok else -int(share.sum())
        s.changed()
        adopted = sum(x for x in result.values() if x > 0)
        self.rounds.append({"epoch": prop.epoch, "lost": list(prop.fenced),
                            "orphans": int(orphans.size), "adopted": adopted,
                            "t": s.now, "by": result})
        if adopted < orphans.size:  # some voter's freeze ran out: try again later
            self.next_round = s.now + s.cfg.freeze_s
        _log.warning("agent %s: fence round %d: %s lost; %d orphaned landmarks, %d adopted (%s)",
                     s.id, prop.epoch, ", ".join(prop.fenced) or "nobody", orphans.size,
                     adopted, ", ".join(f"{k} {v}" for k, v in result.items()))

