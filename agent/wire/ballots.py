"""Signed fence ballots: a drone's vote in a fence round, as a detached Ed25519 signature with
the drone's trade-signing key (:class:`agent.wire.signed.SigningKeys`, the secured profile's
``drone-<id>.sign`` and the team's ``team.json``).

What is signed: a domain tag of its own (no trade envelope can be taken for a ballot, nor the
reverse), the ballot schema, the mission, the voter, the round (epoch, coordinator) and the
fenced agents (sorted). A ballot has no time and no addressee: it states a durable fact (the
voter journaled the fence and refuses those agents for good), so a replayed ballot only
repeats it. The proofs made of ballots are :mod:`agent.protocol.fence_proof`.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING, Final

import msgspec

if TYPE_CHECKING:  # cryptography is loaded where used (start-up time)
    from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PublicKey

from agent.wire.signing import SigningKeys

_DOMAIN: Final = b"viscover/fence-ballot/v1"
#: Ballot schema spoken by this build.
BALLOT_SCHEMA: Final = 1
_SIG_LEN: Final = 64
_enc = msgspec.msgpack.Encoder()


def ballot_bytes(mission: str, voter: str, epoch: int, coordinator: str,
                 fenced: Sequence[str]) -> bytes:
    """The canonical byte string a ballot's signature covers (see the module docstring)."""
    return _enc.encode((_DOMAIN, BALLOT_SCHEMA, mission, voter, epoch, coordinator,
                        sorted(fenced)))


def sign_ballot(keys: SigningKeys, mission: str, epoch: int, coordinator: str,
                fenced: Sequence[str]) -> bytes:
    """``keys.me``'s signature of its vote to fence ``fenced`` in round (``epoch``,
    ``coordinator``) of ``mission``."""
    return keys.private.sign(ballot_bytes(mission, keys.me, epoch, coordinator, fenced))


def ballot_ok(team: Mapping[str, Ed25519PublicKey], mission: str, voter: str, epoch: int,
              coordinator: str, fenced: Sequence[str], sig: bytes) -> bool:
    """Whether ``sig`` is ``voter``'s signature (its key in ``team``) of that vote."""
    from cryptography.exceptions import InvalidSignature

    key = team.get(voter)
    if key is None or len(sig) != _SIG_LEN:
        return False
    try:
        key.verify(sig, ballot_bytes(mission, voter, epoch, coordinator, fenced))
    except InvalidSignature:
        return False
    return True
