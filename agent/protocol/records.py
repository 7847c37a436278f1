"""Journal records of the trade protocol: every durable change of an agent's ledger is one
of these tagged ``msgspec.Struct`` s (msgpack, CRC-framed in :mod:`agent.storage.journal`).
:class:`~agent.protocol.machine.TradeMachine` changes its state only by applying them, so
replaying a journal rebuilds exactly the state the agent had.
"""

from __future__ import annotations

from typing import Annotated

import msgspec

from agent.errors import UsageError
from agent.wire.peer import FenceProof, LmSet

Vec3 = tuple[float, float, float]


class Rec(msgspec.Struct, tag_field="rec", kw_only=True):
    """Base of journal records. Landmark sets are packed :class:`LmSet` s (ids, versions)."""


class GenesisRec(Rec, tag="genesis"):
    """First record: the agent's initial landmarks (scenario assignment) and versions."""

    agent: str
    owned: LmSet


class StartRec(Rec, tag="start"):
    """A (re)start of the agent process with a new incarnation number, at Unix time ``wall``
    [s] (0: not recorded)."""

    incarnation: int
    wall: float = 0.0


class PoseRec(Rec, tag="pose"):
    """Last known pose (position [m], unit direction, mission time [s]); not fsynced."""

    p: Vec3
    v: Vec3
    t: float


class OfferRec(Rec, tag="offer"):
    """I: offer ``trade_id`` sent to ``partner``."""

    trade_id: str
    partner: str


class CommitRec(Rec, tag="commit"):
    """I: decided to commit; owns ``r_to_i`` at version + 1, ``i_to_r`` become held."""

    trade_id: str
    partner: str
    i_to_r: LmSet
    r_to_i: LmSet


class AbortRec(Rec, tag="abort"):
    """I: the offer ended without a transfer (``reason``: busy, no_trade, refused, timeout,
    restart)."""

    trade_id: str
    partner: str
    reason: str


class DoneRec(Rec, tag="done"):
    """I: R acknowledged the commit; held ``i_to_r`` are dropped."""

    trade_id: str


class PreparedRec(Rec, tag="prepared"):
    """R: accepted the trade; ``r_to_i`` become held until the outcome is known."""

    trade_id: str
    partner: str
    i_to_r: LmSet
    r_to_i: LmSet


class CommittedRec(Rec, tag="committed"):
    """R: learned I committed; owns ``i_to_r`` at version + 1, drops held ``r_to_i``."""

    trade_id: str


class RestoredRec(Rec, tag="restored"):
    """R: learned I aborted; held ``r_to_i`` are owned again at the same version."""

    trade_id: str


class FenceRec(Rec, tag="fence"):
    """Voted to fence out agents ``fenced`` (round ``epoch`` of ``coordinator``): their requests
    are refused from now on and our trades with them stay as they are until a round resolves
    them (:class:`AdoptRec`)."""

    epoch: int
    coordinator: str
    fenced: list[str]
    #: the round's proof, once known (agent.protocol.fence_proof): kept to publish it again
    proof: FenceProof | None = None


class AdoptRec(Rec, tag="adopt"):
    """Fence round ``epoch`` of ``coordinator`` resolved: our trades with the ``fenced`` agents
    end (what we hold for them is ours again, except ``drop``: the team found it newer
    elsewhere), and we adopt the orphaned landmarks ``owned`` (ids, versions to own them at)."""

    epoch: int
    coordinator: str
    fenced: list[str]
    owned: LmSet
    drop: LmSet


class UnfenceRec(Rec, tag="unfence"):
    """Fence round ``epoch`` of ``coordinator`` ended without a proof, its coordinator says
    (:mod:`agent.protocol.fencing`, "Abandoned rounds"): the fences we took only by voting in
    it are lifted, and we vote in it no more."""

    epoch: int
    coordinator: str


class FencedRec(Rec, tag="fenced"):
    """This agent learned that the team fenced it out in round ``epoch`` (``by`` told it): its
    whole ledger is dropped, its landmarks were adopted by the others."""

    epoch: int
    by: str


class MemberRec(Rec, tag="member"):
    """Admitted ``agent``, a drone not in the scenario, to the team (it may trade with us; a
    fence round must count it). Journaled by the admitting agent before it acknowledges, and
    by the joiner itself (``agent`` = itself) once a majority of the team admitted it."""

    agent: str


class StageRec(Rec, tag="stage"):
    """Strategy "potential": this agent's state when its thesis stage ended, kept for the
    revert (agent.runtime.moves.revert): pose p [m; world ENU], unit v, its landmarks and its
    vision of them (eq. 3.8). Not needed for safety: not fsynced."""

    p: Vec3
    v: Vec3
    owned: LmSet
    vision: float


class CaptureRec(Rec, tag="capture"):
    """Inspection missions: landmarks this agent's camera captured (ids) at mission time t
    [s] from pose p [m; world ENU], optical axis v and image x axis ``right`` (unit), each at
    ``quality`` (eq. 3.1); journaled before its published captured set names them, so a
    restart never un-captures them."""

    ids: Annotated[list[int], msgspec.Meta(max_length=1_000_000)]
    t: float = 0.0
    p: Vec3 = (0.0, 0.0, 0.0)
    v: Vec3 = (1.0, 0.0, 0.0)
    right: Vec3 = (0.0, -1.0, 0.0)
    quality: Annotated[list[float], msgspec.Meta(max_length=1_000_000)] = \
        msgspec.field(default_factory=list)


Record = (
    GenesisRec | StartRec | PoseRec | OfferRec | CommitRec | AbortRec | DoneRec | PreparedRec
    | CommittedRec | RestoredRec | FenceRec | AdoptRec | UnfenceRec | FencedRec | MemberRec
    | StageRec | CaptureRec
)

#: Records that must be on disk before the message that depends on them is sent: the
#: participant's vote (prepared), the coordinator's decision (commit), the participant's
#: commit (its CommitAck lets the initiator drop its held copy), and start-up records.
#: ``RestoredRec`` needs no fsync: if a crash loses it, the restarted responder is in doubt
#: again and the initiator answers "aborted" again; any later durable record fsyncs the
#: append-only file, including it, before anything can depend on it. Offers, done and pose
#: records are not needed for safety. A fence is durable before the vote that depends on it
#: (a restarted voter must still refuse the fenced agent), an adoption before its ack, a
#: lifted fence before a trade with the agent it lifts, a fenced agent's drop before anything
#: else, an admission before its acknowledgement, a
#: capture before the captured set that names it.
DURABLE = (GenesisRec, StartRec, CommitRec, PreparedRec, CommittedRec, FenceRec, AdoptRec,
           UnfenceRec, FencedRec, MemberRec, CaptureRec)


class JournalMismatch(UsageError, ValueError):
    """A journal that cannot be this agent's: written by an incompatible build, or naming
    landmarks that are not in this mission (wrong scenario). Never truncated."""
