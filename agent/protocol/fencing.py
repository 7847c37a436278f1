"""Fence rounds: the team declares agents lost and adopts their landmarks (beyond the thesis,
which assumes every agent stays). Pure: no I/O, no clock (times are passed in).

An agent that left the mission before completing it and did not come back within the
scenario's ``lost_after`` is *lost*. Its landmarks would stay uninspected forever, so the
survivors fence it out and adopt them:

1. **Proposal.** The coordinator C (the lowest live id; any agent once a round has been due
   in its view for two freeze periods, as views differ) sends
   :class:`~agent.wire.peer.FenceProposal` (round ``(epoch, C)``, agents F: the newly lost
   and every agent C fenced before) to every other agent of the team (the *voters*, C
   included).
2. **Vote.** A voter V accepts only if it sees no agent of F alive and is not frozen for
   another round that outranks this one (:func:`outranks`: a lower coordinator id, or the
   same coordinator's newer round, takes a freeze over, so that when several coordinators
   compete the lowest one's round gets through instead of each freezing the others' voters
   for ever). It journals :class:`~agent.protocol.records.FenceRec` (durable before the
   vote: from then on V refuses every request of F for good and leaves its trades with F
   as they are), *freezes* (no trade step changes its ledger until released, see
   :attr:`~agent.protocol.machine.TradeMachine.frozen`) and answers
   :class:`~agent.wire.peer.FenceVote` with its ledger (owned and held landmarks) and what it
   holds for trades with fenced agents.
3. **Adoption.** With a vote from every voter, and the voters a strict majority of the team
   (the scenario's agents), C decides (:func:`decide_round`): a landmark a voter
   holds for a trade with a fenced agent (*contested*) stays with it unless another voter
   claims it (the fenced agent moved it on before it was fenced everywhere); every landmark
   in no ledger and not kept is an orphan and goes to the voter that sees it best
   (:func:`assign_orphans`). Each voter gets an :class:`~agent.wire.peer.AdoptOrder`; one
   still frozen for that round journals :class:`~agent.protocol.records.AdoptRec` (its trades
   with fenced agents end, contested landmarks kept or dropped, orphans adopted) and
   unfreezes; one whose freeze expired does nothing (a later round finishes its part).

Why no landmark ends with two owners or none:

* Trades between voters never take a landmark out of the union of their ledgers (a landmark
  in flight is held by its giver until its receiver owns it). A frozen voter's ledger does not
  change, and all voters were frozen at once (each was frozen from its vote until it adopted,
  and C orders adoption only after the last vote), so the union of the votes is the union of
  the voters' ledgers at that instant: exactly the landmarks not held only by F.
* Nobody else can gain an orphan meanwhile: every voter refuses F for good, and a second
  round needs the same voters frozen for it (rounds are serialised by the freeze). A voter
  taken over by another round adopts nothing for the first (an order is taken only while
  frozen for its round since the vote), and a round decides only once every voter voted for
  it, so once any round adopts, every earlier round it took voters from can adopt nothing.
* Before every agent refuses F, F may still trade with some of them. What F gives away
  arrives in a voter's ledger (not an orphan); what a voter holds for a trade with F is kept
  only if nobody else claims it, else F had committed and moved it on. F's own ledger is void
  from the first vote on: F learns it is fenced from the first voter it meets.
* Under a partition only a majority side can fence: two sides cannot both adopt. The fenced
  agent's own claims are void (the observer ignores them); when it comes back it learns the
  fence from a peer's state or a :class:`~agent.wire.peer.Fenced` reply and journals
  :class:`~agent.protocol.records.FencedRec`, dropping its ledger.

With two agents no side is a majority: nothing is adopted (safe, not live), and the mission
reports the orphans.

A proven fence is never lifted. An agent that hears of one from a peer's state refuses the
fenced agent too (refusing is always safe, and the next round finds every voter agreeing); the
fenced agent, once it hears of it, drops its ledger and leaves, even when the round that
fenced it did not complete (a round may have completed at some voters and not at others, so
a voter cannot tell that nobody adopted). Its landmarks are then orphans until a round with
a majority adopts them.

A fence is heard of only with its proof (:mod:`agent.protocol.fence_proof`): the ballots of
a strict majority of the team, each naming the round and the fenced agents (signed by its
voter on the secured profile). Each ballot goes with a vote, so a proof exists only once a
majority journaled the fence and refuses the fenced agents for good; the coordinator
assembles it as soon as it holds a majority of votes (even if the round is given up later)
and hands it on with its :class:`~agent.wire.peer.AdoptOrder`; agents publish the proofs they
accepted. A fence claim without a valid proof is ignored: nobody refuses the agent it names,
and the agent never drops its ledger for it. This keeps the argument above: what is adopted
in a round is only ever held by agents in its F (every other agent votes with its ledger), a
completed round's voters are a majority, so a proof of it exists whenever its adoption can
have happened; an agent that only one peer (or any minority) calls fenced has lost nothing to
adoption, and keeping its ledger is what keeps its landmarks owned. A voter that voted in a
round that never reached a majority refuses the agents it named (its own journaled fence, as
before), but publishes no fence it cannot prove; those agents learn nothing from it.

**Abandoned rounds.** Such a fence would otherwise stay for good: the voter would refuse the
agent it named after it came back, refuse every later round naming it ("alive"), and make
every round that does not name it fail on its vote, so that a later loss could never be
fenced and the mission would never complete. So a fence a voter took only by
voting (:attr:`~agent.protocol.machine.TradeMachine.vote_fences`: no proof, no adoption) is
lifted once *every* round it voted it in is abandoned (:class:`~agent.protocol.records.
UnfenceRec`, :meth:`FenceVoter.abandon`), and the voter votes in those rounds no more:

* The coordinator C gives round R up without a proof (fewer than a majority of votes, a
  joiner it did not count, a ballot that does not check): it lifts its own vote's fences and
  releases the voters. A voter holding a fence from R asks C where R stands
  (:class:`~agent.wire.peer.RoundQuery`): ``running``, ``proven`` (the proof comes with the
  answer: the fence holds, the voter keeps the proof) or ``abandoned`` (lift).
* Why ``abandoned`` is safe: C answers it only when R is not running and C holds no proof
  of R. A round runs in C's memory only and is never resumed (after a restart C starts new
  rounds with higher epochs), and C orders no adoption before R's proof is journaled. So no
  landmark was or will be adopted in R: the fenced agent's ledger is whole, and trading with
  it again cannot make a landmark with two owners. A fence from another round still in
  progress stays (it is that round's too), and a proof or an adoption makes a fence
  permanent.
* If C never comes back, its abandoned rounds' fences stay (safe, not live); a voter does not
  guess, as a proof of R may exist at C only.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from agent.core.vision import DistanceTerm, Landmarks, per_landmark_cols
from agent.protocol.fence_proof import VoteSigner
from agent.protocol.machine import Step, TradeMachine
from agent.protocol.records import AdoptRec, FencedRec, FenceRec, UnfenceRec
from agent.wire.peer import (
    AdoptAck,
    AdoptOrder,
    FenceProposal,
    FenceVote,
    LmSet,
    Refused,
    pack_arrays,
    unpack,
)

IntArray = NDArray[np.int64]
Vec3 = tuple[float, float, float]
RoundId = tuple[int, str]  #: (epoch, coordinator)
#: Why a voter refuses a proposal: the Refused reason, and the step's outcome (an
#: :data:`~agent.protocol.machine.Outcome`).
VoteRefusal = Literal["fenced", "voter_alive", "alive", "finished", "frozen"]


def voters_of(team: Iterable[str], fenced: Iterable[str], lost: Iterable[str]) -> list[str]:
    """The agents that must vote to fence ``lost``: the team minus every fenced agent."""
    out = set(fenced) | set(lost)
    return sorted(a for a in team if a not in out)


def has_quorum(team: Sequence[str], fenced: Iterable[str], lost: Iterable[str]) -> bool:
    """The voters among ``team`` (the scenario's agents; joiners vote but are not counted)
    are a strict majority of it (two sides of a partition cannot both have one; fenced agents
    still count, so losing half the team stops adoption)."""
    return 2 * len(voters_of(team, fenced, lost)) > len(team)


@dataclass
class RoundDecision:
    """What a fence round decides: orphans (ids ascending) and, per voter (index in the
    votes), the contested landmarks it must let go."""

    orphans: IntArray
    drop: list[IntArray]


def decide_round(universe: IntArray, ledgers: Sequence[IntArray],
                 contested: Sequence[tuple[IntArray, IntArray]]) -> RoundDecision:
    """Contested landmarks stay with a voter unless another voter claims the landmark in its
    ledger or contests it at a higher version; orphans are the landmarks nobody keeps."""
    claimed = np.unique(np.concatenate([np.asarray(x, np.int64) for x in ledgers])) \
        if ledgers else np.zeros(0, dtype=np.int64)
    all_ids = [c[0] for c in contested] + [np.zeros(0, np.int64)]
    all_vers = [c[1] for c in contested] + [np.zeros(0, np.int64)]
    ids_cat, vers_cat = np.concatenate(all_ids), np.concatenate(all_vers)
    drops, kept = [], [claimed]
    for ids, vers in contested:
        newer = np.zeros(ids.size, dtype=bool)
        if ids.size and ids_cat.size:  # another contested claim at a higher version
            same = ids[:, None] == ids_cat[None, :]
            newer = (same & (vers_cat[None, :] > vers[:, None])).any(axis=1)
        lose = np.isin(ids, claimed) | newer
        drops.append(ids[lose])
        kept.append(ids[~lose])
    return RoundDecision(orphan_ids(universe, kept), drops)


def orphan_ids(universe: IntArray, ledgers: Iterable[IntArray]) -> IntArray:
    """Mission landmarks in none of the voters' ledgers (ids ascending)."""
    parts = [np.asarray(x, dtype=np.int64) for x in ledgers]
    claimed = np.concatenate(parts) if parts else np.zeros(0, dtype=np.int64)
    return np.setdiff1d(np.asarray(universe, dtype=np.int64), claimed)


def adoption_versions(orphans: IntArray, known: Iterable[tuple[IntArray, IntArray]]) -> IntArray:
    """Version to adopt each orphan at: one above the highest version known for it (from the
    lost agents' last states; 1 when none is known)."""
    out = np.zeros(orphans.size, dtype=np.int64)
    for ids, vers in known:
        if ids.size == 0 or orphans.size == 0:
            continue
        pos = np.minimum(np.searchsorted(orphans, ids), orphans.size - 1)
        hit = orphans[pos] == ids
        np.maximum.at(out, pos[hit], vers[hit])
    return out + 1


def assign_orphans(lm: Landmarks, poses: Sequence[tuple[Vec3, Vec3]],
                   term: DistanceTerm) -> NDArray[np.intp]:
    """Index of the voter each landmark of ``lm`` goes to: the best vision (eq. 3.1) from the
    voters' poses (position [m; world ENU], unit camera direction); a landmark nobody sees
    goes to the nearest voter."""
    n, m = len(poses), lm.m
    if m == 0 or n == 0:
        return np.zeros(m, dtype=np.intp)
    vis = np.empty((n, m))
    dist = np.empty((n, m))
    for k, (p, v) in enumerate(poses):  # loop over voters; vectorised over landmarks
        pa, va = np.asarray(p, dtype=np.float64), np.asarray(v, dtype=np.float64)
        vis[k] = per_landmark_cols(pa, va, lm, term)
        dist[k] = np.linalg.norm(lm.qT - pa[:, None], axis=0)
    best: NDArray[np.intp] = np.argmax(vis, axis=0).astype(np.intp)
    unseen = vis.max(axis=0) <= 0.0
    best[unseen] = np.argmin(dist[:, unseen], axis=0)
    return best


@dataclass
class Freeze:
    """This voter is frozen for round ``rid`` until mission time ``until`` [s]."""

    rid: RoundId
    until: float


def outranks(new: RoundId, old: RoundId) -> bool:
    """Whether round ``new`` (epoch, coordinator) takes over a voter frozen for ``old``: a
    lower coordinator id (the one that coordinates when all are live), or the same
    coordinator's newer round (it gave the old one up)."""
    return new[1] < old[1] or (new[1] == old[1] and new[0] > old[0])


class FenceVoter:
    """The voter's side of fence rounds for one agent's :class:`TradeMachine` (see the module
    docstring). Call under the agent's lock; journal each returned step's records before
    sending its message."""

    def __init__(self, machine: TradeMachine, sign: VoteSigner | None = None) -> None:
        self.m = machine
        self.sign = sign  #: signs our ballots (None: the open profile, unsigned)
        self.freeze: Freeze | None = None
        self.answered: dict[RoundId, bool] = {}  #: adoption answers given, per round

    def expire(self, now: float) -> None:
        """End a freeze whose time ran out (mission time ``now`` [s])."""
        if self.freeze is not None and now >= self.freeze.until:
            self.release()

    def release(self) -> None:
        """Unfreeze (round over, or given up)."""
        self.freeze = None
        self.m.frozen = False

    def on_proposal(self, prop: FenceProposal, live: set[str], p: Vec3, v: Vec3, now: float,
                    hold_s: float) -> Step:
        """Vote on ``prop`` from our pose (p [m; world ENU], v unit) at mission time ``now``
        [s], seeing ``live`` agents alive; a vote freezes us for ``hold_s`` [s]."""
        m, step = self.m, Step()
        rid = (prop.epoch, prop.sender)
        self.expire(now)
        reason: VoteRefusal | None = None
        if m.fenced_out is not None or prop.sender in m.fenced:
            reason = "fenced"
        elif m.me in prop.fenced:
            reason = "voter_alive"
        elif set(prop.fenced) & live:
            reason = "alive"
        elif rid in self.answered or rid in m.abandoned:
            reason = "finished"
        elif self.freeze is not None and self.freeze.rid != rid and \
                not outranks(rid, self.freeze.rid):
            reason = "frozen"
        if reason is not None:
            step.message = Refused(sender=m.me, trade_id="", reason=reason)
            step.outcome = reason
            return step
        new = sorted(set(prop.fenced) - m.permanent_fences())  # this round is their source
        if new:
            rec = FenceRec(epoch=prop.epoch, coordinator=prop.sender, fenced=new)
            m.apply(rec)
            step.records.append(rec)
        m.fence_epoch = max(m.fence_epoch, prop.epoch)
        if self.freeze is None or self.freeze.rid != rid:  # a new freeze, or one taken over
            self.freeze = Freeze(rid, now + hold_s)
        m.frozen = True
        sig = b"" if self.sign is None else \
            self.sign(prop.epoch, prop.sender, sorted(set(prop.fenced)))
        step.message = FenceVote(sender=m.me, epoch=prop.epoch,
                                 ledger=pack_arrays(*m.ledger_arrays()),
                                 contested=pack_arrays(*m.contested_arrays()), p=p, v=v,
                                 fenced=sorted(m.fenced), members=sorted(m.members - {m.me}),
                                 sig=sig)
        step.outcome = "voted"
        return step

    def on_adopt(self, order: AdoptOrder, now: float) -> Step:
        """Adopt ``order``'s orphans if still frozen for its round, then unfreeze."""
        m, step = self.m, Step()
        rid = (order.epoch, order.sender)
        self.expire(now)
        if rid in self.answered:
            step.message = AdoptAck(sender=m.me, epoch=order.epoch, ok=self.answered[rid])
            step.outcome = "repeat"
            return step
        arrays, drop = unpack(order.owned), unpack(order.drop)
        ok = self.freeze is not None and self.freeze.rid == rid and arrays is not None \
            and drop is not None and m.knows(arrays[0]) and set(order.fenced) <= m.fenced
        if ok and arrays is not None and drop is not None:
            if np.intersect1d(m.ledger_arrays()[0], arrays[0]).size or \
                    np.setdiff1d(drop[0], m.contested_arrays()[0]).size:
                ok = False  # not orphans, or not ours to drop: refuse the order
            else:
                rec = AdoptRec(epoch=order.epoch, coordinator=order.sender,
                               fenced=sorted(order.fenced), owned=order.owned, drop=order.drop)
                m.apply(rec)
                step.records.append(rec)
        if self.freeze is not None and self.freeze.rid == rid:
            self.release()
        self.answered[rid] = ok
        step.message = AdoptAck(sender=m.me, epoch=order.epoch, ok=ok)
        step.outcome = "adopted" if ok else "expired"
        return step

    def abandon(self, rid: RoundId) -> Step:
        """Round ``rid`` ended without a proof (its coordinator says so, or we coordinated
        it): lift the fences we took only by voting in it, vote in it no more, and unfreeze
        if frozen for it. Journal the step's records before trading with an agent it lifts."""
        m, step = self.m, Step()
        if rid not in m.abandoned:
            rec = UnfenceRec(epoch=rid[0], coordinator=rid[1])
            m.apply(rec)
            step.records.append(rec)
            step.outcome = "unfenced"
        if self.freeze is not None and self.freeze.rid == rid:
            self.release()
        return step

    def learn_fenced(self, epoch: int, by: str) -> Step:
        """A peer says the team fenced us out in round ``epoch``: drop the ledger (once)."""
        step = Step()
        if self.m.fenced_out is None:
            rec = FencedRec(epoch=epoch, by=by)
            self.m.apply(rec)
            step.records.append(rec)
            step.outcome = "fenced_out"
        self.release()
        return step


def empty_set() -> LmSet:
    """An empty landmark set."""
    return pack_arrays(np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64))
