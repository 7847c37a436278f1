"""In-process test double of the Zenoh transport, on a deterministic virtual clock.

A :class:`MemoryNetwork` connects any number of :class:`MemoryTransport` nodes. Everything runs
in the calling thread: ``publish`` queues deliveries on a heap ordered by (virtual time,
sequence number) and, unless ``auto_flush`` is off, delivers the ones due now before it
returns; delayed ones (faults) are delivered by :meth:`MemoryNetwork.advance`. A callback that
publishes does not recurse: its messages are queued and delivered by the same pump loop, in
order. Given the same seeds and the same calls, a run is exactly reproducible.

``request`` runs the queryable's handler inline and compares the virtual latency (query delay +
reply delay, seconds) with the timeout; it does not advance the clock. Lost queries or replies
give None, as in :class:`agent.net.transport.ZenohTransport` (which also waits the timeout).

:meth:`MemoryNetwork.split` partitions the network (messages and liveliness, both ways) until
:meth:`MemoryNetwork.heal`, as a broken link between two routers would.

Key expressions: ``*`` matches exactly one chunk, ``**`` zero or more chunks; two expressions
match when they intersect. ``$*`` sub-chunk wildcards are not supported.
"""

from __future__ import annotations

import heapq
import itertools
import logging
import threading
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from functools import cache, lru_cache

from agent.net.contract import (
    Declared,
    LivelinessCallback,
    QueryHandler,
    SampleCallback,
    default_kind,
)
from agent.net.faults import FaultInjector
from agent.wire import keys

_log = logging.getLogger(f"viscover.{__name__}")


def _chunks(keyexpr: str) -> tuple[str, ...]:
    if not keyexpr or keyexpr.startswith("/") or keyexpr.endswith("/") or "//" in keyexpr:
        raise ValueError(f"invalid key expression {keyexpr!r}")
    return tuple(keyexpr.split("/"))


@lru_cache(maxsize=4096)
def intersects(a: str, b: str) -> bool:
    """True if key expressions ``a`` and ``b`` (with ``*``/``**`` chunks) share a key."""
    ca, cb = _chunks(a), _chunks(b)

    @cache
    def go(i: int, j: int) -> bool:
        if i == len(ca) and j == len(cb):
            return True
        if i < len(ca) and ca[i] == "**":
            return go(i + 1, j) or (j < len(cb) and go(i, j + 1))
        if j < len(cb) and cb[j] == "**":
            return go(i, j + 1) or (i < len(ca) and go(i + 1, j))
        if i == len(ca) or j == len(cb):
            return False
        if ca[i] == "*" or cb[j] == "*" or ca[i] == cb[j]:
            return go(i + 1, j + 1)
        return False

    return go(0, 0)


@dataclass(eq=False)
class _Entry:
    """A declared subscription, queryable, token or liveliness watcher."""

    network: MemoryNetwork
    node: MemoryTransport
    keyexpr: str
    kind: str  # "sub", "queryable", "token", "watch"
    callback: Callable[..., object] | None = None
    on_leave: LivelinessCallback | None = None
    active: bool = True
    seen: set[str] = field(default_factory=set)  # tokens a watcher has been told about

    def undeclare(self) -> None:
        """Remove it from the network (a token's watchers see it leave)."""
        self.network._undeclare(self)


class MemoryNetwork:
    """A deterministic in-process message bus with a virtual clock (seconds)."""

    def __init__(self, auto_flush: bool = True) -> None:
        self.auto_flush = auto_flush
        self.now = 0.0
        self._lock = threading.RLock()
        self._heap: list[tuple[float, int, Callable[[], None]]] = []
        self._seq = itertools.count()
        self._entries: list[_Entry] = []
        self._nodes: dict[str, MemoryTransport] = {}
        self._pumping = False
        self._inside: frozenset[str] | None = None  #: one side of a partition (None: none)

    # -- partitions --------------------------------------------------------------------------
    def _severed(self, a: str, b: str) -> bool:
        return self._inside is not None and ((a in self._inside) != (b in self._inside))

    def split(self, group: Iterable[str]) -> None:
        """Partition the network: nodes in ``group`` and all others (nodes created later
        too) no longer reach each other, messages nor liveliness (each side sees the other's
        tokens leave), until :meth:`heal`."""
        with self._lock:
            self._inside = frozenset(group)
            for watch in self._live("watch"):
                for token in self._live("token"):
                    self._notify(watch, token.keyexpr, False)
            self._maybe_flush()

    def heal(self) -> None:
        """End every partition: tokens on the other side are seen joining again."""
        with self._lock:
            self._inside = None
            for watch in self._live("watch"):
                for token in self._live("token"):
                    self._notify(watch, token.keyexpr, True)
            self._maybe_flush()

    def transport(self, node_id: str, faults: FaultInjector | None = None) -> MemoryTransport:
        """Create a node on this network."""
        with self._lock:
            if node_id in self._nodes and not self._nodes[node_id].closed:
                raise ValueError(f"node {node_id!r} already exists")
            node = MemoryTransport(self, node_id, faults)
            self._nodes[node_id] = node
            return node

    # -- scheduling --------------------------------------------------------------------------
    def _schedule(self, delay_s: float, fn: Callable[[], None]) -> None:
        heapq.heappush(self._heap, (self.now + max(0.0, delay_s), next(self._seq), fn))

    def _pump(self, until: float) -> int:
        """Run queued events due at or before ``until``; returns how many ran."""
        if self._pumping:
            return 0
        self._pumping = True
        ran = 0
        try:
            while self._heap and self._heap[0][0] <= until:
                due, _, fn = heapq.heappop(self._heap)
                self.now = max(self.now, due)
                ran += 1
                try:
                    fn()
                except Exception:
                    _log.exception("memory network: callback failed")
        finally:
            self._pumping = False
        return ran

    def _maybe_flush(self) -> None:
        if self.auto_flush:
            self._pump(self.now)

    def flush(self) -> int:
        """Deliver everything due at the current virtual time; returns the number delivered."""
        with self._lock:
            return self._pump(self.now)

    def advance(self, dt_s: float) -> int:
        """Move the clock forward ``dt_s`` seconds, delivering everything due on the way."""
        with self._lock:
            end = self.now + dt_s
            ran = self._pump(end)
            self.now = max(self.now, end)
            return ran

    def run_until_idle(self, max_s: float = 3600.0) -> int:
        """Deliver every queued event (advancing the clock), at most ``max_s`` seconds ahead."""
        with self._lock:
            return self._pump(self.now + max_s)

    @property
    def pending(self) -> int:
        """Number of queued deliveries."""
        with self._lock:
            return len(self._heap)

    # -- entries -----------------------------------------------------------------------------
    def _add(self, entry: _Entry) -> _Entry:
        with self._lock:
            self._entries.append(entry)
            if entry.kind == "token":
                for watch in self._live("watch"):
                    self._notify(watch, entry.keyexpr, True)
            elif entry.kind == "watch":
                for token in self._live("token"):
                    self._notify(entry, token.keyexpr, True)
            self._maybe_flush()
        return entry

    def _live(self, kind: str) -> list[_Entry]:
        return [e for e in self._entries if e.kind == kind and e.active]

    def _notify(self, watch: _Entry, key: str, alive: bool) -> None:
        if not intersects(watch.keyexpr, key):
            return
        me = watch.node.node_id
        visible = [t for t in self._live("token")
                   if t.keyexpr == key and not self._severed(me, t.node.node_id)]
        if alive:
            if key in watch.seen or not visible:
                return
            watch.seen.add(key)
        else:
            if visible or key not in watch.seen:
                return
            watch.seen.discard(key)
        cb = watch.callback if alive else watch.on_leave

        def run() -> None:
            if watch.active and cb is not None:
                cb(key)

        self._schedule(0.0, run)

    def _undeclare(self, entry: _Entry) -> None:
        with self._lock:
            if not entry.active:
                return
            entry.active = False
            self._entries.remove(entry)
            if entry.kind == "token":
                for watch in self._live("watch"):
                    self._notify(watch, entry.keyexpr, False)
            self._maybe_flush()

    def kill(self, node_id: str) -> None:
        """Simulate a crash of ``node_id``: all it declared vanishes at once."""
        node = self._nodes.get(node_id)
        if node is not None:
            node.close()

    # -- messaging ---------------------------------------------------------------------------
    def _publish(self, sender: MemoryTransport, key: str, payload: bytes, kind: str) -> None:
        with self._lock:
            delays: tuple[float, ...] = (0.0,)
            if sender.faults is not None:
                delays = sender.faults.decide(kind, None, "out").delays_s
            for delay in delays:
                self._schedule(delay, lambda: self._arrive(sender.node_id, key, payload, kind))
            self._maybe_flush()

    def _arrive(self, sender: str, key: str, payload: bytes, kind: str) -> None:
        for sub in self._live("sub"):
            if not intersects(sub.keyexpr, key) or self._severed(sender, sub.node.node_id):
                continue
            delays: tuple[float, ...] = (0.0,)
            if sub.node.faults is not None:
                delays = sub.node.faults.decide(kind, sender, "in").delays_s
            for delay in delays:
                def deliver(sub: _Entry = sub, key: str = key, payload: bytes = payload) -> None:
                    self._deliver(sub, key, payload)

                self._schedule(delay, deliver)

    @staticmethod
    def _deliver(sub: _Entry, key: str, payload: bytes) -> None:
        if sub.active and sub.callback is not None:
            sub.callback(key, payload)

    def _request(
        self, sender: MemoryTransport, key: str, payload: bytes, timeout: float, kind: str
    ) -> bytes | None:
        with self._lock:
            delays: tuple[float, ...] = (0.0,)
            if sender.faults is not None:
                delays = sender.faults.decide(kind, keys.try_agent_of(key), "out").delays_s
            if not delays or delays[0] >= timeout:
                return None
            targets = [q for q in self._live("queryable") if intersects(q.keyexpr, key)
                       and not self._severed(sender.node_id, q.node.node_id)]
            if not targets:
                return None
            target = targets[0]
            handler = target.callback
            if handler is None:
                return None
            result: bytes | None = None
            for i, _ in enumerate(delays):  # a duplicated query runs the handler again
                try:
                    out = handler(payload, key)
                except Exception:
                    _log.exception("memory queryable %s: handler failed", target.keyexpr)
                    out = None
                if i == 0:
                    result = out if isinstance(out, bytes) or out is None else bytes(out)  # type: ignore[call-overload]
            if result is None:
                return None
            latency = delays[0]
            if target.node.faults is not None:
                reply = target.node.faults.decide(f"{kind}.reply", sender.node_id, "out")
                if reply.dropped:
                    return None
                latency += reply.delays_s[0]
            return result if latency < timeout else None


class MemoryTransport:
    """A node of a :class:`MemoryNetwork`; implements :class:`agent.net.transport.Transport`."""

    def __init__(
        self, network: MemoryNetwork, node_id: str, faults: FaultInjector | None = None
    ) -> None:
        self.network = network
        self.node_id = node_id
        self.faults = faults
        self.closed = False
        self._entries: list[_Entry] = []

    def _check_open(self) -> None:
        if self.closed:
            raise RuntimeError(f"transport {self.node_id} is closed")

    def _declare(self, entry: _Entry) -> Declared:
        self._check_open()
        _chunks(entry.keyexpr)
        self._entries.append(entry)
        return self.network._add(entry)

    def publish(self, key: str, payload: bytes, kind: str | None = None) -> None:
        """Publish ``payload`` on ``key`` (delivered now if due and auto_flush is on)."""
        self._check_open()
        self.network._publish(self, key, bytes(payload), default_kind(key, kind))

    def subscribe(self, keyexpr: str, callback: SampleCallback) -> Declared:
        """Call ``callback(key, payload)`` for each matching sample."""
        return self._declare(_Entry(self.network, self, keyexpr, "sub", callback))

    def declare_queryable(self, key: str, handler: QueryHandler) -> Declared:
        """Answer queries on ``key`` with ``handler(payload, selector)``."""
        return self._declare(_Entry(self.network, self, key, "queryable", handler))

    def request(
        self, key: str, payload: bytes, timeout: float, kind: str | None = None
    ) -> bytes | None:
        """One-to-one query, handled inline; None on loss, no queryable or virtual timeout."""
        if self.closed:
            return None
        return self.network._request(
            self, key, bytes(payload), timeout, default_kind(key, kind, "query")
        )

    def declare_liveliness(self, key: str) -> Declared:
        """Declare a liveliness token on ``key``."""
        return self._declare(_Entry(self.network, self, key, "token"))

    def watch_liveliness(
        self, keyexpr: str, on_join: LivelinessCallback, on_leave: LivelinessCallback
    ) -> Declared:
        """Report matching tokens joining (existing ones too) and leaving."""
        return self._declare(
            _Entry(self.network, self, keyexpr, "watch", on_join, on_leave=on_leave)
        )

    def close(self) -> None:
        """Undeclare everything this node declared (watchers see its tokens leave)."""
        if self.closed:
            return
        self.closed = True
        for entry in list(self._entries):
            entry.undeclare()
        self._entries.clear()
