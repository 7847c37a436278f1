"""Signed trade messages: a trade query or reply proves which drone sent it.

The secured router (``broker_config/router_secure.json5``) ties every key to its owner by
certificate common name, but any drone may *query* any peer's ``trade/<id>`` queryable, and the
application never learns who asked: zenoh-python's ``Query``/``Sample`` carry no authenticated
identity (``source_info`` is chosen by the sender, and the certificate name stays inside the
router's access control). So every trade request and reply travels in a :class:`Sealed`
envelope signed with the sender's Ed25519 key and checked against the team's public keys.

What is signed: a domain tag, the envelope's schema, kind (request / reply / stale), the
mission, the sender, the addressee, both ends' *incarnation tokens*, the sender's sequence
stamp, ``bound`` and the inner message.

**Incarnation tokens.** Each :class:`TradeSeal` (one per agent process) draws a random
63-bit token when it is made; it is never written anywhere, so every start of a drone's
process has a new one. A request names the token of the receiver it was made for.

* A request is accepted once: it must name the receiver's current token, and its stamp
  must be later than that of every request accepted from the same sender process (the
  sender's token) by this receiver process. A request naming another token (a first contact,
  or a receiver that restarted since) is not applied: it is answered with a signed *stale*
  reply, bound to it, that tells the sender the current token; the sender asks again.
* **Why a replay cannot be accepted across a restart**: the receiver's memory of what it
  accepted dies with its process, but so does its token. A request recorded before the
  restart names the old token, and the new process draws a fresh one (2^63 values, from
  :mod:`secrets`, never stored), so the recording is refused however soon it is replayed,
  and whatever happened to the journal (a lost disk, a fresh ``--state-dir``). Within one
  receiver process, the per-sender-process stamps refuse repeats and older requests.
* **Bounded memory.** The replay memory keeps, per team member, the stamps of its
  ``TOKENS_PER_SENDER`` most recently heard processes (a member's key is needed to add one, so
  the whole memory is at most that many per team member). A process evicted from it leaves its
  last stamp as the member's *floor*: a request from a process of that member the memory does
  not hold is accepted only with a stamp above the floor, so an evicted process's requests
  are still refused as replays (a member restarted with its wall clock stepped back behind
  the floor is refused until its clock passes it, only after such a flood). Evictions are
  counted (:attr:`TradeSeal.evictions`, and per request in :class:`Opened`).
* **No clocks are compared.** Freshness is judged by the receiver alone (its token and its
  memory), so drones whose wall clocks disagree by any amount trade normally. The stamp is
  the sender's wall clock in ns made strictly increasing within its process, used only as a
  sequence number (a clock stepped back by a restarted sender starts a new sequence: its
  token is new too).
* A reply is bound to its request (``bound`` = the request's signature): it cannot answer any
  other request, and it must come from the drone the request was sent to. A stale reply is
  bound the same way, so nobody but the receiver can make a sender re-learn its token.

Refusals are :class:`Refusal` values (reason, detail), never exceptions: ``unsigned`` (not an
envelope), ``forged`` (unknown signer, bad signature, wrong addressee or mission, inner sender
not the signer), ``replay`` (repeated or older than one already accepted) or ``stale`` (made
for another incarnation: not an attack by itself, so not counted; its ``answer`` is the stale
reply to send back).
"""

from __future__ import annotations

import base64
import binascii
import json
import secrets
import threading
import time
from collections.abc import Callable
from typing import TYPE_CHECKING, Annotated, Final

import msgspec

from agent.wire.signing import (
    REASON_FORGED,
    REASON_REPLAY,
    REASON_STALE,
    REASON_UNSIGNED,
    Opened,
    Refusal,
    SigningKeys,
)

__all__ = ["REASON_FORGED", "REASON_REPLAY", "REASON_STALE", "REASON_UNSIGNED", "Opened",
           "Refusal", "Sealed", "SigningKeys", "TradeSeal", "load_private_key", "parse_team",
           "private_key_pem", "public_key_text"]

if TYPE_CHECKING:  # cryptography is loaded where used (an open-profile agent starts faster)
    from cryptography.hazmat.primitives.asymmetric.ed25519 import (
        Ed25519PrivateKey,
        Ed25519PublicKey,
    )

#: Envelope schema spoken by this build (2: incarnation tokens, no clock window).
SEAL_SCHEMA: Final = 2
#: Kinds of envelope.
REQUEST: Final = 0
REPLY: Final = 1
STALE: Final = 2

_DOMAIN: Final = b"viscover/trade/v2"
#: Processes (incarnation tokens) of one sender the replay memory keeps (module docstring).
TOKENS_PER_SENDER: Final = 8
_SIG_LEN: Final = 64
#: Largest inner message [bytes] (two landmark sets of a million landmarks and the rest).
_MAX_BODY: Final = 32_000_000
#: An agent id or mission name (as :data:`agent.wire.keys.ID_PATTERN`).
AgentId = Annotated[str, msgspec.Meta(pattern=r"^[A-Za-z0-9_-]{1,32}$")]
#: An incarnation token (0: unknown).
Token = Annotated[int, msgspec.Meta(ge=0, le=2**63 - 1)]


class Sealed(msgspec.Struct, array_like=True, frozen=True):
    """A signed trade request, reply or stale reply (see the module docstring)."""

    schema: int
    kind: Annotated[int, msgspec.Meta(ge=REQUEST, le=STALE)]
    mission: AgentId
    sender: AgentId
    to: AgentId
    boot: Token  #: the sender's incarnation token
    to_boot: Token  #: a request: the receiver's token it was made for (0 in replies)
    ts_ns: Annotated[int, msgspec.Meta(ge=0, le=2**63 - 1)]
    bound: Annotated[bytes, msgspec.Meta(max_length=_SIG_LEN)]
    body: Annotated[bytes, msgspec.Meta(max_length=_MAX_BODY)]
    sig: Annotated[bytes, msgspec.Meta(min_length=_SIG_LEN, max_length=_SIG_LEN)]


_enc = msgspec.msgpack.Encoder()
_dec = msgspec.msgpack.Decoder(Sealed)


def _signed_bytes(e: Sealed) -> bytes:
    """The canonical byte string an envelope's signature covers (every field but ``sig``)."""
    return _enc.encode((_DOMAIN, e.schema, e.kind, e.mission, e.sender, e.to, e.boot,
                        e.to_boot, e.ts_ns, e.bound, e.body))


class TradeSeal:
    """Seals this drone's trade messages and opens its peers' (thread-safe); one per process.

    Args:
        keys: this drone's key and the team's public keys.
        mission: the mission name (a request for another mission is refused).
        clock_ns: wall clock [ns since the epoch] of the stamps (a sequence only; tests pass
            a fake one).
    """

    def __init__(self, keys: SigningKeys, mission: str,
                 clock_ns: Callable[[], int] = time.time_ns) -> None:
        self.keys = keys
        self.mission = mission
        #: this process's incarnation token (random, never stored: see the module docstring)
        self.boot = secrets.randbelow(2**63 - 1) + 1
        self._clock = clock_ns
        self._lock = threading.Lock()
        self._last_sent = 0
        self._peer_boot: dict[str, int] = {}
        #: sender -> {sender's token: stamp of the last request accepted from it}, most
        #: recently heard last, at most TOKENS_PER_SENDER tokens per sender
        self._last_seen: dict[str, dict[int, int]] = {}
        #: sender -> highest stamp of its processes evicted from the memory
        self._floor: dict[str, int] = {}
        self.evictions = 0  #: entries evicted from the replay memory so far

    def know(self, peer: str, boot: int) -> None:
        """Take ``boot`` as drone ``peer``'s current incarnation token."""
        with self._lock:
            self._peer_boot[peer] = boot

    def peer_boot(self, peer: str) -> int:
        """The incarnation token of drone ``peer`` we know (0: none yet)."""
        with self._lock:
            return self._peer_boot.get(peer, 0)

    def _stamp(self) -> int:
        """A time stamp [ns] later than every one this seal issued before."""
        with self._lock:
            self._last_sent = max(self._clock(), self._last_sent + 1)
            return self._last_sent

    def _seal(self, kind: int, body: bytes, to: str, bound: bytes, to_boot: int = 0) -> Sealed:
        """The envelope of ``body`` to ``to``, signed now."""
        env = Sealed(SEAL_SCHEMA, kind, self.mission, self.keys.me, to, self.boot, to_boot,
                     self._stamp(), bound, body, b"")
        return msgspec.structs.replace(env, sig=self.keys.private.sign(_signed_bytes(env)))

    def seal_request(self, body: bytes, to: str) -> tuple[bytes, bytes]:
        """(envelope bytes, nonce) of request ``body`` to drone ``to`` (for the incarnation
        of it we know, if any); the nonce is what the reply must be bound to."""
        with self._lock:
            to_boot = self._peer_boot.get(to, 0)
        env = self._seal(REQUEST, body, to, b"", to_boot)
        return _enc.encode(env), env.sig

    def seal_reply(self, body: bytes, to: str, nonce: bytes) -> bytes:
        """Envelope bytes of reply ``body`` to ``to``'s request ``nonce``."""
        return _enc.encode(self._seal(REPLY, body, to, nonce))

    def _open(self, data: bytes, kinds: tuple[int, ...]) -> Sealed | Refusal:
        """The envelope in ``data`` if well formed, of one of ``kinds``, ours and correctly
        signed by a team member; else why not."""
        from cryptography.exceptions import InvalidSignature

        try:
            env = _dec.decode(data)
        except (msgspec.DecodeError, msgspec.ValidationError, TypeError, ValueError) as e:
            return Refusal(REASON_UNSIGNED, f"not a signed envelope: {e}")
        if env.schema != SEAL_SCHEMA or env.kind not in kinds:
            return Refusal(REASON_UNSIGNED, f"envelope schema {env.schema} kind {env.kind}")
        key = self.keys.team.get(env.sender)
        if key is None:
            return Refusal(REASON_FORGED, f"signer {env.sender!r} is not in the team")
        try:
            key.verify(env.sig, _signed_bytes(env))
        except InvalidSignature:
            return Refusal(REASON_FORGED, f"bad signature for {env.sender!r}")
        if env.to != self.keys.me or env.mission != self.mission:
            return Refusal(REASON_FORGED, f"addressed to {env.to!r} on mission {env.mission!r}")
        return env

    def open_request(self, data: bytes) -> Opened | Refusal:
        """The authenticated request in ``data``, or why it is refused (forged, replayed,
        stale: made for another incarnation of this drone, with the stale reply to send)."""
        env = self._open(data, (REQUEST,))
        if isinstance(env, Refusal):
            return env
        if env.to_boot != self.boot:
            answer = _enc.encode(self._seal(STALE, b"", env.sender, env.sig))
            return Refusal(REASON_STALE, f"request from {env.sender} made for another "
                           f"incarnation of {self.keys.me}", answer)
        with self._lock:
            seen = self._last_seen.setdefault(env.sender, {})
            prev = seen.pop(env.boot, None)  # (put back last: most recently heard)
            last = prev if prev is not None else self._floor.get(env.sender, -1)
            if env.ts_ns <= last:
                if prev is not None:
                    seen[env.boot] = prev
                return Refusal(REASON_REPLAY, f"request from {env.sender} not newer than the "
                               f"last one ({(last - env.ts_ns) / 1e6:.3f} ms older)")
            seen[env.boot] = env.ts_ns
            evicted = 0
            while len(seen) > TOKENS_PER_SENDER:
                old_boot = next(iter(seen))
                self._floor[env.sender] = max(self._floor.get(env.sender, -1),
                                              seen.pop(old_boot))
                evicted += 1
            self.evictions += evicted
        return Opened(env.sender, env.body, env.sig, evicted)

    def memory_size(self) -> int:
        """Entries in the replay memory now (tests, diagnostics)."""
        with self._lock:
            return sum(len(v) for v in self._last_seen.values())

    def open_reply(self, data: bytes, frm: str, nonce: bytes) -> bytes | Refusal:
        """The inner reply in ``data`` if ``frm`` signed it for our request ``nonce``; a
        ``stale`` refusal if ``frm`` answered that the request named another incarnation of
        it (its current token is learned: ask again)."""
        env = self._open(data, (REPLY, STALE))
        if isinstance(env, Refusal):
            return env
        if env.sender != frm:
            return Refusal(REASON_FORGED, f"reply signed by {env.sender!r}, asked {frm!r}")
        if env.bound != nonce:
            return Refusal(REASON_REPLAY, f"reply from {frm} to another request")
        self.know(frm, env.boot)
        if env.kind == STALE:
            return Refusal(REASON_STALE, f"{frm}: first contact or restarted; ask again")
        return env.body


# -- keys --------------------------------------------------------------------------------------


def private_key_pem(key: Ed25519PrivateKey) -> bytes:
    """PKCS#8 PEM of an Ed25519 private key (unencrypted: protect the file)."""
    from cryptography.hazmat.primitives import serialization

    return key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8,
                             serialization.NoEncryption())


def load_private_key(pem: bytes) -> Ed25519PrivateKey:
    """The Ed25519 private key of a PEM file's bytes (ValueError if it is not one)."""
    from cryptography.hazmat.primitives import serialization
    from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey

    key = serialization.load_pem_private_key(pem, password=None)
    if not isinstance(key, Ed25519PrivateKey):
        raise ValueError("not an Ed25519 private key")
    return key


def public_key_text(key: Ed25519PrivateKey | Ed25519PublicKey) -> str:
    """Base64 of the raw 32-byte public key."""
    from cryptography.hazmat.primitives import serialization
    from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey

    pub = key.public_key() if isinstance(key, Ed25519PrivateKey) else key
    raw = pub.public_bytes(serialization.Encoding.Raw, serialization.PublicFormat.Raw)
    return base64.b64encode(raw).decode("ascii")


def parse_team(text: str | bytes) -> dict[str, Ed25519PublicKey]:
    """``{drone id: public key}`` of a team file (JSON ``{"signing_keys": {id: base64}}``);
    ValueError naming the bad entry."""
    from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PublicKey

    doc = json.loads(text)
    entries = doc.get("signing_keys") if isinstance(doc, dict) else None
    if not isinstance(entries, dict):
        raise ValueError('no "signing_keys" object')
    out: dict[str, Ed25519PublicKey] = {}
    for aid, b64 in entries.items():
        try:
            msgspec.convert(aid, AgentId)
            out[aid] = Ed25519PublicKey.from_public_bytes(base64.b64decode(b64, validate=True))
        except (msgspec.ValidationError, binascii.Error, ValueError, TypeError) as e:
            raise ValueError(f"signing key of {str(aid)[:40]!r}: {e}") from None
    return out
