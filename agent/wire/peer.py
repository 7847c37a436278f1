"""Every viscover wire message: versioned, tagged ``msgspec.Struct`` classes (msgpack).

Each Struct carries ``schema: int = SCHEMA`` (checked by :class:`agent.wire.codec.Codec`) and a
``kind`` tag. Positions are metres and directions unit vectors, both in the mission's world
frame (ENU); times are seconds of the sending agent's mission clock.
(Over 400 lines, not split: it is the one contract of the messages between agents.)

=================  ==========================================  ===============================
Message            Where                                       Meaning
=================  ==========================================  ===============================
:class:`Pose`      publication on ``pose/<id>``                position/direction of an agent
:class:`AgentState` publication on ``state/<id>``              full state (observer, completion)
:class:`MissionStatus` publication on ``status/<id>``          "mission complete" notices
:class:`Offer`     query on ``trade/<R>`` (I -> R)             step 1: I proposes a trade
:class:`Commit`    query on ``trade/<R>`` (I -> R)             step 3: I has committed
:class:`StatusQuery` query on ``trade/<I>`` (R -> I)           R in doubt asks for the decision
:class:`Busy`      reply to Offer                              R optimising or in a trade
:class:`NoTrade`   reply to Offer                              Algorithm 7 moves nothing
:class:`Accept`    reply to Offer                              R prepared the transfer
:class:`CommitAck` reply to Commit                             R committed
:class:`Decision`  reply to StatusQuery                        committed / aborted / pending
:class:`Refused`   reply to anything invalid or stale          see ``reason``
:class:`FenceProposal` query on ``trade/<V>`` (C -> V)         fence round: lost agents, freeze
:class:`FenceVote` reply to FenceProposal                      V fenced them, froze, its ledger
:class:`AdoptOrder` query on ``trade/<V>`` (C -> V)            V adopts these orphans
:class:`AdoptAck`  reply to AdoptOrder                         adopted (or the freeze expired)
:class:`Fenced`    reply to a request of a fenced agent        the team fenced the sender out
:class:`JoinRequest` query on ``trade/<V>`` (J -> V)           a drone not in the scenario asks in
:class:`JoinAck`   reply to JoinRequest                        V admitted J (journaled)
=================  ==========================================  ===============================

The fence round (C = coordinator, V = voter) is :mod:`agent.protocol.fencing`; its proof
(:class:`FenceProof`, the voters' :class:`FenceBallot` s) travels in :class:`AdoptOrder` and
in :class:`AgentState` and is checked by :mod:`agent.protocol.fence_proof`.

Landmark sets travel as :class:`LmSet`: two packed little-endian arrays (int64 landmark ids,
int32 versions), so that decoding and validating a set of thousands of landmarks costs no Python
loop (a transfer moves a landmark from version n at its old owner to n + 1 at its new owner).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Annotated, Final, Literal

import msgspec
import numpy as np
from numpy.typing import NDArray

#: Wire schema version spoken by this build.
SCHEMA: Final = 1

#: Largest landmark version accepted on the wire (versions only grow by one per transfer).
MAX_VERSION: Final = 2**31 - 1
#: Largest mission stage (:attr:`AgentState.stage`): the thesis', the coverage moves, and up
#: to 14 whole-team re-split rounds.
MAX_STAGE: Final = 16
#: Largest incarnation accepted (one per restart of an agent: a million restarts is absurd, and
#: a forged huge one must not make the real states look old).
MAX_INCARNATION: Final = 1_000_000
#: Largest trade counter in a trade id (one per offer of one incarnation).
MAX_TRADE_COUNTER: Final = 2**31 - 1
#: Longest list or map of ids in a message (agents, partners, pending trades).
MAX_IDS: Final = 1024
#: Longest landmark set in bytes (8 bytes an id: a million landmarks).
MAX_SET_BYTES: Final = 8_000_000
#: Committed trades an :class:`AgentState` reports the terms of (its newest ones).
MAX_RECENT_TRADES: Final = 8
#: Fence proofs an :class:`AgentState` carries (the newest covering each fenced agent).
MAX_FENCE_PROOFS: Final = 8
#: Partners an :class:`AgentState` names (the next ones it will offer to): receivers need only
#: whether any are left, and a state at 5 Hz must not grow with the team (docs/protocol.md).
PARTNERS_PUBLISHED: Final = 3
#: Capture claims an :class:`AgentState` carries (its newest and a few older ones in turn:
#: agent.protocol.captures), and landmark ids one claim names (a bigger capture is split).
MAX_CAPTURE_CLAIMS: Final = 16
MAX_CLAIM_IDS: Final = 4096
#: The capture claim format this build writes (:class:`CaptureClaim`); others are refused.
CLAIM_VERSION: Final = 1

#: Every field that comes from the network is bounded at decoding (msgspec constraints): an
#: agent id as :data:`agent.wire.keys.ID_PATTERN`, a trade id ``initiator:incarnation:counter``
#: (or empty), a reason up to 64 characters, integers non-negative and bounded.
AgentId = Annotated[str, msgspec.Meta(pattern=r"^[A-Za-z0-9_-]{1,32}$")]
TradeId = Annotated[str, msgspec.Meta(
    max_length=80, pattern=r"^([A-Za-z0-9_-]{1,32}:[0-9]{1,12}:[0-9]{1,12})?$")]
Reason = Annotated[str, msgspec.Meta(max_length=64)]
Seq = Annotated[int, msgspec.Meta(ge=0, le=2**62)]
Count = Annotated[int, msgspec.Meta(ge=0, le=2**62)]
Incarnation = Annotated[int, msgspec.Meta(ge=0, le=MAX_INCARNATION)]
SetBytes = Annotated[bytes, msgspec.Meta(max_length=MAX_SET_BYTES)]
#: An Ed25519 signature (64 bytes), or empty on the open profile.
Signature = Annotated[bytes, msgspec.Meta(max_length=64)]

Phase = Literal["optimising", "converged", "trading", "in_doubt"]
PHASES: Final = ("optimising", "converged", "trading", "in_doubt")


class LmSet(msgspec.Struct, array_like=True, frozen=True):
    """A set of landmarks with versions: ``ids`` little-endian int64, ``versions``
    little-endian int32, same length, ids unique (checked by :func:`unpack`)."""

    ids: SetBytes = b""
    versions: SetBytes = b""


_ID = np.dtype("<i8")
_VER = np.dtype("<i4")


def pack(d: Mapping[int, int]) -> LmSet:
    """``{id: version}`` -> :class:`LmSet`."""
    n = len(d)
    ids = np.fromiter(d.keys(), dtype=np.int64, count=n).astype(_ID)
    vers = np.fromiter(d.values(), dtype=np.int64, count=n).astype(_VER)
    return LmSet(ids.tobytes(), vers.tobytes())


def pack_arrays(ids: NDArray[np.int64], versions: NDArray[np.int64]) -> LmSet:
    """Id and version arrays -> :class:`LmSet`."""
    return LmSet(ids.astype(_ID).tobytes(), versions.astype(_VER).tobytes())


def unpack(s: LmSet) -> tuple[NDArray[np.int64], NDArray[np.int64]] | None:
    """(ids, versions) as int64 arrays, or None if malformed (lengths, duplicate ids,
    versions outside [0, MAX_VERSION))."""
    if len(s.ids) % 8 or len(s.versions) % 4 or len(s.ids) // 8 != len(s.versions) // 4:
        return None
    ids, vers = unpack_trusted(s)
    if ids.size and (vers < 0).any():
        return None
    # Sets we pack are sorted; only an unsorted one needs the O(m log m) duplicate check.
    if ids.size > 1 and not (ids[1:] > ids[:-1]).all() and np.unique(ids).size != ids.size:
        return None
    return ids, vers


def unpack_trusted(s: LmSet) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """(ids, versions) as int64 arrays of a set known to be well formed (our own journal)."""
    return (np.frombuffer(s.ids, dtype=_ID).astype(np.int64),
            np.frombuffer(s.versions, dtype=_VER).astype(np.int64))


def pack_bits(mask: NDArray[np.bool_]) -> bytes:
    """A per-landmark mask (rows of the scenario's landmark order) as a bit set (little bit
    order, ceil(m / 8) bytes)."""
    return np.packbits(mask, bitorder="little").tobytes()


def unpack_bits(bits: bytes, m: int) -> NDArray[np.bool_] | None:
    """The mask (m,) of a bit set from :func:`pack_bits`, or None if it is not one for m
    landmarks (wrong length, or bits set past the last landmark)."""
    if len(bits) != (m + 7) // 8:
        return None
    mask = np.unpackbits(np.frombuffer(bits, dtype=np.uint8), bitorder="little")
    if mask[m:].any():
        return None
    return np.asarray(mask[:m], dtype=np.bool_)


def to_dict(s: LmSet) -> dict[int, int] | None:
    """:class:`LmSet` -> ``{id: version}``, or None if malformed."""
    arrays = unpack(s)
    if arrays is None:
        return None
    return dict(zip(arrays[0].tolist(), arrays[1].tolist(), strict=True))


class _Msg(msgspec.Struct, tag_field="kind", kw_only=True, omit_defaults=False):
    """Common base: every message has a schema version and the sender's agent id."""

    schema: int = SCHEMA
    sender: AgentId


# -- publications ------------------------------------------------------------------------------


class Pose(_Msg, tag="pose"):
    """Pose of ``sender`` at mission time ``t`` [s]: position ``p`` [m], unit direction ``v``."""

    seq: Seq
    t: float
    p: tuple[float, float, float]
    v: tuple[float, float, float]


class Counters(msgspec.Struct, kw_only=True):
    """Trade counters of one agent (since its first start; rebuilt from its journal)."""

    ok: Count = 0  #: successful trades (committed, either role)
    failed: Count = 0  #: offers that moved nothing (NoTrade) or were aborted
    busy: Count = 0  #: Busy replies received
    timeouts: Count = 0  #: requests without a reply
    rejected: Count = 0  #: incoming payloads rejected (undecodable, wrong schema, impossible)
    #: entries evicted from its bounded per-sender tables (a flood of new incarnation tokens)
    evicted: Count = 0


class TradeTerms(msgspec.Struct, kw_only=True, frozen=True):
    """One committed trade of the sending agent, as its journal holds it: the initiator's
    ``CommitRec`` or the responder's ``PreparedRec`` (at its ``CommittedRec``), so that both
    sides of a trade report the same terms crosswise (one's ``gained`` is the other's
    ``given``). Sets carry the giver's versions (the receiver owns them at version + 1)."""

    n: Count  #: ordinal among the sender's committed trades (its ``counters.ok`` after it)
    trade_id: TradeId
    partner: AgentId
    role: Literal["initiator", "responder"]
    count: Count  #: the sender's ``trades_with[partner]`` after this trade
    gained: LmSet
    given: LmSet


class Battery(msgspec.Struct, kw_only=True, frozen=True):
    """A flying agent's battery as its autopilot reports it (BATTERY_STATUS, SYS_STATUS):
    remaining charge ``pct`` [%] and pack voltage ``voltage_v`` [V]; None: not reported."""

    pct: Annotated[float, msgspec.Meta(ge=0.0, le=100.0)] | None = None
    voltage_v: Annotated[float, msgspec.Meta(gt=0.0, lt=1000.0)] | None = None

    def summary(self) -> str:
        """One cell of ``viscover status``: '74 %, 15.31 V', '74 %', '15.31 V' or 'unknown'."""
        parts = ([] if self.pct is None else [f"{self.pct:.0f} %"]) + \
            ([] if self.voltage_v is None else [f"{self.voltage_v:.2f} V"])
        return ", ".join(parts) or "unknown"


#: Why an inspection drone gave landmarks up (agent.protocol.inspection_end): no viewpoint
#: capturing them could be reached, one was reached but the capture did not happen there, or
#: it left the mission on low battery holding them.
GivenUpReason = Literal["unreachable", "blocked", "battery"]


class GivenUp(msgspec.Struct, array_like=True, frozen=True):
    """Landmarks of an inspection given up for ``reason``: a bit set of the scenario's
    landmark rows (:func:`pack_bits`)."""

    reason: GivenUpReason
    landmarks: Annotated[bytes, msgspec.Meta(max_length=MAX_SET_BYTES // 64)]


class CaptureClaim(msgspec.Struct, array_like=True, frozen=True):
    """One image of the sending drone's camera as evidence of its captures: taken at mission
    time ``t`` [s] from position ``p`` [m; world ENU] with unit optical axis ``v`` [world
    ENU], capturing the landmarks ``ids`` (little-endian int64, at most
    :data:`MAX_CLAIM_IDS`). A receiver merges them only when the pose agrees with what the
    sender published (and the ground station's mocap of it) and the inspection's capture test
    holds from it (agent.protocol.captures, agent.runtime.moves.inspecting)."""

    version: Annotated[int, msgspec.Meta(ge=0, le=255)]
    t: float
    p: tuple[float, float, float]
    v: tuple[float, float, float]
    ids: Annotated[bytes, msgspec.Meta(max_length=8 * MAX_CLAIM_IDS)]


class AgentState(_Msg, tag="state"):
    """An agent's published state (periodically and on change).

    ``owned``/``held`` map landmark ids to versions (``held``: given away in a pending
    transfer, not counted for coverage). ``trades_with[x]`` counts successful trades with agent
    ``x``; completion requires both sides of every pair to agree.
    """

    incarnation: Incarnation
    seq: Seq
    t: float
    p: tuple[float, float, float]
    v: tuple[float, float, float]
    phase: Phase
    owned: LmSet
    held: LmSet
    vision: float
    counters: Counters
    #: the next partners it will offer to (at most :data:`PARTNERS_PUBLISHED` sent; empty:
    #: none left)
    partners: Annotated[list[AgentId], msgspec.Meta(max_length=MAX_IDS)]
    pending: Annotated[list[TradeId], msgspec.Meta(max_length=MAX_IDS)]
    trades_with: Annotated[dict[AgentId, Count], msgspec.Meta(max_length=MAX_IDS)]
    complete: bool = False
    #: agents this one knows the team fenced out (lost; only those ``fence_proofs`` prove),
    #: and the newest fence round it knows
    fenced: Annotated[list[AgentId], msgspec.Meta(max_length=MAX_IDS)] = \
        msgspec.field(default_factory=list)
    fence_epoch: Count = 0
    #: landmarks held for trades with fenced agents, waiting for a fence round to resolve them
    contested: Count = 0
    #: drones not in the scenario this one admitted or heard of (agent.runtime.ends.joining)
    members: Annotated[list[AgentId], msgspec.Meta(max_length=MAX_IDS)] = \
        msgspec.field(default_factory=list)
    #: the team fenced this agent out (round ``fence_epoch``): its ledger was dropped and its
    #: claims are void
    fenced_out: bool = False
    #: 2 once this agent's thesis stage completed and it makes coverage moves (strategy
    #: "potential"), one more per whole-team re-split round after that
    #: (agent.runtime.moves.coverage);
    #: 1 before, and always under the thesis' strategy
    stage: Annotated[int, msgspec.Meta(ge=1, le=MAX_STAGE)] = 1
    #: this agent's vision of its own set when its thesis stage ended (eq. 3.8; -1: unknown)
    stage1_vision: float = -1.0
    #: it takes back its thesis-stage set and pose: the moves ended below the thesis' score
    reverting: bool = False
    #: the terms of its newest committed trades (at most :data:`MAX_RECENT_TRADES`, oldest
    #: first): what a trade event reports; empty from builds before it (and before a trade)
    trades: Annotated[list[TradeTerms], msgspec.Meta(max_length=MAX_RECENT_TRADES)] = \
        msgspec.field(default_factory=list)
    #: inspection missions: the landmarks captured in this agent's view (its own, journaled,
    #: and its peers'), one bit per landmark row of the scenario (:func:`pack_bits`); a
    #: grow-only set every receiver merges by union. Empty in coverage missions.
    captured: Annotated[bytes, msgspec.Meta(max_length=MAX_SET_BYTES // 64)] = b""
    #: the proofs of the fences in ``fenced`` (:class:`FenceProof`, the newest covering each;
    #: agent.protocol.fence_proof): a fence is believed only with one. Empty from builds
    #: before it.
    fence_proofs: Annotated[list[FenceProof], msgspec.Meta(max_length=MAX_FENCE_PROOFS)] = \
        msgspec.field(default_factory=list)
    #: a flying agent's battery (agent.flight.battery); None: a vehicle without one (a
    #: kinematic agent), or a build before it
    battery: Battery | None = None
    #: inspection missions: the landmarks the capture table says some viewpoint captures, one
    #: bit per landmark row (the same for every agent of the mission); empty in coverage
    #: missions and from builds before it
    capturable: Annotated[bytes, msgspec.Meta(max_length=MAX_SET_BYTES // 64)] = b""
    #: inspection missions: the landmarks given up in this agent's view (its own and its
    #: peers', merged: agent.protocol.inspection_end), one set per reason. Empty when nothing
    #: was given up, in coverage missions and from builds before it.
    given_up: Annotated[list[GivenUp], msgspec.Meta(max_length=3)] = \
        msgspec.field(default_factory=list)
    #: inspection missions: the evidence of this agent's own captures (:class:`CaptureClaim`,
    #: its newest ones and older ones in turn); None from builds before it (whose
    #: ``captured`` is then believed by nobody)
    claims: Annotated[list[CaptureClaim], msgspec.Meta(max_length=MAX_CAPTURE_CLAIMS)] | None \
        = None
    #: inspection missions: capture claims of its peers this agent refused (no evidence, a
    #: pose it was not at, a capture test failing from it, an uncapturable landmark)
    refused_claims: Count = 0


class MissionStatus(_Msg, tag="status"):
    """Published when an agent's view of the mission changes to complete (or back)."""

    t: float
    complete: bool
    coverage: float
    agents: Annotated[list[AgentId], msgspec.Meta(max_length=MAX_IDS)]


# -- trade requests --------------------------------------------------------------------------


class Regroup(msgspec.Struct, kw_only=True, frozen=True):
    """A pair re-split proposed with an Offer (the coverage moves of ``strategy =
    "potential"``, :func:`agent.core.coverage_moves.group_proposal`): R's landmark ids the
    proposal was computed for (``before``), I's landmarks that go to R (``give``) and R's that
    go to I (``take``), R's pose after the move ``goal_p`` [m; world ENU], unit ``goal_v``."""

    before: LmSet
    give: LmSet
    take: LmSet
    goal_p: tuple[float, float, float]
    goal_v: tuple[float, float, float]
    #: a revert pull (agent.runtime.moves.revert): I takes back ``take``, landmarks it owned when
    #: the thesis stage ended; R gives them if it owns them all, whatever else it owns
    #: (``before`` and the goal are not used; ``give`` must be empty)
    pull: bool = False


class Offer(_Msg, tag="offer"):
    """I -> R: I's pose and its owned landmarks with versions; with ``regroup`` a re-split
    that R accepts only if it was made for its current set (else R runs Algorithm 7)."""

    trade_id: TradeId
    p: tuple[float, float, float]
    v: tuple[float, float, float]
    owned: LmSet
    regroup: Regroup | None = None


class Commit(_Msg, tag="commit"):
    """I -> R: I has journaled its commit of ``trade_id`` (repeated until acknowledged)."""

    trade_id: TradeId


class StatusQuery(_Msg, tag="status_query"):
    """R -> I: R is prepared for ``trade_id`` and asks I's decision."""

    trade_id: TradeId


# -- trade replies ---------------------------------------------------------------------------


class Busy(_Msg, tag="busy"):
    """R cannot trade now: ``reason`` is ``"optimising"`` (drop R) or ``"trading"`` (retry)."""

    trade_id: TradeId
    reason: Literal["optimising", "trading"]


class NoTrade(_Msg, tag="no_trade"):
    """Algorithm 7 moves no landmark between I and R: both drop each other."""

    trade_id: TradeId


class Accept(_Msg, tag="accept"):
    """R prepared the transfer: ``i_to_r`` (I's landmarks, I's versions) and ``r_to_i``
    (R's landmarks, R's versions) now move; R holds ``r_to_i`` until it learns the outcome."""

    trade_id: TradeId
    i_to_r: LmSet
    r_to_i: LmSet


class CommitAck(_Msg, tag="commit_ack"):
    """R committed ``trade_id``: it owns ``i_to_r`` at version + 1."""

    trade_id: TradeId


class Decision(_Msg, tag="decision"):
    """I's answer to a :class:`StatusQuery`."""

    trade_id: TradeId
    status: Literal["committed", "aborted", "pending"]


class Refused(_Msg, tag="refused"):
    """The request was invalid, stale or inconsistent with the receiver's ledger."""

    trade_id: TradeId
    reason: Reason


# -- fence rounds (agent.protocol.fencing) ---------------------------------------------------


class FenceProposal(_Msg, tag="fence"):
    """C -> V: agents ``fenced`` are lost; fence them, freeze and vote with your ledger."""

    epoch: Count
    fenced: Annotated[list[AgentId], msgspec.Meta(max_length=MAX_IDS)]


class FenceVote(_Msg, tag="fence_vote"):
    """V -> C: V journaled the fence, froze its ledger and reports it (owned and held, with
    versions; ``contested``: held for trades with fenced agents), with its pose (p [m; world
    ENU], v unit) and the fences it knows."""

    epoch: Count
    ledger: LmSet
    contested: LmSet
    p: tuple[float, float, float]
    v: tuple[float, float, float]
    fenced: Annotated[list[AgentId], msgspec.Meta(max_length=MAX_IDS)]
    #: drones not in the scenario V admitted: the round must count them too
    members: Annotated[list[AgentId], msgspec.Meta(max_length=MAX_IDS)] = \
        msgspec.field(default_factory=list)
    #: V's signature of its ballot for this round (:class:`FenceBallot`; empty: open profile)
    sig: Signature = b""


class AdoptOrder(_Msg, tag="adopt"):
    """C -> V: end your trades with the ``fenced`` agents (keep what you hold for them except
    ``drop``), adopt the orphans ``owned`` (ids, versions to own them at), then unfreeze."""

    epoch: Count
    fenced: Annotated[list[AgentId], msgspec.Meta(max_length=MAX_IDS)]
    owned: LmSet
    drop: LmSet
    #: the round's proof (votes of a strict majority): V keeps it and publishes it
    proof: FenceProof | None = None


class AdoptAck(_Msg, tag="adopt_ack"):
    """V -> C: ``ok`` V adopted (or already had); not ok: V was no longer frozen for it."""

    epoch: Count
    ok: bool


class Fenced(_Msg, tag="fenced"):
    """The team fenced the sender of the request out in round ``epoch``: it is lost, its
    landmarks were adopted; it must drop its ledger."""

    epoch: Count


class JoinRequest(_Msg, tag="join"):
    """J -> V: J, a drone not in the scenario, asks to join the team at pose ``p`` [m; world
    ENU], unit camera direction ``v``, holding no landmark."""

    p: tuple[float, float, float]
    v: tuple[float, float, float]


class JoinAck(_Msg, tag="join_ack"):
    """V -> J: V journaled J as a member: it trades with J and counts it in fence rounds."""

    ok: bool


class FenceBallot(msgspec.Struct, array_like=True, frozen=True):
    """One voter's vote in fence round (``epoch``, ``coordinator``) to fence ``fenced`` (ids
    ascending), with ``sig``: the voter's Ed25519 signature of exactly that
    (:func:`agent.wire.ballots.ballot_bytes`; empty on the open profile)."""

    voter: AgentId
    epoch: Count
    coordinator: AgentId
    fenced: Annotated[list[AgentId], msgspec.Meta(max_length=MAX_IDS)]
    sig: Signature = b""


class FenceProof(msgspec.Struct, array_like=True, frozen=True):
    """The proof that the team fenced ``fenced`` out in round (``epoch``, ``coordinator``):
    the ballots of the round's voters, a strict majority of the scenario's team, none fenced
    (checked by :func:`agent.protocol.fence_proof.check_proof`)."""

    epoch: Count
    coordinator: AgentId
    fenced: Annotated[list[AgentId], msgspec.Meta(max_length=MAX_IDS)]
    ballots: Annotated[list[FenceBallot], msgspec.Meta(max_length=MAX_IDS)]


class RoundQuery(_Msg, tag="round_query"):
    """V -> C: V fences agents only because it voted in C's round ``epoch``; is that round
    still running, proven, or ended without a proof (:mod:`agent.protocol.fencing`)?"""

    epoch: Count


class RoundStatus(_Msg, tag="round_status"):
    """C -> V: C's round ``epoch`` is ``running``, ``proven`` (its ``proof``: V keeps it) or
    ``abandoned`` (ended without a proof and never resumed: V lifts the fences it took only
    by voting in it)."""

    epoch: Count
    status: Literal["running", "proven", "abandoned"]
    proof: FenceProof | None = None


Request = (Offer | Commit | StatusQuery | FenceProposal | AdoptOrder | RoundQuery
           | JoinRequest)

Reply = (Busy | NoTrade | Accept | CommitAck | Decision | Refused | FenceVote | AdoptAck
         | RoundStatus | Fenced | JoinAck)

Publication = Pose | AgentState | MissionStatus

__all__ = [
    "CLAIM_VERSION",
    "MAX_CAPTURE_CLAIMS",
    "MAX_CLAIM_IDS",
    "MAX_FENCE_PROOFS",
    "MAX_INCARNATION",
    "MAX_RECENT_TRADES",
    "MAX_TRADE_COUNTER",
    "MAX_VERSION",
    "PHASES",
    "SCHEMA",
    "Accept",
    "AdoptAck",
    "AdoptOrder",
    "AgentState",
    "Battery",
    "Busy",
    "CaptureClaim",
    "Commit",
    "CommitAck",
    "Counters",
    "Decision",
    "FenceBallot",
    "FenceProof",
    "FenceProposal",
    "FenceVote",
    "Fenced",
    "GivenUp",
    "GivenUpReason",
    "JoinAck",
    "JoinRequest",
    "LmSet",
    "MissionStatus",
    "NoTrade",
    "Offer",
    "Phase",
    "Pose",
    "Publication",
    "Refused",
    "Regroup",
    "Reply",
    "Request",
    "RoundQuery",
    "RoundStatus",
    "StatusQuery",
    "TradeTerms",
    "pack",
    "pack_arrays",
    "pack_bits",
    "parse_trade_id",
    "to_dict",
    "unpack",
    "unpack_bits",
    "unpack_trusted",
]


def parse_trade_id(trade_id: str) -> tuple[str, int, int] | None:
    """Split ``"{initiator}:{incarnation}:{counter}"``; None if malformed or out of bounds
    (incarnation above :data:`MAX_INCARNATION`, counter above :data:`MAX_TRADE_COUNTER`)."""
    parts = trade_id.split(":")
    if len(parts) != 3:
        return None
    who, inc, ctr = parts
    if not who or not inc.isdigit() or not ctr.isdigit() or len(inc) > 12 or len(ctr) > 12:
        return None
    if int(inc) > MAX_INCARNATION or int(ctr) > MAX_TRADE_COUNTER:
        return None
    return who, int(inc), int(ctr)


def make_trade_id(initiator: str, incarnation: int, counter: int) -> str:
    """``"{initiator}:{incarnation}:{counter}"``."""
    return f"{initiator}:{incarnation}:{counter}"
