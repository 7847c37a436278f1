"""The capture state of an inspection mission's landmarks for the recording (topic
:data:`~agent.storage.recording.CAPTURES_TOPIC`): one point cloud, each landmark coloured
captured (green), pending (orange) or uncapturable (grey), rewritten whenever the team's
captured set grows.

The team's captured set is what a strict majority of the latest published states'
``captured`` bit sets name (:func:`~agent.protocol.captures.agreed_bits`, the observer's rule:
no one drone's word makes a landmark captured). Which landmarks are uncapturable comes from
the scenario's capture table (:func:`~agent.world.tables.mission_tables`, about a second),
computed on a background thread so that the recorder starts at once: until it is known they
show as pending. World frame :data:`~agent.storage.recording.WORLD` (ENU, metres).
"""

from __future__ import annotations

import logging
import threading
from typing import Final

import numpy as np
from foxglove.messages import (
    PackedElementField,
    PackedElementFieldNumericType,
    PointCloud,
    Pose,
    Quaternion,
    Vector3,
)
from numpy.typing import NDArray

from agent.config.scenario import Scenario
from agent.mission import scene
from agent.protocol.captures import agreed_bits
from agent.storage.recording import WORLD
from agent.world.tables import mission_tables

_log = logging.getLogger(f"viscover.{__name__}")

PENDING: Final = 0  #: not captured yet
CAPTURED: Final = 1  #: captured by some drone
UNCAPTURABLE: Final = 2  #: no pose of the capture table captures it (left out of the goal)
#: RGBA bytes of each state (rows: PENDING, CAPTURED, UNCAPTURABLE)
STATE_COLOURS: Final = np.array([[255, 127, 14, 255], [44, 160, 44, 255],
                                 [150, 150, 150, 255]], dtype=np.uint8)
#: point layout: x, y, z float32, red..alpha uint8, id uint32, state uint8 (+ 3 pad bytes)
_CLOUD = np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("red", "u1"), ("green", "u1"),
                   ("blue", "u1"), ("alpha", "u1"), ("id", "<u4"), ("state", "u1"),
                   ("pad", "u1", (3,))])
#: bytes per point of the cloud
POINT_STRIDE: Final = _CLOUD.itemsize
_F = PackedElementFieldNumericType
_FIELDS = [("x", 0, _F.Float32), ("y", 4, _F.Float32), ("z", 8, _F.Float32),
           ("red", 12, _F.Uint8), ("green", 13, _F.Uint8), ("blue", 14, _F.Uint8),
           ("alpha", 15, _F.Uint8), ("id", 16, _F.Uint32), ("state", 20, _F.Uint8)]


def capture_states(captured: NDArray[np.bool_], uncapturable: NDArray[np.bool_] | None
                   ) -> NDArray[np.uint8]:
    """Each landmark's state (m,): CAPTURED, else UNCAPTURABLE if known so, else PENDING."""
    out = np.full(captured.shape[0], PENDING, dtype=np.uint8)
    if uncapturable is not None:
        out[uncapturable] = UNCAPTURABLE
    out[captured] = CAPTURED
    return out


def capture_cloud(q: NDArray[np.float64], ids: NDArray[np.int64], state: NDArray[np.uint8],
                  wall: float) -> PointCloud:
    """Landmarks q (m, 3) [m; world ENU] as a point cloud coloured by capture ``state``, with
    id and state fields; stamped at wall time ``wall`` [s since the epoch]."""
    pts = np.zeros(q.shape[0], dtype=_CLOUD)
    for k, axis in enumerate("xyz"):
        pts[axis] = q[:, k]
    rgba = STATE_COLOURS[state]
    for k, ch in enumerate(("red", "green", "blue", "alpha")):
        pts[ch] = rgba[:, k]
    pts["id"] = ids
    pts["state"] = state
    fields = [PackedElementField(name=n, offset=off, type=t) for n, off, t in _FIELDS]
    return PointCloud(timestamp=scene.stamp(wall), frame_id=WORLD,
                      pose=Pose(position=Vector3(x=0.0, y=0.0, z=0.0),
                                orientation=Quaternion(x=0.0, y=0.0, z=0.0, w=1.0)),
                      point_stride=_CLOUD.itemsize,
                      fields=fields, data=pts.tobytes())


def cloud_states(message: bytes, m: int) -> NDArray[np.uint8]:
    """The ``state`` of each of the m landmarks of a recorded capture cloud (its serialised
    message: the packed points, its last field, are its last m·:data:`POINT_STRIDE` bytes)."""
    return np.frombuffer(message[len(message) - m * POINT_STRIDE:], dtype=_CLOUD)["state"].copy()


class CaptureView:
    """The team's captured set as the recorder hears it, and each landmark's state."""

    def __init__(self, sc: Scenario) -> None:
        assert sc.inspection is not None, "not an inspection mission"
        self.m = len(sc.landmark_ids)
        self._bits: dict[str, bytes] = {}  #: latest published captured set of each drone
        self.uncapturable: NDArray[np.bool_] | None = None  #: once the table is computed
        self._last: NDArray[np.uint8] | None = None
        self._lock = threading.Lock()
        self._thread = threading.Thread(target=self._table, args=(sc,), name="capture-table",
                                        daemon=True)
        self._thread.start()

    def settle(self, timeout_s: float = 30.0) -> None:
        """Wait (at most ``timeout_s`` [wall s]) for the capture table, so that the last
        states written show the uncapturable landmarks as such."""
        self._thread.join(timeout_s)

    def _table(self, sc: Scenario) -> None:
        """Compute the uncapturable landmarks (background thread)."""
        try:
            table, _ = mission_tables(sc)
        except Exception as exc:  # the view only loses the grey points
            _log.warning("recorder: no capture table (%s): uncapturable shown pending", exc)
            return
        with self._lock:
            self.uncapturable = ~table.capturable

    def states(self) -> NDArray[np.uint8]:
        """Each landmark's state now (m,)."""
        with self._lock:
            return capture_states(agreed_bits(self._bits.values(), self.m), self.uncapturable)

    def update(self, aid: str, bits: bytes) -> NDArray[np.uint8] | None:
        """A newer state of ``aid`` with captured set ``bits``: the states if they changed
        since last returned (or on the first call), else None."""
        with self._lock:
            if bits:
                self._bits[aid] = bits
        now = self.states()
        if self._last is not None and np.array_equal(now, self._last):
            return None
        self._last = now
        return now
