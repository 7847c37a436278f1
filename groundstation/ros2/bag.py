"""A ROS 2 bag of what the bridge publishes, written by ``rosbags`` (rosbag2 metadata version 8,
MCAP storage, CDR): ``metadata.yaml`` and ``<folder>.mcap`` in a new folder, one connection per
topic with its message definition, RIHS01 hash and offered QoS; each message logged at its
stamp [ns since the Unix epoch]. Meant for ``ros2 bag info`` / ``play`` of Jazzy and later
and for Foxglove (the ``.mcap`` file alone); checked with rosbags' reader.
"""

from __future__ import annotations

import threading
from pathlib import Path
from typing import Final

from rosbags.interfaces import (
    Connection,
    QosDurability,
    QosHistory,
    QosLiveliness,
    QosReliability,
    QosTime,
)
from rosbags.interfaces import Qos as BagQos
from rosbags.rosbag2 import StoragePlugin, Writer

from groundstation.ros2 import typesupport as ts

#: rosbag2 metadata version written: 8, the first with type description hashes (readers
#: of later versions read it; rosbags also writes 9, which older readers refuse).
VERSION: Final = 8
#: rmw's infinite duration, as ``ros2 bag`` records it.
_INFINITE: Final = QosTime(sec=9223372036, nsec=854775807)
#: the QoS every topic is recorded with (what the bridge offers: reliable, volatile, depth 10)
OFFERED: Final = BagQos(history=QosHistory.KEEP_LAST, depth=10,
                        reliability=QosReliability.RELIABLE,
                        durability=QosDurability.VOLATILE, deadline=_INFINITE,
                        lifespan=_INFINITE, liveliness=QosLiveliness.AUTOMATIC,
                        liveliness_lease_duration=_INFINITE,
                        avoid_ros_namespace_conventions=False)


class BagError(Exception):
    """The bag cannot be written where asked (one line, for the user)."""


class BagWriter:
    """A new bag at ``path`` (a folder that must not exist yet); thread-safe."""

    @staticmethod
    def check(path: Path) -> Path:
        """``path`` if a bag can be created there; a :class:`BagError` saying why not."""
        if path.exists():
            raise BagError(f"{path} exists; a bag is written into a new folder: give a path "
                           "that does not exist yet")
        if not path.parent.is_dir():
            raise BagError(f"{path.parent} is not a folder")
        return path

    def __init__(self, path: Path) -> None:
        self.path = self.check(path)
        self._writer = Writer(path, version=VERSION, storage_plugin=StoragePlugin.MCAP)
        try:
            self._writer.open()
        except OSError as e:
            raise BagError(f"{path}: cannot create it: {e.strerror or e}") from None
        self._lock = threading.Lock()
        self._connections: dict[str, Connection] = {}
        self.counts: dict[str, int] = {}
        self.closed = False

    def write(self, topic: str, typename: str, cdr: bytes, stamp_ns: int) -> None:
        """Log one serialised message of ``typename`` on ``topic`` at ``stamp_ns``."""
        with self._lock:
            if self.closed:
                return
            conn = self._connections.get(topic)
            if conn is None:
                conn = self._writer.add_connection(
                    topic, typename, msgdef=ts.msgdef(typename), rihs01=ts.rihs01(typename),
                    offered_qos_profiles=[OFFERED])
                self._connections[topic] = conn
            self._writer.write(conn, int(stamp_ns), cdr)
            self.counts[topic] = self.counts.get(topic, 0) + 1

    def close(self) -> None:
        """Write the MCAP summary and ``metadata.yaml``; idempotent."""
        with self._lock:
            if self.closed:
                return
            self.closed = True
            self._writer.close()
