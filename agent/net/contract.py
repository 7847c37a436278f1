"""The transport contract agent code programs against (every implementation keeps it).


:class:`Transport` is what agent code programs against; :class:`agent.net.transport.ZenohTransport`
runs it over an Eclipse Zenoh session, :class:`agent.net.memory.MemoryTransport` in process.

Semantics shared by every implementation:

* ``publish(key, payload, kind)``: best-effort one-to-many. ``kind`` names the message class
  for fault injection (default: the key's kind chunk, see :mod:`agent.wire.keys`).
* ``subscribe(keyexpr, callback)``: ``callback(key, payload)`` runs on a transport worker
  thread (never on a Zenoh thread), one sample at a time, in arrival order.
* ``declare_queryable(key, handler)``: ``handler(payload, selector) -> bytes | None`` runs on a
  worker thread; returning None sends no reply (the requester gets None at once).
* ``request(key, payload, timeout_s)``: one-to-one query; the first reply's payload, or None on
  timeout, no queryable, a lost query or lost reply (then after ``timeout_s`` seconds).
* ``request_hedged(key, make_payload, offsets_s, timeout_s)`` (:class:`HedgingTransport`, the
  Zenoh transport only): the same query sent as several copies, copy ``k`` at ``offsets_s[k]``
  seconds, every copy kept waiting until ``timeout_s``; the first reply of any copy wins and
  says which copy it answered and its round trip (:class:`HedgedReply`). For idempotent
  requests only: the responder may see every copy.
* ``declare_liveliness(key)`` / ``watch_liveliness(keyexpr, on_join, on_leave)``: presence;
  the watcher is told of tokens that already exist (``on_join``) and of every later change.
* Every ``declare_*``/``subscribe``/``watch_*`` returns a :class:`Declared` handle.

Faults (:class:`agent.net.faults.FaultInjector`) apply to outgoing publishes, incoming samples,
outgoing queries (kind = the request kind) and outgoing replies (kind = ``<kind>.reply``).
The sender's id, the kind and the requester's timeout travel in the Zenoh attachment.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import NamedTuple, Protocol, runtime_checkable

from agent.wire import keys

SampleCallback = Callable[[str, bytes], None]
QueryHandler = Callable[[bytes, str], bytes | None]
LivelinessCallback = Callable[[str], None]


@runtime_checkable
class Declared(Protocol):
    """Handle of a subscription, queryable, liveliness token or watcher."""

    def undeclare(self) -> None:
        """Stop it; idempotent."""


@runtime_checkable
class Transport(Protocol):
    """Messaging used by an agent process (see the module docstring for semantics)."""

    node_id: str

    def publish(self, key: str, payload: bytes, kind: str | None = None) -> None:
        """Publish ``payload`` on the concrete ``key``."""

    def subscribe(self, keyexpr: str, callback: SampleCallback) -> Declared:
        """Call ``callback(key, payload)`` for each sample matching ``keyexpr``."""

    def declare_queryable(self, key: str, handler: QueryHandler) -> Declared:
        """Answer queries on ``key`` with ``handler(payload, selector)``."""

    def request(
        self, key: str, payload: bytes, timeout: float, kind: str | None = None
    ) -> bytes | None:
        """One-to-one query; reply payload or None after at most ``timeout`` seconds."""

    def declare_liveliness(self, key: str) -> Declared:
        """Declare a liveliness token on ``key`` (gone when undeclared or the node dies)."""

    def watch_liveliness(
        self, keyexpr: str, on_join: LivelinessCallback, on_leave: LivelinessCallback
    ) -> Declared:
        """Report tokens matching ``keyexpr`` appearing (existing ones too) and vanishing."""

    def close(self) -> None:
        """Undeclare everything and release resources; idempotent."""


class HedgedReply(NamedTuple):
    """What :meth:`HedgingTransport.request_hedged` got: the first reply's ``payload`` (None:
    no copy answered within the timeout), the index of the ``copy`` it answered (-1: none),
    that copy's round trip ``rtt_s`` [s] (None: none), the copies ``sent`` and the bytes they
    carried (``bytes_out``; copies lost by fault injection count: they left the program)."""

    payload: bytes | None
    copy: int = -1
    rtt_s: float | None = None
    sent: int = 0
    bytes_out: int = 0


@runtime_checkable
class HedgingTransport(Protocol):
    """A transport that can send one query as several copies and take the first reply."""

    def request_hedged(
        self, key: str, make_payload: Callable[[int], bytes], offsets_s: Sequence[float],
        timeout: float, kind: str | None = None,
    ) -> HedgedReply:
        """Send copy ``k`` (payload ``make_payload(k)``) at ``offsets_s[k]`` seconds after the
        call (offsets at or after ``timeout`` are not sent, nor any once a reply arrived);
        return the first reply of any copy, or none after ``timeout`` seconds."""


def default_kind(key: str, kind: str | None, fallback: str = "data") -> str:
    """The fault-injection kind of a message: ``kind`` or the key's kind chunk."""
    if kind:
        return kind
    return keys.kind_of(key) or fallback
