"""Signed trade messages: a trade query or reply proves which drone sent it.

The secured router (``broker_config/router_secure.json5``) ties every key to its owner by
certificate common name, but any drone may *query* any peer's ``trade/<id>`` queryable, and the
application never learns who asked: zenoh-python's ``Query``/``Sample`` carry no authenticated
identity (``source_info`` is chosen by the sender, and the certificate name stays inside the
router's access control). So every trade request and reply travels in a :class:`Sealed`
envelope signed with the sender's Ed25519 key and checked against the team's public keys.

What is signed: a domain tag, the envelope's schema, kind (request / reply), the mission, the
sender, the addressee, the sender's wall-clock time in ns, ``bound`` and the inner message.

* A request is accepted once: its time must be within ``max_age_s`` of the receiver's clock
  and later than the last request accepted from that sender (per receiver), so a recorded
  request replayed later is refused, and so is a copy sent to another drone or mission.
* A reply is bound to its request (``bound`` = the request's signature): it cannot answer any
  other request, and it must come from the drone the request was sent to.

Refusals are :class:`Refusal` values (reason, detail), never exceptions: ``unsigned`` (not an
envelope), ``forged`` (unknown signer, bad signature, wrong addressee or mission, inner sender
not the signer) or ``replay`` (old or repeated). Drones' clocks must agree within ``max_age_s``
(NTP or chrony on the companion computers).
"""

from __future__ import annotations

import base64
import binascii
import json
import threading
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Annotated, Final, NamedTuple

import msgspec
from cryptography.exceptions import InvalidSignature
from cryptography.hazmat.primitives import serialization
from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey, Ed25519PublicKey

#: Envelope schema spoken by this build.
SEAL_SCHEMA: Final = 1
#: Kinds of envelope.
REQUEST: Final = 0
REPLY: Final = 1
#: Reject reasons (counted like the codec's).
REASON_UNSIGNED: Final = "unsigned"
REASON_FORGED: Final = "forged"
REASON_REPLAY: Final = "replay"
#: Default acceptance window of a request's time stamp [s].
DEFAULT_MAX_AGE_S: Final = 30.0

_DOMAIN: Final = b"viscover/trade/v1"
_SIG_LEN: Final = 64
#: Largest inner message [bytes] (two landmark sets of a million landmarks and the rest).
_MAX_BODY: Final = 32_000_000
#: An agent id or mission name (as :data:`agent.wire.keys.ID_PATTERN`).
AgentId = Annotated[str, msgspec.Meta(pattern=r"^[A-Za-z0-9_-]{1,32}$")]


class Sealed(msgspec.Struct, array_like=True, frozen=True):
    """A signed trade request or reply (see the module docstring)."""

    schema: int
    kind: Annotated[int, msgspec.Meta(ge=REQUEST, le=REPLY)]
    mission: AgentId
    sender: AgentId
    to: AgentId
    ts_ns: Annotated[int, msgspec.Meta(ge=0, le=2**63 - 1)]
    bound: Annotated[bytes, msgspec.Meta(max_length=_SIG_LEN)]
    body: Annotated[bytes, msgspec.Meta(max_length=_MAX_BODY)]
    sig: Annotated[bytes, msgspec.Meta(min_length=_SIG_LEN, max_length=_SIG_LEN)]


class Refusal(NamedTuple):
    """Why an envelope was refused: a reject reason and a (network-derived) detail."""

    reason: str
    detail: str


class Opened(NamedTuple):
    """An accepted request: its authenticated sender, the inner message, and the nonce its
    reply must be bound to."""

    sender: str
    body: bytes
    nonce: bytes


@dataclass(frozen=True)
class SigningKeys:
    """One drone's signing key and the team's public keys (drone id -> key)."""

    me: str
    private: Ed25519PrivateKey = field(repr=False)
    team: Mapping[str, Ed25519PublicKey] = field(repr=False)
    max_age_s: float = DEFAULT_MAX_AGE_S


_enc = msgspec.msgpack.Encoder()
_dec = msgspec.msgpack.Decoder(Sealed)


def _signed_bytes(schema: int, kind: int, mission: str, sender: str, to: str, ts_ns: int,
                  bound: bytes, body: bytes) -> bytes:
    """The canonical byte string an envelope's signature covers."""
    return _enc.encode((_DOMAIN, schema, kind, mission, sender, to, ts_ns, bound, body))


class TradeSeal:
    """Seals this drone's trade messages and opens its peers' (thread-safe).

    Args:
        keys: this drone's key and the team's public keys.
        mission: the mission name (a request for another mission is refused).
        clock_ns: wall clock [ns since the epoch] (tests pass a fake one).
    """

    def __init__(self, keys: SigningKeys, mission: str,
                 clock_ns: Callable[[], int] = time.time_ns) -> None:
        self.keys = keys
        self.mission = mission
        self._clock = clock_ns
        self._lock = threading.Lock()
        self._last_sent = 0
        self._last_seen: dict[str, int] = {}

    def _stamp(self) -> int:
        """A wall-clock time stamp [ns] later than every one this seal issued before."""
        with self._lock:
            self._last_sent = max(self._clock(), self._last_sent + 1)
            return self._last_sent

    def _seal(self, kind: int, body: bytes, to: str, bound: bytes) -> Sealed:
        """The envelope of ``body`` to ``to``, signed now."""
        ts = self._stamp()
        me = self.keys.me
        sig = self.keys.private.sign(
            _signed_bytes(SEAL_SCHEMA, kind, self.mission, me, to, ts, bound, body))
        return Sealed(SEAL_SCHEMA, kind, self.mission, me, to, ts, bound, body, sig)

    def seal_request(self, body: bytes, to: str) -> tuple[bytes, bytes]:
        """(envelope bytes, nonce) of request ``body`` to drone ``to``; the nonce is what
        the reply must be bound to."""
        env = self._seal(REQUEST, body, to, b"")
        return _enc.encode(env), env.sig

    def seal_reply(self, body: bytes, to: str, nonce: bytes) -> bytes:
        """Envelope bytes of reply ``body`` to ``to``'s request ``nonce``."""
        return _enc.encode(self._seal(REPLY, body, to, nonce))

    def _open(self, data: bytes, kind: int) -> Sealed | Refusal:
        """The envelope in ``data`` if well formed, ours and correctly signed by a team
        member; else why not."""
        try:
            env = _dec.decode(data)
        except (msgspec.DecodeError, msgspec.ValidationError, TypeError, ValueError) as e:
            return Refusal(REASON_UNSIGNED, f"not a signed envelope: {e}")
        if env.schema != SEAL_SCHEMA or env.kind != kind:
            return Refusal(REASON_UNSIGNED, f"envelope schema {env.schema} kind {env.kind}")
        key = self.keys.team.get(env.sender)
        if key is None:
            return Refusal(REASON_FORGED, f"signer {env.sender!r} is not in the team")
        try:
            key.verify(env.sig, _signed_bytes(env.schema, env.kind, env.mission, env.sender,
                                              env.to, env.ts_ns, env.bound, env.body))
        except InvalidSignature:
            return Refusal(REASON_FORGED, f"bad signature for {env.sender!r}")
        if env.to != self.keys.me or env.mission != self.mission:
            return Refusal(REASON_FORGED, f"addressed to {env.to!r} on mission {env.mission!r}")
        return env

    def open_request(self, data: bytes) -> Opened | Refusal:
        """The authenticated request in ``data``, or why it is refused (forged, replayed)."""
        env = self._open(data, REQUEST)
        if isinstance(env, Refusal):
            return env
        age_s = (self._clock() - env.ts_ns) / 1e9
        if abs(age_s) > self.keys.max_age_s:
            return Refusal(REASON_REPLAY, f"request from {env.sender} {age_s:+.1f} s old")
        with self._lock:
            last = self._last_seen.get(env.sender, -1)
            if env.ts_ns <= last:
                return Refusal(REASON_REPLAY, f"request from {env.sender} not newer than the "
                               f"last one ({(last - env.ts_ns) / 1e6:.3f} ms older)")
            self._last_seen[env.sender] = env.ts_ns
        return Opened(env.sender, env.body, env.sig)

    def open_reply(self, data: bytes, frm: str, nonce: bytes) -> bytes | Refusal:
        """The inner reply in ``data`` if ``frm`` signed it for our request ``nonce``."""
        env = self._open(data, REPLY)
        if isinstance(env, Refusal):
            return env
        if env.sender != frm:
            return Refusal(REASON_FORGED, f"reply signed by {env.sender!r}, asked {frm!r}")
        if env.bound != nonce:
            return Refusal(REASON_REPLAY, f"reply from {frm} to another request")
        return env.body


# -- keys --------------------------------------------------------------------------------------


def private_key_pem(key: Ed25519PrivateKey) -> bytes:
    """PKCS#8 PEM of an Ed25519 private key (unencrypted: protect the file)."""
    return key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8,
                             serialization.NoEncryption())


def load_private_key(pem: bytes) -> Ed25519PrivateKey:
    """The Ed25519 private key of a PEM file's bytes (ValueError if it is not one)."""
    key = serialization.load_pem_private_key(pem, password=None)
    if not isinstance(key, Ed25519PrivateKey):
        raise ValueError("not an Ed25519 private key")
    return key


def public_key_text(key: Ed25519PrivateKey | Ed25519PublicKey) -> str:
    """Base64 of the raw 32-byte public key."""
    pub = key.public_key() if isinstance(key, Ed25519PrivateKey) else key
    raw = pub.public_bytes(serialization.Encoding.Raw, serialization.PublicFormat.Raw)
    return base64.b64encode(raw).decode("ascii")


def parse_team(text: str | bytes) -> dict[str, Ed25519PublicKey]:
    """``{drone id: public key}`` of a team file (JSON ``{"signing_keys": {id: base64}}``);
    ValueError naming the bad entry."""
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
