"""The Zenoh implementation of the transport contract (:mod:`agent.net.contract`, whose names
this module re-exports): an Eclipse Zenoh session whose callbacks run on worker threads
(:class:`agent.net.worker.Worker`), never on Zenoh's, with fault injection on every message.

Faults (:class:`agent.net.faults.FaultInjector`) apply to outgoing publishes, incoming samples,
outgoing queries (kind = the request kind) and outgoing replies (kind = ``<kind>.reply``).
The sender's id, the kind and the requester's timeout travel in the Zenoh attachment
(:mod:`agent.net.attachment`).

(Over 400 lines, not split: it is one adapter; the session's handles, worker threads, fault
hooks and hedged queries only make sense together.)
"""

from __future__ import annotations

import itertools
import logging
import queue
import threading
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import zenoh

from agent.net.attachment import Meta, decode_meta, encode_meta
from agent.net.contract import (
    Declared,
    HedgedReply,
    HedgingTransport,
    LivelinessCallback,
    QueryHandler,
    SampleCallback,
    Transport,
    default_kind,
)
from agent.net.faults import FaultInjector
from agent.net.hedge import Got, Hedge
from agent.net.worker import Worker
from agent.wire import keys

_log = logging.getLogger(f"viscover.{__name__}")

class _Handle:
    """A :class:`Declared` wrapping a Zenoh entity, flagged inactive once undeclared."""

    def __init__(self, owner: ZenohTransport, entity: Any) -> None:
        self._owner = owner
        self._entity = entity
        self.active = True

    def undeclare(self) -> None:
        if not self.active:
            return
        self.active = False
        self._owner._forget(self)
        if not self._owner.closed:
            try:
                self._entity.undeclare()
            except zenoh.ZError as exc:
                _log.debug("undeclare failed: %s", exc)


class ZenohTransport:
    """:class:`Transport` over a Zenoh session.

    Args:
        config: path of a json5 config file, or a ``zenoh.Config``.
        faults: optional fault injector applied as described in the module docstring.
        node_id: this node's id (sent as the sender of every message; used for partitions).
        query_workers: threads running queryable handlers (1 keeps handlers serial).
    """

    def __init__(
        self,
        config: str | Path | zenoh.Config,
        faults: FaultInjector | None = None,
        node_id: str = "node",
        *,
        query_workers: int = 1,
    ) -> None:
        cfg = config if isinstance(config, zenoh.Config) else zenoh.Config.from_file(str(config))
        self.node_id = node_id
        self.faults = faults
        self.closed = False
        self._lock = threading.Lock()
        self._handles: list[_Handle] = []
        self._closing = threading.Event()
        self._session = zenoh.open(cfg)
        # Samples and liveliness events: one ordered worker. Queries: their own workers so a
        # handler that itself sends a request cannot stall sample delivery. Timers: delayed
        # sends (faults) so neither of the others is held up by a sleep.
        self._events = Worker(f"zenoh-events-{node_id}")
        self._queries = [Worker(f"zenoh-queries-{node_id}-{i}") for i in range(query_workers)]
        self._query_rr = itertools.count()
        self._timers = Worker(f"zenoh-timers-{node_id}")

    @property
    def session(self) -> zenoh.Session:
        """The underlying Zenoh session (do not close it directly)."""
        return self._session

    # -- helpers -----------------------------------------------------------------------------
    def _track(self, entity: Any) -> _Handle:
        handle = _Handle(self, entity)
        with self._lock:
            self._handles.append(handle)
        return handle

    def _forget(self, handle: _Handle) -> None:
        with self._lock:
            if handle in self._handles:
                self._handles.remove(handle)

    def _check_open(self) -> None:
        if self.closed:
            raise RuntimeError(f"transport {self.node_id} is closed")

    # -- pub/sub -----------------------------------------------------------------------------
    def publish(self, key: str, payload: bytes, kind: str | None = None) -> None:
        """Publish ``payload`` on ``key``; faults may drop, delay or duplicate it."""
        self._check_open()
        kind = default_kind(key, kind)
        attachment = encode_meta(Meta(self.node_id, kind))
        delays: tuple[float, ...] = (0.0,)
        if self.faults is not None:
            delays = self.faults.decide(kind, None, "out").delays_s
        for delay in delays:
            if delay <= 0.0:
                self._put(key, payload, attachment)
            else:
                self._timers.submit(lambda: self._put(key, payload, attachment), delay)

    def _put(self, key: str, payload: bytes, attachment: bytes) -> None:
        if not self.closed:
            self._session.put(key, payload, attachment=attachment)

    def subscribe(self, keyexpr: str, callback: SampleCallback) -> Declared:
        """Deliver samples matching ``keyexpr`` to ``callback(key, payload)`` on a worker."""
        self._check_open()
        holder: list[_Handle] = []

        def deliver(key: str, payload: bytes) -> None:
            if (not holder or holder[0].active) and not self.closed:
                callback(key, payload)

        def arrived(key: str, payload: bytes, meta: Meta | None) -> None:
            delays: tuple[float, ...] = (0.0,)
            if self.faults is not None:
                kind = meta.kind if meta else default_kind(key, None)
                peer = meta.sender if meta else keys.try_agent_of(key)
                delays = self.faults.decide(kind, peer, "in").delays_s
            for delay in delays:
                if delay <= 0.0:
                    deliver(key, payload)
                else:
                    def later(key: str = key, payload: bytes = payload) -> None:
                        self._events.submit(lambda: deliver(key, payload))

                    self._timers.submit(later, delay)

        def on_sample(sample: zenoh.Sample) -> None:  # Zenoh thread: copy and hand over only
            key = str(sample.key_expr)
            payload = sample.payload.to_bytes()
            att = sample.attachment
            meta = decode_meta(att.to_bytes() if att is not None else None)
            self._events.submit(lambda: arrived(key, payload, meta))

        sub = self._session.declare_subscriber(keyexpr, on_sample)
        handle = self._track(sub)
        holder.append(handle)
        return handle

    # -- queries -----------------------------------------------------------------------------
    def declare_queryable(self, key: str, handler: QueryHandler) -> Declared:
        """Answer queries on ``key``: ``handler(payload, selector)`` runs on a query worker."""
        self._check_open()
        holder: list[_Handle] = []

        def finish(query: zenoh.Query, reply: bytes | None) -> None:
            try:
                if reply is not None and not self.closed:
                    query.reply(key, reply)
            except zenoh.ZError as exc:
                _log.debug("reply on %s failed: %s", key, exc)
            finally:
                query.drop()  # type: ignore[no-untyped-call]

        def serve(query: zenoh.Query, payload: bytes, selector: str, meta: Meta | None) -> None:
            reply: bytes | None = None
            try:
                if (not holder or holder[0].active) and not self.closed:
                    reply = handler(payload, selector)
            except Exception:
                _log.exception("queryable %s: handler failed", key)
                reply = None
            if reply is None or self.faults is None:
                finish(query, reply)
                return
            kind = f"{meta.kind if meta else default_kind(key, None, 'query')}.reply"
            peer = meta.sender if meta else None
            decision = self.faults.decide(kind, peer, "out")
            if decision.dropped:
                # A lost reply: hold the query so the requester waits for its timeout.
                hold_s = meta.timeout_s if meta and meta.timeout_s > 0 else 0.0
                self._timers.submit(lambda: finish(query, None), hold_s)
                return
            # Zenoh consolidates replies on one key, so duplicate replies collapse to one.
            self._timers.submit(lambda: finish(query, reply), decision.delays_s[0])

        def on_query(query: zenoh.Query) -> None:  # Zenoh thread: hand over only
            pl = query.payload
            payload = pl.to_bytes() if pl is not None else b""
            att = query.attachment
            meta = decode_meta(att.to_bytes() if att is not None else None)
            selector = str(query.selector)
            worker = self._queries[next(self._query_rr) % len(self._queries)]
            if not worker.submit(lambda: serve(query, payload, selector, meta)):
                query.drop()  # type: ignore[no-untyped-call]

        qbl = self._session.declare_queryable(key, on_query)
        handle = self._track(qbl)
        holder.append(handle)
        return handle

    def request(
        self, key: str, payload: bytes, timeout: float, kind: str | None = None
    ) -> bytes | None:
        """Query ``key`` and return the first reply payload, or None.

        Blocks the caller for at most about ``timeout`` seconds. Must not be called from a
        Zenoh callback (the transport never runs user code on one).
        """
        if self.closed:
            return None
        kind = default_kind(key, kind, "query")
        deadline = time.monotonic() + timeout
        delays: tuple[float, ...] = (0.0,)
        if self.faults is not None:
            delays = self.faults.decide(kind, keys.try_agent_of(key), "out").delays_s
        if not delays or delays[0] >= timeout:
            self._closing.wait(timeout)  # lost (or too late) like a real message: time out
            return None
        attachment = encode_meta(Meta(self.node_id, kind, float(timeout)))
        for extra in delays[1:]:  # duplicated query: fire and forget the extra copy
            self._timers.submit(
                lambda: self._get_detached(key, payload, attachment, deadline), extra
            )
        if delays[0] > 0.0 and self._closing.wait(delays[0]):
            return None
        remaining = deadline - time.monotonic()
        if remaining <= 0.0 or self.closed:
            return None
        try:
            replies = self._session.get(
                key, payload=payload, attachment=attachment, timeout=remaining
            )
            for reply in replies:
                if reply.ok is not None:
                    return reply.ok.payload.to_bytes()
        except zenoh.ZError as exc:
            _log.debug("get %s failed: %s", key, exc)
        return None

    def request_hedged(
        self, key: str, make_payload: Callable[[int], bytes], offsets_s: Sequence[float],
        timeout: float, kind: str | None = None,
    ) -> HedgedReply:
        """Send the query ``key`` as copies on the schedule ``offsets_s`` [s after the call],
        each kept waiting until ``timeout`` [s]; the first reply of any copy (see
        :class:`HedgedReply`). Each copy meets the fault injector on its own (kind = ``kind``)
        and its reply too, as a separate query. As :meth:`request`, returns at once (None)
        when every copy sent has ended without a reply (no queryable) and none was lost on
        the way. Must not be called from a Zenoh callback."""
        if self.closed:
            return HedgedReply(None)
        kind = default_kind(key, kind, "query")
        peer = keys.try_agent_of(key)
        t0 = time.monotonic()
        deadline = t0 + timeout
        h = Hedge()
        sent = nbytes = 0
        for k, off in enumerate(offsets_s):
            if off >= timeout:
                break
            first = self._await_reply(h, min(t0 + off, deadline))
            if first is not None or self.closed or h.over():
                return self._hedged_reply(first, sent, nbytes)
            payload = make_payload(k)
            sent += 1
            nbytes += len(payload)
            issued = time.monotonic()
            remaining = deadline - issued
            if remaining <= 0.0:
                break
            delays: tuple[float, ...] = (0.0,)
            if self.faults is not None:
                delays = self.faults.decide(kind, peer, "out").delays_s
            if not delays or min(delays) >= remaining:
                h.lost = True  # dropped (or too late): nobody will tell us
            attachment = encode_meta(Meta(self.node_id, kind, float(remaining)))
            for delay in delays:
                if delay >= remaining:
                    continue
                send = self._copy_sender(h, k, issued, key, payload, attachment, deadline)
                h.opened()
                if delay <= 0.0:
                    send()
                elif not self._timers.submit(send, delay):
                    h.ended(k)
        return self._hedged_reply(self._await_reply(h, deadline), sent, nbytes)

    def _copy_sender(self, h: Hedge, k: int, issued: float, key: str, payload: bytes,
                     attachment: bytes, deadline: float) -> Callable[[], None]:
        """A callable sending copy ``k`` (sent at monotonic time ``issued``) whose replies and
        end go to ``h``."""

        def on_reply(reply: zenoh.Reply) -> None:  # Zenoh thread: copy and hand over only
            if reply.ok is not None:
                h.got.put((k, issued, time.monotonic(), reply.ok.payload.to_bytes()))

        def send() -> None:
            remaining = deadline - time.monotonic()
            if remaining <= 0.0 or self.closed:
                h.ended(k)
                return
            try:
                self._session.get(key, zenoh.handlers.Callback(on_reply, lambda: h.ended(k)),
                                  payload=payload, attachment=attachment, timeout=remaining)
            except zenoh.ZError as exc:
                _log.debug("get %s failed: %s", key, exc)
                h.ended(k)

        return send

    def _await_reply(self, h: Hedge, until: float) -> Got | None:
        """The first reply of ``h`` before monotonic time ``until`` (copy, time sent, time
        received, payload), or None: at ``until``, once every copy ended without a reply
        (:meth:`Hedge.over`), or at once when the transport closes."""
        while not self._closing.is_set():
            wait = until - time.monotonic()
            try:
                item = h.got.get(timeout=min(0.05, wait)) if wait > 0.0 else h.got.get_nowait()
            except queue.Empty:
                if wait <= 0.0:
                    return None
                continue
            if item[3] is not None:
                return (item[0], item[1], item[2], item[3])
            if h.over():
                return None
        return None

    @staticmethod
    def _hedged_reply(first: Got | None, sent: int, nbytes: int) -> HedgedReply:
        if first is None:
            return HedgedReply(None, sent=sent, bytes_out=nbytes)
        k, issued, received, payload = first
        return HedgedReply(payload, k, max(0.0, received - issued), sent, nbytes)

    def _get_detached(self, key: str, payload: bytes, attachment: bytes, deadline: float) -> None:
        remaining = deadline - time.monotonic()
        if remaining > 0.0 and not self.closed:
            self._session.get(
                key,
                lambda _reply: None,
                payload=payload,
                attachment=attachment,
                timeout=remaining,
            )

    # -- liveliness --------------------------------------------------------------------------
    def declare_liveliness(self, key: str) -> Declared:
        """Declare a liveliness token on ``key``."""
        self._check_open()
        return self._track(self._session.liveliness().declare_token(key))

    def watch_liveliness(
        self, keyexpr: str, on_join: LivelinessCallback, on_leave: LivelinessCallback
    ) -> Declared:
        """Call ``on_join(key)``/``on_leave(key)`` on the events worker as tokens come and go."""
        self._check_open()
        holder: list[_Handle] = []

        def dispatch(key: str, alive: bool) -> None:
            # Before ``holder`` is filled the declaration is still returning: deliver (the
            # history of existing tokens can arrive first, and it is sent only once).
            if (not holder or holder[0].active) and not self.closed:
                (on_join if alive else on_leave)(key)

        def on_sample(sample: zenoh.Sample) -> None:  # Zenoh thread
            key = str(sample.key_expr)
            alive = sample.kind == zenoh.SampleKind.PUT
            self._events.submit(lambda: dispatch(key, alive))

        sub = self._session.liveliness().declare_subscriber(keyexpr, on_sample, history=True)
        handle = self._track(sub)
        holder.append(handle)
        return handle

    # -- lifecycle ---------------------------------------------------------------------------
    def close(self, timeout_s: float = 5.0) -> None:
        """Stop the workers (each joined for at most ``timeout_s`` seconds; a handler still
        running after that is left behind with a warning), drop pending queries, close the
        session."""
        with self._lock:
            if self.closed:
                return
            self.closed = True
            handles = list(self._handles)
            self._handles.clear()
        self._closing.set()
        for handle in handles:
            handle.active = False
        pending: list[Callable[[], None]] = []
        for worker in (self._events, *self._queries, self._timers):
            pending.extend(worker.stop(timeout_s))
        # Pending query tasks and held replies end by dropping their query: run them now so
        # no requester is left waiting (handlers see closed=True and reply nothing).
        for fn in pending:
            try:
                fn()
            except Exception:
                _log.exception("pending task failed during close")
        self._session.close()  # type: ignore[no-untyped-call]

    def __enter__(self) -> ZenohTransport:
        return self

    def __exit__(self, *_exc: object) -> None:
        self.close()

__all__ = ["Declared", "HedgedReply", "HedgingTransport", "LivelinessCallback", "QueryHandler",
           "SampleCallback", "Transport", "ZenohTransport", "default_kind"]
