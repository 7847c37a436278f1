"""What the bridge publishes, decided without any I/O: :class:`MissionRos` takes what the
mission says (agent poses, mocap, states, ownership, events, the status view), each with the
wall time it arrived [ns since the Unix epoch], and returns the ROS messages to send
(:class:`Out`); the bridge (:mod:`groundstation.ros2.bridge`) and the tests feed it.

* An agent pose (camera at p [m; world ENU], unit direction v): ``<ns>/<drone>/pose``; on
  ``/tf`` world → ``<drone>`` (level body heading along v) → ``<drone>/camera``, unless the
  drone has motion capture younger than ``mocap_fresh_s``; the frusta (all drones, one
  MarkerArray) at most ``scene_hz`` times a second.
* A mocap pose (p [m; world ENU], attitude (w, x, y, z) R_ENU←FLU): ``<ns>/<drone>/mocap``
  (a topic announced once the drone's first mocap pose is heard: a kinematic mission, or
  one flown outdoors on the autopilots' pose, has none) and on ``/tf`` world → ``<drone>``
  with that attitude, and ``<drone>`` → ``<drone>/camera`` from the drone's latest camera
  direction.
* A state: the drone's label (phase, landmarks, vision); in an inspection its captured set:
  the team's set is what a strict majority of the drones' latest sets name (the observer's
  rule), whose growth is logged on ``<ns>/events`` (the capture log: whose state made which
  landmarks agreed) and redraws ``<ns>/captures``.
* An ownership change: ``<ns>/landmarks`` (also re-sent every period for late subscribers:
  the topics are volatile).
* An event of the mission watch: one log line on ``<ns>/events``; the view: ``<ns>/status``.

Thread-safe (one lock): the bridge calls it from the transport's worker and its timer.
"""

from __future__ import annotations

import math
import threading
from collections.abc import Sequence
from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from agent.config.scenario import Scenario
from agent.mission.watch import MissionView
from agent.protocol.captures import agreed_bits
from agent.storage.events import Capture, MissionEvent
from groundstation.ros2 import frames, messages
from groundstation.ros2 import typesupport as ts
from groundstation.ros2.frames import Quat
from groundstation.ros2.names import TF_TOPIC, WORLD, Names, drone_token, drone_tokens

#: half-angle [rad] of a drawn frustum when the scenario gives no field of view
DEFAULT_HALF_ANGLE = math.radians(30.0)
#: most landmark ids named in one capture-log line
LOG_IDS = 20


class Out(NamedTuple):
    """One message to send: topic, type, the rosbags message, its time [ns since epoch]."""

    topic: str
    typename: str
    msg: object
    stamp_ns: int


class MissionRos:
    """The ROS view of one mission (module docstring); ``sc`` its scenario. Raises a
    ValueError when two of its drones would have one ROS name."""

    def __init__(self, sc: Scenario, names: Names, *, scene_hz: float = 10.0,
                 mocap_fresh_s: float = 0.5) -> None:
        self.names = names
        self.ids = [a.id for a in sc.agents]
        self.tokens = drone_tokens(self.ids)  # ValueError: two ids, one ROS name
        self.rows = {a: i for i, a in enumerate(self.ids)}
        self.q = np.asarray(sc.q, dtype=np.float64).reshape(-1, 3)
        self.landmark_ids = np.asarray(sc.landmark_ids, dtype=np.int64)
        self.inspection = sc.inspection is not None
        self.depth = float(sc.d_opt)
        self.diameter = 0.1 * float(sc.d_opt)
        fov = None if sc.inspection is None else sc.inspection.fov  # full angles [rad]
        self.half = (DEFAULT_HALF_ANGLE, DEFAULT_HALF_ANGLE) if fov is None else \
            (float(fov[0]) / 2.0, float(fov[1]) / 2.0)
        self.scene_period_ns = int(1e9 / scene_hz)
        self.fresh_ns = int(mocap_fresh_s * 1e9)
        self._lock = threading.Lock()
        self._camera: dict[str, tuple[tuple[float, ...], tuple[float, ...]]] = {}
        self._body: dict[str, tuple[Quat, int]] = {}  #: mocap attitude and its time [ns]
        self._labels: dict[str, str] = {}
        self._next_scene = 0
        self._owner: NDArray[np.intp] = np.full(self.q.shape[0], -1, dtype=np.intp)
        self._owner_known = False
        self._bits: dict[str, bytes] = {}
        self._captured = np.zeros(self.q.shape[0], dtype=np.bool_)

    # -- drones ----------------------------------------------------------------------------
    def known(self, aid: str) -> bool:
        """Whether ``aid`` is a drone of the mission (of the scenario, or one that joined)."""
        return aid in self.rows

    def join(self, aid: str) -> bool:
        """Take ``aid`` (a drone that joined the mission) in; False when its ROS name would
        be another drone's."""
        with self._lock:
            if aid in self.rows:
                return True
            tok = drone_token(aid)
            if tok in self.tokens.values():
                return False
            self.ids.append(aid)
            self.tokens[aid] = tok
            self.rows[aid] = len(self.rows)
            return True

    def _tf_camera(self, aid: str, ns: int) -> list[tuple[str, str, Sequence[float], Quat]]:
        """The transforms of ``aid`` that its agent pose gives (none with fresh mocap)."""
        p, v = self._camera[aid]
        body = self._body.get(aid)
        tok = self.tokens[aid]
        if body is not None and ns - body[1] <= self.fresh_ns:
            return []
        yaw, pitch = frames.yaw_pitch(v)
        return [(WORLD, Names.body_frame(tok), p, frames.yaw_quat(yaw)),
                (Names.body_frame(tok), Names.camera_frame(tok), (0.0, 0.0, 0.0),
                 frames.pitch_quat(pitch))]

    def pose(self, aid: str, p: Sequence[float], v: Sequence[float], ns: int) -> list[Out]:
        """An agent's pose: camera at p [m; world ENU] looking along unit v, received at
        ``ns``."""
        with self._lock:
            if aid not in self.rows:
                return []
            tok = self.tokens[aid]
            self._camera[aid] = (tuple(float(x) for x in p), tuple(float(x) for x in v))
            out = [Out(self.names.pose(tok), ts.POSE_STAMPED,
                       messages.pose_stamped(p, frames.camera_quat(v), ns, WORLD), ns)]
            tf = self._tf_camera(aid, ns)
            if tf:
                out.append(Out(TF_TOPIC, ts.TF_MESSAGE, messages.tf_message(tf, ns), ns))
            if ns >= self._next_scene:
                self._next_scene = ns + self.scene_period_ns
                out.append(self._frusta(ns))
            return out

    def mocap(self, aid: str, p: Sequence[float], q_wxyz: Sequence[float],
              ns: int) -> list[Out]:
        """A motion-capture pose: body at p [m; world ENU], attitude (w, x, y, z)
        R_ENU←FLU, received at ``ns``."""
        with self._lock:
            if aid not in self.rows:
                return []
            tok = self.tokens[aid]
            q = frames.mocap_quat(q_wxyz)
            self._body[aid] = (q, ns)
            tf: list[tuple[str, str, Sequence[float], Quat]] = [
                (WORLD, Names.body_frame(tok), p, q)]
            if aid in self._camera:
                tf.append((Names.body_frame(tok), Names.camera_frame(tok), (0.0, 0.0, 0.0),
                           frames.camera_in_body(q, self._camera[aid][1])))
            return [Out(self.names.mocap(tok), ts.POSE_STAMPED,
                        messages.pose_stamped(p, q, ns, WORLD), ns),
                    Out(TF_TOPIC, ts.TF_MESSAGE, messages.tf_message(tf, ns), ns)]

    def _frusta(self, ns: int) -> Out:
        """Every drone's frustum and label (caller holds the lock)."""
        have = [a for a in self.ids if a in self._camera]
        return Out(self.names.frusta, ts.MARKER_ARRAY, messages.frustum_markers(
            [self.rows[a] for a in have], [self._camera[a][0] for a in have],
            [self._camera[a][1] for a in have], [self._labels.get(a, a) for a in have], ns,
            self.depth, self.half[0], self.half[1], WORLD), ns)

    # -- states ----------------------------------------------------------------------------
    def state(self, aid: str, phase: str, owned: int, vision: float, captured: bytes,
              ns: int) -> list[Out]:
        """The newest state of ``aid`` (phase, landmarks owned, vision, captured bit set):
        its label; in an inspection, the capture log and map when the team's set grew."""
        with self._lock:
            if aid not in self.rows:
                return []
            self._labels[aid] = f"{aid} {phase} {owned} lm vis {vision:.2f}"
            if not self.inspection or not captured:
                return []
            self._bits[aid] = captured
            agreed = agreed_bits(self._bits.values(), self.q.shape[0])  # the observer's rule
            new = agreed & ~self._captured
            changed = bool((agreed != self._captured).any())
            self._captured = agreed
            if not new.any():
                return [self._captures(ns)] if changed else []
            ids = self.landmark_ids[new].tolist()
            shown = ", ".join(str(i) for i in ids[:LOG_IDS]) + (", ..." if len(ids) > LOG_IDS
                                                               else "")
            text = (f"{aid}: {len(ids)} new capture(s) (landmarks {shown}); "
                    f"{int(agreed.sum())} / {agreed.size} captured")
            ev = Capture(time=ns / 1e9, source=aid, level="info", text=text, landmarks=ids,
                         captured=int(agreed.sum()), total=int(agreed.size))
            return [Out(self.names.events, ts.LOG, messages.log_of(ev), ns),
                    self._captures(ns)]

    def _captures(self, ns: int) -> Out:
        return Out(self.names.captures, ts.MARKER_ARRAY, messages.landmark_marker(
            self.q, messages.capture_colours(self._captured), ns, "captures", self.diameter,
            WORLD), ns)

    def ownership(self, ids: Sequence[str], owner: NDArray[np.intp], ns: int,
                  force: bool = False) -> list[Out]:
        """Each landmark's owner as a row of ``ids`` (-1: none): ``<ns>/landmarks`` when it
        changed (or ``force``: the periodic re-send, with the captures of an inspection)."""
        with self._lock:
            rows = np.array([self.rows.get(a, -1) for a in ids] + [-1], dtype=np.intp)
            mine = rows[np.where(owner >= 0, owner, len(ids))]
            changed = not self._owner_known or not np.array_equal(mine, self._owner)
            if not changed and not force:
                return []
            self._owner, self._owner_known = mine, True
            out = [Out(self.names.landmarks, ts.MARKER_ARRAY, messages.landmark_marker(
                self.q, messages.owner_colours(mine), ns, "landmarks", self.diameter, WORLD),
                ns)]
            if force and self.inspection:
                out.append(self._captures(ns))
            return out

    # -- mission ---------------------------------------------------------------------------
    def event(self, ev: MissionEvent, ns: int) -> Out:
        """One event of the mission watch as a log line (stamped with its own time)."""
        return Out(self.names.events, ts.LOG, messages.log_of(ev), ns)

    def status(self, view: MissionView, ns: int) -> Out:
        """The mission view as diagnostics."""
        with self._lock:
            tokens = dict(self.tokens)
        return Out(self.names.status, ts.DIAGNOSTIC_ARRAY,
                   messages.diagnostics(view, tokens, ns), ns)

    def topics(self) -> list[tuple[str, str]]:
        """(topic, type) of everything this mission publishes, drones of the scenario first:
        a drone's mocap once its first mocap pose came (nothing announced that is never
        published)."""
        n = self.names
        with self._lock:
            toks = [(self.tokens[a], a in self._body) for a in self.ids]
        out = [(f(t), ts.POSE_STAMPED) for t, mocap in toks
               for f in ((n.pose, n.mocap) if mocap else (n.pose,))]
        out += [(TF_TOPIC, ts.TF_MESSAGE), (n.landmarks, ts.MARKER_ARRAY),
                (n.frusta, ts.MARKER_ARRAY), (n.status, ts.DIAGNOSTIC_ARRAY),
                (n.events, ts.LOG)]
        if self.inspection:
            out.append((n.captures, ts.MARKER_ARRAY))
        return out
