"""A ROS 2 node on a Zenoh session as rmw_zenoh makes one (conventions in
:mod:`groundstation.ros2.rmw`): its node token, a publisher per topic (a Zenoh publisher on the
topic's data key, an ``MP`` liveliness token, a GID, a sequence number, the attachment on every
sample) and subscriptions (an ``MS`` token and a Zenoh subscriber).

A subscription takes samples whatever type hash their key carries (its Zenoh key ends in
``*``), so Humble and Jazzy publishers both reach it; its token names this node's own
convention. Payloads are handed to a worker thread (never run on Zenoh's); one that does not
decode as the topic's type is counted and logged (rate-limited), never raised.
"""

from __future__ import annotations

import itertools
import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import zenoh

from agent.net.rejects import LockedRejectCounter, rate_limited_log
from agent.net.worker import Worker
from groundstation.ros2 import rmw
from groundstation.ros2 import typesupport as ts

_log = logging.getLogger(f"viscover.{__name__}")


@dataclass
class Publisher:
    """One topic's publisher: its data key, token, GID and next sequence number."""

    topic: str
    typename: str
    key: str
    token: str
    gid: bytes
    zpub: Any
    ztoken: Any
    lock: threading.Lock = field(default_factory=threading.Lock)
    sequence: int = 0


class RosNode:
    """Node ``name`` in ``namespace`` on ``session`` (not owned: the caller closes it), in
    ROS domain ``domain``, type hashes of ``distro``."""

    def __init__(self, session: zenoh.Session, domain: int, distro: rmw.Distro,
                 namespace: str, name: str = "bridge", node_id: int = 0) -> None:
        self.session, self.domain, self.distro = session, domain, distro
        self.namespace, self.name, self.node_id = namespace, name, node_id
        self.zid = str(session.info.zid())
        self.token = rmw.node_token(domain, self.zid, node_id, namespace, name)
        self._entity = itertools.count(1)
        self._lock = threading.Lock()
        self._pubs: dict[str, Publisher] = {}
        self._subs: list[tuple[Any, Any]] = []
        self._tokens: list[Any] = [session.liveliness().declare_token(self.token)]
        self._worker: Worker | None = None
        self.rejects = LockedRejectCounter()
        self._reject_log = rate_limited_log(_log)
        self.closed = False

    def type_hash(self, typename: str) -> str:
        """The hash this node writes for ``typename``."""
        return rmw.type_hash_for(ts.rihs01(typename), self.distro)

    def _entity_token(self, kind: str, topic: str, typename: str, qos: rmw.Qos,
                      type_hash: str) -> str:
        return rmw.entity_token(self.domain, self.zid, self.node_id, next(self._entity), kind,
                                self.namespace, self.name, topic, rmw.dds_type_name(typename),
                                type_hash, qos)

    def publisher(self, topic: str, typename: str, qos: rmw.Qos | None = None) -> Publisher:
        """The publisher of ``topic`` (created and announced at its first use)."""
        with self._lock:
            pub = self._pubs.get(topic)
            if pub is not None:
                if pub.typename != typename:
                    raise ValueError(f"{topic} is published as {pub.typename}, not {typename}")
                return pub
            h = self.type_hash(typename)
            key = rmw.data_key(self.domain, topic, rmw.dds_type_name(typename), h)
            token = self._entity_token(rmw.PUBLISHER, topic, typename, qos or rmw.Qos(), h)
            pub = Publisher(topic, typename, key, token, rmw.gid_of(token),
                            self.session.declare_publisher(key),
                            self.session.liveliness().declare_token(token))
            self._pubs[topic] = pub
            return pub

    def publish(self, topic: str, typename: str, cdr: bytes, stamp_ns: int | None = None
                ) -> None:
        """Send one serialised message on ``topic`` with its attachment (sequence number,
        ``stamp_ns`` [ns since the epoch; default now], the publisher's GID)."""
        if self.closed:
            return
        pub = self.publisher(topic, typename)
        with pub.lock:
            pub.sequence += 1
            att = rmw.encode_attachment(pub.sequence, time.time_ns() if stamp_ns is None
                                        else stamp_ns, pub.gid)
            pub.zpub.put(cdr, attachment=att)

    def subscribe(self, topic: str, typename: str,
                  callback: Callable[[object, rmw.Attachment | None], None],
                  qos: rmw.Qos | None = None) -> None:
        """Call ``callback(message, attachment)`` on a worker thread for each message of
        ``typename`` published on ``topic`` (any type hash)."""
        with self._lock:
            if self._worker is None:
                self._worker = Worker(f"ros2-{self.name}-subscriptions")
            worker = self._worker
            token = self._entity_token(rmw.SUBSCRIPTION, topic, typename, qos or rmw.Qos(),
                                       self.type_hash(typename))
        key = rmw.data_key(self.domain, topic, rmw.dds_type_name(typename), "*")

        def deliver(key: str, data: bytes, att: bytes | None) -> None:
            try:
                msg = ts.deserialize(data, typename)
            except Exception as exc:  # rosbags raises SerdeError and plain errors alike
                self.rejects.add("undecodable", key)
                self._reject_log.log("undecodable", f"{topic}: not a {typename}: {exc}")
                return
            if not self.closed:
                callback(msg, rmw.decode_attachment(att))

        def on_sample(sample: zenoh.Sample) -> None:  # Zenoh thread: copy and hand over
            att = sample.attachment
            data, k = sample.payload.to_bytes(), str(sample.key_expr)
            raw = att.to_bytes() if att is not None else None
            worker.submit(lambda: deliver(k, data, raw))

        sub = self.session.declare_subscriber(key, on_sample)
        ztoken = self.session.liveliness().declare_token(token)
        with self._lock:
            self._subs.append((sub, ztoken))

    def tokens(self) -> list[str]:
        """Every liveliness token this node declared: its own, then publishers'."""
        with self._lock:
            return [self.token, *(p.token for p in self._pubs.values())]

    def close(self) -> None:
        """Undeclare every publisher, subscription and token; stop the worker. Idempotent."""
        with self._lock:
            if self.closed:
                return
            self.closed = True
            pubs, subs, toks = list(self._pubs.values()), list(self._subs), list(self._tokens)
            worker, self._worker = self._worker, None
        if worker is not None:  # first: no publication may run while its publisher goes
            worker.stop()
        entities = [e for p in pubs for e in (p.zpub, p.ztoken)]
        entities += [e for pair in subs for e in pair] + toks
        for e in entities:
            try:
                e.undeclare()
            except (zenoh.ZError, RuntimeError) as exc:  # closing, or in use by a callback
                _log.debug("undeclare failed: %s", exc)
