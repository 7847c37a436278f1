"""The trade protocol as a pure state machine (no I/O, no clock, no threads).

(Over 400 lines, not split: every handler reads and writes the same ledger, and a reader
checks a transition against the others in one place; the records are in
:mod:`agent.protocol.records`.)

One :class:`TradeMachine` per agent. Every durable change of state is a journal *record*
(a tagged ``msgspec.Struct`` below); the machine changes its state only through
:meth:`TradeMachine.apply`, so replaying the journal rebuilds exactly the state the agent had.
Handlers return the records they produced together with the message to send; the caller must
write (and ``fsync``) the records *before* sending that message.

Ledger: for every landmark of the mission (dense arrays indexed by the landmark's rank among
the sorted mission ids) the version we own it at (or -1) and the version and trade we hold it
for (given away in a pending transfer, not counted for coverage; or -1). A transfer moves a
landmark from version n at its old owner to n + 1 at its new owner. Every ledger operation of a
trade is a handful of numpy index operations: no Python loop over landmarks.

Journal records are in :mod:`agent.protocol.records`; the wire messages in
:mod:`agent.wire.peer`; the decision of what to trade (Algorithm 7) in :mod:`agent.core.trading`.

Exchange (initiator I = coordinator, responder R = participant; thesis section 4.5 and
Algorithm 7 made fault tolerant, a two-phase commit in which R's vote is the trade itself):

1. I records :class:`OfferRec` and queries R with :class:`~agent.wire.peer.Offer`.
2. R answers ``Busy`` / ``NoTrade`` / ``Refused`` (nothing changes), or records
   :class:`PreparedRec` (its ``r_to_i`` become held) and answers ``Accept``. A repeated Offer
   gets the remembered answer; an offer older than the newest seen from that initiator is
   refused as stale.
3. I on Accept records :class:`CommitRec` (owns ``r_to_i`` at version + 1, ``i_to_r`` become
   held) then sends ``Commit`` until acknowledged; without an Accept after its retries it
   records :class:`AbortRec` and ignores late Accepts.
4. R on Commit records :class:`CommittedRec` (owns ``i_to_r`` at version + 1, drops held
   ``r_to_i``) and answers ``CommitAck`` (idempotent). R in doubt asks I with
   ``StatusQuery``; I answers committed / aborted / pending (an unknown id is aborted: I
   never commits without a journal record). On aborted R records :class:`RestoredRec`.
5. I on CommitAck records :class:`DoneRec` (drops held ``i_to_r``).

Because I commits only after R prepared, and R commits only after I committed (R learns it
from Commit or from a Decision), a landmark is at every instant owned by one agent or held by
one agent at a lower version than its new owner's: (landmark, version) pairs are created once.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from agent.protocol.records import (
    AbortRec,
    AdoptRec,
    CaptureRec,
    CommitRec,
    CommittedRec,
    DoneRec,
    FencedRec,
    FenceRec,
    GenesisRec,
    JournalMismatch,
    MemberRec,
    OfferRec,
    PoseRec,
    PreparedRec,
    Rec,
    RestoredRec,
    StageRec,
    StartRec,
    UnfenceRec,
    Vec3,
)
from agent.wire.peer import (
    MAX_RECENT_TRADES,
    MAX_VERSION,
    Accept,
    Busy,
    Commit,
    CommitAck,
    Decision,
    FenceProof,
    LmSet,
    NoTrade,
    Offer,
    Refused,
    Regroup,
    Reply,
    Request,
    StatusQuery,
    TradeTerms,
    make_trade_id,
    pack_arrays,
    parse_trade_id,
    unpack,
    unpack_trusted,
)

IntArray = NDArray[np.int64]
Mask = NDArray[np.bool_]

#: ``decide(p_i, v_i, ids_i, p_r, v_r, ids_r) -> (i_to_r mask over ids_i, r_to_i over ids_r)``:
#: Algorithm 7 evaluated by the responder (positions [m], unit directions, landmark ids).
DecideFn = Callable[[Vec3, Vec3, IntArray, Vec3, Vec3, IntArray], tuple[Mask, Mask]]

_NONE = -1  #: "not owned" / "not held" in the dense ledger arrays


# -- machine ---------------------------------------------------------------------------------

_EMPTY = LmSet()


@dataclass
class InitTrade:
    """An initiated trade not finished yet: ``state`` offered (waiting for an answer) or
    committed (waiting for CommitAck)."""

    partner: str
    state: Literal["offered", "committed"]
    i_to_r: LmSet = _EMPTY
    r_to_i: LmSet = _EMPTY


@dataclass
class PrepTrade:
    """A prepared (in doubt) trade on the responder side."""

    partner: str
    i_to_r: LmSet
    r_to_i: LmSet


OfferOutcome = Literal["commit", "drop", "drop_both", "retry_later", "ignored"]

#: What a handler's :class:`Step` did, for the runtime to act on (and count). Every value a
#: handler sets (here, in :mod:`agent.protocol.fencing` and :mod:`agent.runtime.ends.joining`);
#: a misspelt comparison is a type error (mypy's ``strict_equality``).
Outcome = Literal[
    "",  # nothing to act on: the message, if any, is the whole answer
    # initiator (new_offer, abort_offer, on_offer_reply, on_commit_reply)
    "offered",  # OfferRec journaled: send the Offer
    "aborted",  # our offer given up (AbortRec); R: a Commit of a trade it restored, refused
    "commit",  # R accepted: CommitRec journaled, send the Commit
    "drop",  # R refused, is optimising or sent an unacceptable Accept: offer aborted, drop R
    "drop_both",  # R answered NoTrade: offer aborted, neither of the two offers the other
    "retry_later",  # R is busy trading: offer aborted, offer again after a back-off
    "ignored",  # a reply to no pending request of ours (stale, unknown, late or frozen)
    "done",  # CommitAck: DoneRec journaled, the trade is finished on our side
    # responder (on_offer, on_commit, on_decision)
    "invalid",  # an Offer with a bad trade id or landmark set: refused
    "repeat",  # an Offer, Commit or AdoptOrder answered before: the same answer again
    "stale",  # an Offer older than its initiator's newest, or of a finished trade: refused
    "busy",  # an Offer while optimising, trading, in doubt or frozen: Busy
    "conflict",  # an Offer claiming landmarks we own or hold as new: refused
    "no_trade",  # Algorithm 7 moves nothing: NoTrade
    "prepared",  # PreparedRec journaled: Accept (our vote) sent
    "frozen",  # a Commit while frozen for a fence round (Busy), or a proposal then (refused)
    "committed",  # CommittedRec journaled (on Commit or a committed Decision): trade done
    "unknown",  # a Commit of a trade we never prepared: refused
    "restored",  # an aborted Decision: RestoredRec journaled, held landmarks ours again
    "pending",  # the initiator has not decided yet: ask again later
    # fence voter (agent.protocol.fencing.FenceVoter): refusals of a proposal, then the rest
    "fenced",  # we are fenced out, or the proposer is: refused
    "voter_alive",  # the proposal fences us: refused
    "alive",  # we see an agent it would fence alive: refused
    "finished",  # we already answered the adoption of this round, or it was abandoned
    "voted",  # FenceRec journaled (if new), frozen: send the FenceVote
    "adopted",  # AdoptRec journaled: orphans adopted, unfrozen
    "expired",  # an AdoptOrder we may not carry out (freeze over, not orphans): ok=False
    "fenced_out",  # a peer says we are fenced: FencedRec journaled, our ledger dropped
    "unfenced",  # a round ended without a proof: UnfenceRec journaled, its vote fences lifted
    # joiners (agent.runtime.ends.joining)
    "admitted",  # a joiner admitted (MemberRec if new): send the JoinAck
]


@dataclass
class Step:
    """What a handler produced: ``records`` to journal (durable ones fsynced) before sending
    ``message``; ``outcome`` tells the runtime what happened (:data:`Outcome`)."""

    records: list[Rec] = field(default_factory=list)
    message: Request | Reply | None = None
    outcome: Outcome = ""
    trade_id: str | None = None  #: the new trade's id (:meth:`TradeMachine.new_offer`)

    def request(self) -> Request:
        """The message, a request to send (the step of :meth:`TradeMachine.new_offer`);
        TypeError if the step has none."""
        if not isinstance(self.message, Request):
            raise TypeError(f"step {self.outcome!r} has no request: {self.message!r}")
        return self.message

    def reply(self) -> Reply:
        """The message, a reply to send (the step of a handler answering a request);
        TypeError if the step has none."""
        if not isinstance(self.message, Reply):
            raise TypeError(f"step {self.outcome!r} has no reply: {self.message!r}")
        return self.message


class TradeMachine:
    """Ownership ledger and trade protocol of agent ``me``.

    Args:
        me: this agent's id.
        known_ids: every landmark id of the mission (sorted or not).
    """

    def __init__(self, me: str, known_ids: IntArray | list[int]) -> None:
        self.me = me
        self.known = np.unique(np.asarray(known_ids, dtype=np.int64))
        n = self.known.size
        self._own = np.full(n, _NONE, dtype=np.int64)  #: owned version per rank, or -1
        self._held = np.full(n, _NONE, dtype=np.int64)  #: held version per rank, or -1
        self._held_by = np.full(n, _NONE, dtype=np.int64)  #: trade index of a held rank
        self._tids: list[str] = []
        self._tid_index: dict[str, int] = {}
        self.incarnation = 0
        self.counter = 0
        self.genesis = False
        self.initiated: dict[str, InitTrade] = {}
        self.decided: dict[str, str] = {}  # my initiated trade ids -> committed/aborted
        self.prepared: dict[str, PrepTrade] = {}
        self.r_committed: set[str] = set()
        self.r_restored: set[str] = set()
        self.trades_with: dict[str, int] = {}
        self.ok = 0
        #: the terms of our newest committed trades, from the records that committed them
        #: (rebuilt by replay): what our state reports, so that both sides' trade events agree
        self.recent: deque[TradeTerms] = deque(maxlen=MAX_RECENT_TRADES)
        self.failed = 0
        self.last_pose: PoseRec | None = None
        self.stage1: StageRec | None = None  #: the thesis stage's end, for the revert
        self.captured: list[int] = []  #: landmarks this agent captured (inspection missions)
        #: agents the team fenced out (lost; :mod:`agent.protocol.fencing`) and the newest
        #: fence round known
        self.fenced: set[str] = set()
        self.fence_epoch = 0
        self.fenced_out: FencedRec | None = None  #: set once we learn we were fenced out
        self.fence_proofs: list[FenceProof] = []  #: proofs journaled with FenceRec
        #: fenced agents we refuse only because we voted to fence them, with the rounds
        #: (epoch, coordinator) we voted in; a proof or an adoption makes a fence permanent,
        #: an abandoned round (UnfenceRec) lifts what only it fenced
        self.vote_fences: dict[str, set[tuple[int, str]]] = {}
        self.abandoned: set[tuple[int, str]] = set()  #: rounds ended without a proof
        self.adopted = 0  #: landmarks adopted from lost agents
        self.start_walls: list[float] = []  #: Unix times [s] of every start (StartRec)
        #: drones not in the scenario admitted to the team (a joiner: itself once admitted)
        self.members: set[str] = set()
        #: Not durable: frozen for a fence round (no ledger change by a trade until released).
        self.frozen = False
        # Not durable: newest offer seen per initiator and the answer given.
        self._last_offer: dict[str, tuple[tuple[int, int], str, Reply]] = {}

    # -- ledger views --------------------------------------------------------------------
    def owned_arrays(self) -> tuple[IntArray, IntArray]:
        """(landmark ids, versions) we own, ids ascending."""
        ranks = np.flatnonzero(self._own >= 0)
        return self.known[ranks], self._own[ranks]

    def held_arrays(self) -> tuple[IntArray, IntArray]:
        """(landmark ids, versions) we hold for pending transfers, ids ascending."""
        ranks = np.flatnonzero(self._held >= 0)
        return self.known[ranks], self._held[ranks]

    def ledger_arrays(self) -> tuple[IntArray, IntArray]:
        """(landmark ids, versions) we own or hold (not for a fenced agent), ids ascending:
        what a fence vote reports."""
        held = np.where(np.isin(self._held_by, self._fenced_trades()), _NONE, self._held)
        vers = np.maximum(self._own, held)
        ranks = np.flatnonzero(vers >= 0)
        return self.known[ranks], vers[ranks]

    @property
    def owned(self) -> dict[int, int]:
        """``{landmark id: version}`` we own (a copy; for inspection and tests)."""
        ids, vers = self.owned_arrays()
        return dict(zip(ids.tolist(), vers.tolist(), strict=True))

    @property
    def held(self) -> dict[int, tuple[int, str]]:
        """``{landmark id: (version, trade id)}`` we hold (a copy; for inspection and tests)."""
        ranks = np.flatnonzero(self._held >= 0)
        tids = [self._tids[t] for t in self._held_by[ranks].tolist()]
        return dict(zip(self.known[ranks].tolist(),
                        zip(self._held[ranks].tolist(), tids, strict=True), strict=True))

    def _ranks(self, ids: IntArray) -> NDArray[np.intp] | None:
        """Ranks of landmark ids ``ids`` in the mission, or None if any id is unknown."""
        if ids.size == 0:
            return np.zeros(0, dtype=np.intp)
        if self.known.size == 0:
            return None
        pos = np.minimum(np.searchsorted(self.known, ids), self.known.size - 1)
        return pos if bool((self.known[pos] == ids).all()) else None

    def knows(self, ids: IntArray) -> bool:
        """All ``ids`` are landmark ids of the mission."""
        return self._ranks(ids) is not None

    def _record_set(self, s: LmSet) -> tuple[NDArray[np.intp], IntArray]:
        """Ranks and versions of a journal record's landmark set."""
        ids, vers = unpack_trusted(s)
        ranks = self._ranks(ids)
        if ranks is None:
            raise JournalMismatch(
                f"agent {self.me}: the journal names landmark ids that are not in this "
                "mission's scenario; use the scenario the journal was written with, or a "
                "fresh --state-dir"
            )
        return ranks, vers

    def _tid(self, trade_id: str) -> int:
        t = self._tid_index.get(trade_id)
        if t is None:
            t = self._tid_index[trade_id] = len(self._tids)
            self._tids.append(trade_id)
        return t

    # -- state ---------------------------------------------------------------------------
    def apply(self, rec: Rec) -> None:
        """Apply one record (the only way durable state changes; replay calls it too)."""
        if isinstance(rec, GenesisRec):
            ranks, vers = self._record_set(rec.owned)
            self._own.fill(_NONE)
            self._own[ranks] = vers
            self.genesis = True
        elif isinstance(rec, StartRec):
            self.incarnation = max(self.incarnation, rec.incarnation)
            self.start_walls.append(rec.wall)
        elif isinstance(rec, PoseRec):
            self.last_pose = rec
        elif isinstance(rec, StageRec):
            self.stage1 = rec
        elif isinstance(rec, CaptureRec):
            self.captured.extend(rec.ids)
        elif isinstance(rec, OfferRec):
            parsed = parse_trade_id(rec.trade_id)
            if parsed is not None:
                self.counter = max(self.counter, parsed[2])
            self.initiated[rec.trade_id] = InitTrade(rec.partner, "offered")
        elif isinstance(rec, CommitRec):
            self._give(rec.i_to_r, rec.trade_id)
            self._take_all(rec.r_to_i)
            self.initiated[rec.trade_id] = InitTrade(rec.partner, "committed", rec.i_to_r,
                                                     rec.r_to_i)
            self.decided[rec.trade_id] = "committed"
            self._count_trade(rec.trade_id, rec.partner, "initiator", rec.r_to_i, rec.i_to_r)
        elif isinstance(rec, AbortRec):
            self.initiated.pop(rec.trade_id, None)
            self.decided[rec.trade_id] = "aborted"
            self.failed += 1
        elif isinstance(rec, DoneRec):
            tr = self.initiated.pop(rec.trade_id, None)
            if tr is not None:
                self._drop_held(tr.i_to_r, rec.trade_id, restore=False)
        elif isinstance(rec, PreparedRec):
            self._give(rec.r_to_i, rec.trade_id)
            self.prepared[rec.trade_id] = PrepTrade(rec.partner, rec.i_to_r, rec.r_to_i)
        elif isinstance(rec, CommittedRec):
            pt = self.prepared.pop(rec.trade_id, None)
            if pt is not None:
                self._drop_held(pt.r_to_i, rec.trade_id, restore=False)
                self._take_all(pt.i_to_r)
                self._count_trade(rec.trade_id, pt.partner, "responder", pt.i_to_r, pt.r_to_i)
            self.r_committed.add(rec.trade_id)
        elif isinstance(rec, RestoredRec):
            pt = self.prepared.pop(rec.trade_id, None)
            if pt is not None:
                self._drop_held(pt.r_to_i, rec.trade_id, restore=True)
                self.failed += 1
            self.r_restored.add(rec.trade_id)
        elif isinstance(rec, FenceRec):
            new = set(rec.fenced) - {self.me}
            if rec.proof is None:  # our vote: lifted if every round it came from is abandoned
                for aid in new - self.permanent_fences():
                    self.vote_fences.setdefault(aid, set()).add((rec.epoch, rec.coordinator))
            self.fenced |= new
            self.fence_epoch = max(self.fence_epoch, rec.epoch)
            if rec.proof is not None:
                self.fence_proofs.append(rec.proof)
                self._make_permanent(rec.proof.fenced)
        elif isinstance(rec, UnfenceRec):
            rid = (rec.epoch, rec.coordinator)
            self.abandoned.add(rid)
            for aid, rounds in list(self.vote_fences.items()):
                rounds.discard(rid)
                if not rounds:
                    del self.vote_fences[aid]
                    self.fenced.discard(aid)
        elif isinstance(rec, AdoptRec):
            self._make_permanent(rec.fenced)
            self._resolve_fenced(set(rec.fenced) - {self.me}, rec.drop)
            ranks, vers = self._record_set(rec.owned)
            self._own[ranks] = vers
            self._held[ranks] = _NONE
            self._held_by[ranks] = _NONE
            self.adopted += int(ranks.size)
            self.fence_epoch = max(self.fence_epoch, rec.epoch)
        elif isinstance(rec, MemberRec):
            self.members.add(rec.agent)
        elif isinstance(rec, FencedRec):
            self._own.fill(_NONE)
            self._held.fill(_NONE)
            self._held_by.fill(_NONE)
            self.initiated.clear()
            self.prepared.clear()
            self.fenced_out = rec
            self.fence_epoch = max(self.fence_epoch, rec.epoch)
        else:  # pragma: no cover - exhaustive over Record
            raise TypeError(f"unknown record {rec!r}")

    def _count_trade(self, trade_id: str, partner: str, role: Literal["initiator", "responder"],
                     gained: LmSet, given: LmSet) -> None:
        """A trade committed on our side (``gained``/``given``: the terms of the record that
        prepared or committed it): count it and keep its terms for our state."""
        n = self.trades_with[partner] = self.trades_with.get(partner, 0) + 1
        self.ok += 1
        self.recent.append(TradeTerms(n=self.ok, trade_id=trade_id, partner=partner, role=role,
                                      count=n, gained=gained, given=given))

    def _make_permanent(self, fenced: list[str]) -> None:
        """A proof or an adoption fences ``fenced``: no abandoned round lifts them."""
        for aid in fenced:
            self.vote_fences.pop(aid, None)

    def permanent_fences(self) -> set[str]:
        """Fenced agents a proof or an adoption fences: never lifted."""
        return self.fenced - set(self.vote_fences)

    def unproven_rounds(self) -> set[tuple[int, str]]:
        """The rounds (epoch, coordinator) our fences without a proof come from."""
        return set().union(*self.vote_fences.values()) if self.vote_fences else set()

    def _resolve_fenced(self, lost: set[str], drop: LmSet) -> None:
        """End every trade with a fenced agent: our offers are aborted, what we hold for it is
        ours again at the held version, except ``drop`` (found newer elsewhere: let go)."""
        self.fenced |= lost
        dropped = self._record_set(drop)[0]
        self._held[dropped] = _NONE
        self._held_by[dropped] = _NONE
        for tid, tr in list(self.initiated.items()):
            if tr.partner not in lost:
                continue
            if tr.state == "committed":
                self._drop_held(tr.i_to_r, tid, restore=True)
            else:
                self.decided[tid] = "aborted"
                self.failed += 1
            del self.initiated[tid]
        for tid, pt in list(self.prepared.items()):
            if pt.partner in lost:
                self._drop_held(pt.r_to_i, tid, restore=True)
                del self.prepared[tid]
                self.r_restored.add(tid)
                self.failed += 1

    def _fenced_trades(self) -> list[int]:
        """Indices of our pending trades whose partner is fenced out."""
        tids = [t for t, tr in self.initiated.items() if tr.partner in self.fenced]
        tids += [t for t, pt in self.prepared.items() if pt.partner in self.fenced]
        return [self._tid_index[t] for t in tids if t in self._tid_index]

    def contested_arrays(self) -> tuple[IntArray, IntArray]:
        """(ids, versions) we hold for trades with fenced agents: they may have moved on from
        the fenced agent, so a fence round decides whether we keep them."""
        held = (self._held >= 0) & np.isin(self._held_by, self._fenced_trades())
        ranks = np.flatnonzero(held)
        return self.known[ranks], self._held[ranks]

    def _give(self, s: LmSet, trade_id: str) -> None:
        """``s`` leaves the owned set and becomes held for ``trade_id`` at the same versions."""
        ranks, vers = self._record_set(s)
        self._own[ranks] = _NONE
        self._held[ranks] = vers
        self._held_by[ranks] = self._tid(trade_id)

    def _take_all(self, s: LmSet) -> None:
        """Own every landmark of ``s`` at its version + 1; held claims at lower versions are
        superseded."""
        ranks, vers = self._record_set(s)
        self._own[ranks] = vers + 1
        superseded = ranks[(self._held[ranks] >= 0) & (self._held[ranks] <= vers)]
        self._held[superseded] = _NONE
        self._held_by[superseded] = _NONE

    def _drop_held(self, s: LmSet, trade_id: str, restore: bool) -> None:
        """Landmarks of ``s`` still held for ``trade_id`` stop being held; with ``restore``
        they are owned again at the held version (the trade was aborted)."""
        t = self._tid_index.get(trade_id)
        if t is None:
            return
        ranks, _ = self._record_set(s)
        mine = ranks[self._held_by[ranks] == t]
        if restore:
            self._own[mine] = self._held[mine]
        self._held[mine] = _NONE
        self._held_by[mine] = _NONE

    def _do(self, step: Step, rec: Rec) -> None:
        self.apply(rec)
        step.records.append(rec)

    def recover(self, wall: float = 0.0) -> list[Rec]:
        """After replaying the journal at start-up (at Unix time ``wall`` [s]): start a new
        incarnation and abort offers that never reached a decision (their answer is lost with
        the old process). Returns the records to journal (fsync) before going on."""
        recs: list[Rec] = [StartRec(incarnation=self.incarnation + 1, wall=wall)]
        for tid, tr in list(self.initiated.items()):
            if tr.state == "offered":
                recs.append(AbortRec(trade_id=tid, partner=tr.partner, reason="restart"))
        for rec in recs:
            self.apply(rec)
        self.counter = 0 if self.counter < 0 else self.counter
        return recs

    @property
    def pending_ids(self) -> list[str]:
        """Trade ids not resolved yet (initiated or prepared)."""
        return sorted([*self.initiated, *self.prepared])

    @property
    def offering(self) -> bool:
        """True while an offer of ours waits for an answer."""
        return any(tr.state == "offered" for tr in self.initiated.values())

    @property
    def in_doubt(self) -> bool:
        """True while we are prepared for a trade whose outcome we do not know."""
        return bool(self.prepared)

    def unacked_commits(self) -> list[tuple[str, str]]:
        """(trade_id, partner) of committed trades waiting for CommitAck."""
        return [(t, tr.partner) for t, tr in self.initiated.items()
                if tr.state == "committed" and tr.partner not in self.fenced]

    def doubts(self) -> list[tuple[str, str]]:
        """(trade_id, initiator) of prepared trades in doubt."""
        return [(t, pt.partner) for t, pt in self.prepared.items()
                if pt.partner not in self.fenced]

    # -- validation helpers ----------------------------------------------------------------
    def _conflicts(self, ranks: NDArray[np.intp], vers: IntArray) -> bool:
        """True if another agent's claims (``ranks`` at ``vers``) overlap what we own, or what
        we hold at a version not lower than theirs (a held claim at a lower version is being
        superseded)."""
        return bool((self._own[ranks] >= 0).any() or (self._held[ranks] >= vers).any())

    # -- initiator -------------------------------------------------------------------------
    def new_offer(self, partner: str, p: Vec3, v: Vec3, regroup: Regroup | None = None) -> Step:
        """Start a trade with ``partner`` from pose (p [m], v unit) (never while frozen: the
        runtime does not offer then, and an Accept would be ignored); with ``regroup`` the
        transfer it proposes (R accepts it or answers NoTrade)."""
        step = Step()
        self.counter += 1
        tid = make_trade_id(self.me, self.incarnation, self.counter)
        self._do(step, OfferRec(trade_id=tid, partner=partner))
        step.message = Offer(sender=self.me, trade_id=tid, p=p, v=v,
                             owned=pack_arrays(*self.owned_arrays()), regroup=regroup)
        step.outcome = "offered"
        step.trade_id = tid
        return step

    def abort_offer(self, trade_id: str, reason: str) -> Step:
        """Give up an offer still waiting for an answer (e.g. after its retries)."""
        step = Step(outcome="aborted")
        tr = self.initiated.get(trade_id)
        if tr is not None and tr.state == "offered":
            self._do(step, AbortRec(trade_id=trade_id, partner=tr.partner, reason=reason))
        return step

    def _acceptable(self, reply: Accept) -> bool:
        """R's Accept is well formed and consistent with our ledger: ``i_to_r`` is ours at
        those versions, ``r_to_i`` are mission landmarks we neither own nor hold at a version
        as new, and something moves."""
        give, take = unpack(reply.i_to_r), unpack(reply.r_to_i)
        if give is None or take is None or give[0].size + take[0].size == 0:
            return False
        give_ranks, take_ranks = self._ranks(give[0]), self._ranks(take[0])
        return (
            give_ranks is not None and take_ranks is not None
            and bool((take[1] < MAX_VERSION).all())
            and bool((self._own[give_ranks] == give[1]).all())
            and not self._conflicts(take_ranks, take[1])
        )

    def on_offer_reply(self, trade_id: str, reply: Reply) -> Step:
        """Handle R's answer to our Offer ``trade_id``.

        Outcomes: ``commit`` (records CommitRec; message is the Commit to send), ``drop``
        (drop R), ``drop_both`` (NoTrade), ``retry_later`` (R busy trading), ``ignored``
        (stale/unknown/late answer).
        """
        step = Step(outcome="ignored")
        tr = self.initiated.get(trade_id)
        if tr is None or tr.state != "offered" or reply.sender != tr.partner or self.frozen \
                or tr.partner in self.fenced:
            return step
        if getattr(reply, "trade_id", None) != trade_id:
            return step
        if isinstance(reply, Accept):
            if not self._acceptable(reply):
                self._do(step, AbortRec(trade_id=trade_id, partner=tr.partner, reason="refused"))
                step.outcome = "drop"
                return step
            self._do(step, CommitRec(trade_id=trade_id, partner=tr.partner,
                                     i_to_r=reply.i_to_r, r_to_i=reply.r_to_i))
            step.message = Commit(sender=self.me, trade_id=trade_id)
            step.outcome = "commit"
            return step
        if isinstance(reply, Busy):
            self._do(step, AbortRec(trade_id=trade_id, partner=tr.partner, reason="busy"))
            step.outcome = "retry_later" if reply.reason == "trading" else "drop"
        elif isinstance(reply, NoTrade):
            self._do(step, AbortRec(trade_id=trade_id, partner=tr.partner, reason="no_trade"))
            step.outcome = "drop_both"
        elif isinstance(reply, Refused):
            self._do(step, AbortRec(trade_id=trade_id, partner=tr.partner, reason="refused"))
            step.outcome = "drop"
        return step

    def on_commit_reply(self, trade_id: str, reply: Reply) -> Step:
        """Handle R's answer to our Commit: CommitAck finishes the trade (outcome ``done``)."""
        step = Step(outcome="ignored")
        tr = self.initiated.get(trade_id)
        if (
            not self.frozen and tr is not None and tr.state == "committed"
            and isinstance(reply, CommitAck)
            and reply.trade_id == trade_id and reply.sender == tr.partner
        ):
            self._do(step, DoneRec(trade_id=trade_id))
            step.outcome = "done"
        return step

    def on_status_query(self, q: StatusQuery) -> Step:
        """Answer R's StatusQuery about one of our trades."""
        step = Step()
        parsed = parse_trade_id(q.trade_id)
        if parsed is None or parsed[0] != self.me:
            step.message = Refused(sender=self.me, trade_id=q.trade_id, reason="not_mine")
            return step
        tr = self.initiated.get(q.trade_id)
        if tr is not None and tr.partner != q.sender:
            step.message = Refused(sender=self.me, trade_id=q.trade_id, reason="wrong_partner")
            return step
        if tr is not None:
            status = "pending" if tr.state == "offered" else "committed"
        else:
            status = "committed" if self.decided.get(q.trade_id) == "committed" else "aborted"
        step.message = Decision(sender=self.me, trade_id=q.trade_id, status=status)  # type: ignore[arg-type]
        return step

    # -- responder -------------------------------------------------------------------------
    def on_offer(
        self, offer: Offer, p: Vec3, v: Vec3, busy: str | None, decide: DecideFn
    ) -> Step:
        """Answer an Offer with our pose (p [m], v unit). ``busy`` is None when we may trade,
        else ``"optimising"`` or ``"trading"``."""
        step = Step()
        tid = offer.trade_id
        parsed = parse_trade_id(tid)
        if parsed is None or parsed[0] != offer.sender or offer.sender == self.me:
            step.message = Refused(sender=self.me, trade_id=tid, reason="bad_trade_id")
            step.outcome = "invalid"
            return step
        order = (parsed[1], parsed[2])
        last = self._last_offer.get(offer.sender)
        if last is not None:
            if last[1] == tid:
                step.message = last[2]
                step.outcome = "repeat"
                return step
            if order < last[0]:
                step.message = Refused(sender=self.me, trade_id=tid, reason="stale")
                step.outcome = "stale"
                return step
        # After a restart the in-memory answers are gone; the journal still knows prepared
        # or finished trades, so a repeated Offer of one of those never prepares twice.
        if tid in self.prepared:
            pt = self.prepared[tid]
            step.message = Accept(sender=self.me, trade_id=tid, i_to_r=pt.i_to_r,
                                  r_to_i=pt.r_to_i)
            step.outcome = "repeat"
            return step
        if tid in self.r_committed or tid in self.r_restored:
            step.message = Refused(sender=self.me, trade_id=tid, reason="finished")
            step.outcome = "stale"
            return step
        reply: Reply
        if busy is None and (self.prepared or self.frozen):
            busy = "trading"
        arrays = None if busy is not None else unpack(offer.owned)
        ranks = None if arrays is None else self._ranks(arrays[0])
        if busy is not None:
            reply = Busy(sender=self.me, trade_id=tid, reason=busy)  # type: ignore[arg-type]
            step.outcome = "busy"
        elif arrays is None or ranks is None:
            reply = Refused(sender=self.me, trade_id=tid, reason="invalid_landmarks")
            step.outcome = "invalid"
        elif self._conflicts(ranks, arrays[1]):
            reply = Refused(sender=self.me, trade_id=tid, reason="conflict")
            step.outcome = "conflict"
        else:
            ids_i, vi = arrays
            ids_r, vr = self.owned_arrays()
            m_ir, m_ri = decide(offer.p, offer.v, ids_i, p, v, ids_r)
            if not (m_ir.any() or m_ri.any()):
                reply = NoTrade(sender=self.me, trade_id=tid)
                step.outcome = "no_trade"
            else:
                rec = PreparedRec(trade_id=tid, partner=offer.sender,
                                  i_to_r=pack_arrays(ids_i[m_ir], vi[m_ir]),
                                  r_to_i=pack_arrays(ids_r[m_ri], vr[m_ri]))
                self._do(step, rec)
                reply = Accept(sender=self.me, trade_id=tid, i_to_r=rec.i_to_r,
                               r_to_i=rec.r_to_i)
                step.outcome = "prepared"
        self._last_offer[offer.sender] = (order, tid, reply)
        step.message = reply
        return step

    def on_commit(self, c: Commit) -> Step:
        """Answer I's Commit: commit a prepared trade (idempotent)."""
        step = Step()
        pt = self.prepared.get(c.trade_id)
        if pt is not None and pt.partner == c.sender and self.frozen:
            step.message = Busy(sender=self.me, trade_id=c.trade_id, reason="trading")
            step.outcome = "frozen"
        elif pt is not None and pt.partner == c.sender:
            self._do(step, CommittedRec(trade_id=c.trade_id))
            step.message = CommitAck(sender=self.me, trade_id=c.trade_id)
            step.outcome = "committed"
        elif c.trade_id in self.r_committed:
            parsed = parse_trade_id(c.trade_id)
            if parsed is not None and parsed[0] == c.sender:
                step.message = CommitAck(sender=self.me, trade_id=c.trade_id)
                step.outcome = "repeat"
            else:
                step.message = Refused(sender=self.me, trade_id=c.trade_id, reason="wrong_sender")
        else:
            # the Refused reason is the step's outcome too
            reason: Literal["aborted", "unknown"] = \
                "aborted" if c.trade_id in self.r_restored else "unknown"
            step.message = Refused(sender=self.me, trade_id=c.trade_id, reason=reason)
            step.outcome = reason
        return step

    def on_decision(self, trade_id: str, reply: Reply) -> Step:
        """Handle I's answer to our StatusQuery about prepared ``trade_id``."""
        step = Step(outcome="ignored")
        pt = self.prepared.get(trade_id)
        if (
            pt is None or not isinstance(reply, Decision) or reply.trade_id != trade_id
            or reply.sender != pt.partner or self.frozen
        ):
            return step
        if reply.status == "committed":
            self._do(step, CommittedRec(trade_id=trade_id))
            step.outcome = "committed"
        elif reply.status == "aborted":
            self._do(step, RestoredRec(trade_id=trade_id))
            step.outcome = "restored"
        else:
            step.outcome = "pending"
        return step
