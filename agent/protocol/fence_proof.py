"""Fence proofs: a fence is believed only with the votes that made it. Pure: no I/O.

A drone's word that the team fenced someone out (the ``fenced`` list of its state) is not
evidence: a single drone could otherwise make any peer drop its ledger and leave, and make
observers void that peer's claims. A :class:`~agent.wire.peer.FenceProof` carries what the
fence rests on (:mod:`agent.protocol.fencing`): the round (``epoch``, ``coordinator``), the
fenced agents F and one :class:`~agent.wire.peer.FenceBallot` per voter, each naming that round
and F. :func:`check_proof` accepts it when

* F is non-empty, sorted, without repeats, and does not name the coordinator;
* every ballot names the proof's round and F, no voter appears twice, no voter is in F
  (otherwise the proof is malformed and refused as a whole);
* the ballots that count, from members of the scenario's team (joiners vote but are not
  counted, as in :func:`~agent.protocol.fencing.has_quorum`) and, on the secured profile,
  signed by the voter's own key (:func:`agent.wire.ballots.ballot_ok`; a ballot signed by
  any other key is not counted), are a strict majority of the team.

A strict majority of the team voting means a majority journaled the fence before voting
(:class:`~agent.protocol.records.FenceRec`): they refuse F for good, and only a round with a
majority can adopt F's landmarks, so the claim "the team fenced F out" is true, whoever relays
the proof. Who makes it: the coordinator, once it holds a majority of votes (a round given
up after that still fenced F at a majority); it journals it, hands it to the voters in its
:class:`~agent.wire.peer.AdoptOrder` and every agent that accepts one publishes it in its
state (:class:`ProofBook` keeps the newest proof covering each fenced agent: usually one).

What each profile protects against:

* **Secured** (signed ballots): no drone, even one holding a team certificate and signing
  key, can prove a fence that a majority did not vote for: it can sign only its own ballot.
  Replaying a genuine proof only repeats a true fence.
* **Open** (unauthenticated by design, ballots unsigned): only the structure is checked. It
  stops a confused or outdated peer, a lone drone's claim and any claim without a majority of
  distinct team members naming the same round and F; it cannot stop a deliberate forger,
  who may write any ballots (anyone on the open mesh can also publish any drone's state).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping, Sequence
from typing import TYPE_CHECKING

import msgspec

from agent.wire.ballots import ballot_ok
from agent.wire.peer import FenceBallot, FenceProof

if TYPE_CHECKING:  # cryptography is loaded where used (start-up time)
    from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PublicKey

#: Whether a ballot's signature is its voter's (None: the open profile, nothing to check).
BallotCheck = Callable[[FenceBallot], bool]
#: Our signature of our vote in round (epoch, coordinator) to fence the (sorted) agents.
VoteSigner = Callable[[int, str, Sequence[str]], bytes]

#: Proof checks remembered (by the proof's bytes) before the cache is emptied.
_CACHE = 256


def ballot_checker(team_keys: Mapping[str, Ed25519PublicKey], mission: str) -> BallotCheck:
    """The secured profile's :data:`BallotCheck`: signed by the voter's key of ``team_keys``
    for ``mission``."""
    def check(b: FenceBallot) -> bool:
        return ballot_ok(team_keys, mission, b.voter, b.epoch, b.coordinator, b.fenced,
                         b.sig)
    return check


def make_proof(epoch: int, coordinator: str, fenced: Iterable[str],
               sigs: Mapping[str, bytes]) -> FenceProof:
    """The proof of round (``epoch``, ``coordinator``) fencing ``fenced`` from the voters'
    signatures (voter -> signature; empty on the open profile)."""
    f = sorted(set(fenced))
    return FenceProof(epoch=epoch, coordinator=coordinator, fenced=f, ballots=[
        FenceBallot(voter=v, epoch=epoch, coordinator=coordinator, fenced=f, sig=sigs[v])
        for v in sorted(sigs)])


def check_proof(proof: FenceProof, team: Sequence[str], check: BallotCheck | None) -> str | None:
    """Why ``proof`` proves nothing (None: it proves its fence; see the module docstring).
    ``team``: the scenario's agents; ``check``: the ballots' signature check (None: open)."""
    f = proof.fenced
    if not f or list(f) != sorted(set(f)) or proof.coordinator in f:
        return "malformed fenced list"
    voters = [b.voter for b in proof.ballots]
    if len(set(voters)) != len(voters):
        return "a voter twice"
    if set(voters) & set(f):
        return "a fenced agent votes"
    for b in proof.ballots:
        if (b.epoch, b.coordinator, b.fenced) != (proof.epoch, proof.coordinator, f):
            return f"ballot of {b.voter} for another round or fence"
    members = set(team)
    counted = [b.voter for b in proof.ballots
               if b.voter in members and (check is None or check(b))]
    if 2 * len(counted) <= len(members):
        return f"{len(counted)} valid votes of a team of {len(members)}: no majority"
    return None


def has_majority(voters: Iterable[str], team: Sequence[str]) -> bool:
    """Whether ``voters`` include a strict majority of ``team``."""
    return 2 * len(set(voters) & set(team)) > len(team)


class ProofBook:
    """The fence proofs one agent (or observer) accepted, and which fences they prove.

    Args:
        team: the scenario's agents (the majority is of them).
        check: ballot signature check (None: the open profile).
    """

    def __init__(self, team: Sequence[str], check: BallotCheck | None) -> None:
        self.team = list(team)
        self.check = check
        self.proofs: dict[tuple[int, str], FenceProof] = {}  #: accepted, by round
        self.proven: set[str] = set()  #: agents some accepted proof fences
        self._seen: dict[bytes, str | None] = {}  #: proof bytes -> check result

    def verdict(self, proof: FenceProof) -> str | None:
        """:func:`check_proof` of ``proof``, remembered (states repeat their proofs)."""
        raw = msgspec.msgpack.encode(proof)
        if raw not in self._seen:
            if len(self._seen) >= _CACHE:
                self._seen.clear()
            self._seen[raw] = check_proof(proof, self.team, self.check)
        return self._seen[raw]

    def accept(self, proof: FenceProof) -> bool:
        """Keep ``proof`` if it proves its fence; True if it is valid and new to us."""
        rid = (proof.epoch, proof.coordinator)
        if self.verdict(proof) is not None:
            return False
        known = self.proofs.get(rid)
        if known is not None and set(proof.fenced) <= set(known.fenced):
            return False
        self.proofs[rid] = proof
        self.proven |= set(proof.fenced)
        return True

    def cover(self, agents: Iterable[str], limit: int) -> list[FenceProof]:
        """At most ``limit`` proofs, newest first, together proving as many of ``agents`` as
        they can (what a state carries)."""
        want, out = set(agents) & self.proven, list[FenceProof]()
        for _rid, p in sorted(self.proofs.items(), reverse=True):
            if len(out) >= limit or not want:
                break
            if want & set(p.fenced):
                out.append(p)
                want -= set(p.fenced)
        return out
