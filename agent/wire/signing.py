"""What the agent core knows of signed trade messages (:mod:`agent.wire.signed`), without the
seal itself: the reject reasons, a refusal, an opened request and one drone's keys. The seal
(incarnation tokens, stamps, its replay memory) is the runtime's; the core signs only fence
ballots (:mod:`agent.wire.ballots`). Pure data.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Final, NamedTuple

if TYPE_CHECKING:  # cryptography is loaded where used (an open-profile agent starts faster)
    from cryptography.hazmat.primitives.asymmetric.ed25519 import (
        Ed25519PrivateKey,
        Ed25519PublicKey,
    )

#: Reject reasons (counted like the codec's; ``stale`` is not counted).
REASON_UNSIGNED: Final = "unsigned"
REASON_FORGED: Final = "forged"
REASON_REPLAY: Final = "replay"
REASON_STALE: Final = "stale"


class Refusal(NamedTuple):
    """Why an envelope was refused: a reject reason, a (network-derived) detail, and for a
    stale request the signed stale reply to send back (else empty)."""

    reason: str
    detail: str
    answer: bytes = b""


class Opened(NamedTuple):
    """An accepted request: its authenticated sender, the inner message, the nonce its reply
    must be bound to, and how many entries of the seal's bounded replay memory opening it
    evicted (counted by the receiver: a flood of new incarnation tokens shows)."""

    sender: str
    body: bytes
    nonce: bytes
    evicted: int = 0


@dataclass(frozen=True)
class SigningKeys:
    """One drone's signing key and the team's public keys (drone id -> key)."""

    me: str
    private: Ed25519PrivateKey = field(repr=False)
    team: Mapping[str, Ed25519PublicKey] = field(repr=False)
