"""Record a mission from any machine of the mesh (``viscover record``, ``viscover launch``):
``events.jsonl`` and an MCAP file that opens in Foxglove, written with foxglove-sdk (format
and topics: :mod:`agent.storage.recording`).

The recorder listens through a :class:`~agent.mission.watch.MissionWatch` (states, statuses,
liveliness, mocap health, commands: the events) and subscribes to the poses and the motion
capture itself. Every state, pose and event is recorded; the Foxglove views are thinned to
``pose_hz`` per drone for poses and mocap (a mocap sample between two is not even decoded)
and ``scene_hz`` for the drone scene. Payloads that do not decode are counted (the watch's
and the recorder's counters), never raised.

With ``live`` (a port; 0: any free one) the same messages are also served live on
``live_host`` (loopback by default): Foxglove's "Open connection", ``ws://HOST:PORT``, under
either subprotocol name, the mission info, space and landmark clouds latched for viewers that
join later (:mod:`agent.mission.live`). Each drone's pose also goes out as two
FrameTransforms, world → drone → camera (:func:`agent.mission.scene.frame_transforms`), so a
viewer can follow a drone.

Nothing is lost on a clean stop: :meth:`Recorder.close` (called on SIGINT / SIGTERM by the
commands) writes the final event and the MCAP summary; the MCAP is flushed every
``flush_s`` seconds, so after a SIGKILL the reader still streams what was flushed.
"""

from __future__ import annotations

import json
import os
import threading
import time
from pathlib import Path
from typing import IO, Any

import foxglove
import msgspec
import numpy as np
from foxglove.channels import (
    FrameTransformChannel,
    LogChannel,
    PointCloudChannel,
    PoseInFrameChannel,
    SceneUpdateChannel,
)
from foxglove.mcap import MCAPCompression, MCAPWriteOptions

from agent.config.scenario import Scenario
from agent.mission import scene
from agent.mission.capture_scene import CaptureView, capture_cloud
from agent.mission.invariants import Claim
from agent.mission.live import LiveView, Tee, route_sdk_logs
from agent.mission.watch import MissionWatch
from agent.net.contract import Declared, Transport
from agent.net.rejects import rate_limited_log
from agent.storage import recording as fmt
from agent.storage.events import (
    Event,
    Failsafe,
    Flight,
    Level,
    LogLine,
    Process,
    ProcessError,
    Recording,
    RecordingEnd,
    encode_event,
)
from agent.wire import keys
from agent.wire.codec import Codec
from agent.wire.ground import MocapPose
from agent.wire.peer import AgentState, Pose, Publication


def mcap_path(out_dir: Path) -> Path:
    """``recording.mcap`` in ``out_dir``, or the first free ``recording-<n>.mcap`` (a resume)."""
    path = out_dir / fmt.MCAP_NAME
    n = 1
    while path.exists():
        n += 1
        path = out_dir / f"recording-{n}.mcap"
    return path


def line_event(source: str, text: str) -> Event | None:
    """The event of a process's output line (flight phase, failsafe, error, warning) or None."""
    if text.startswith("viscover-flight-agent "):
        phase = text.split(": ", 1)[-1]
        if "left the mission" in phase:
            return Failsafe(source=source, level="error", text=text)
        if "mocap lost" in phase or "failsafe" in phase:
            return Failsafe(source=source, level="warning", text=text)
        return Flight(source=source, level="info", text=text)
    if text.startswith("viscover: error:"):
        return ProcessError(source=source, level="error", text=text)
    if text.startswith("viscover:"):
        return Process(source=source, level="warning", text=text)
    level: Level | None = "error" if " ERROR " in text else \
        "warning" if " WARNING " in text else None
    if level is None:
        return None
    if "mocap stale" in text or "failsafe" in text:
        return Failsafe(source=source, level=level, text=text)
    return LogLine(source=source, level=level, text=text)


class Recorder:
    """Records one mission into ``out_dir`` (see the module docstring)."""

    def __init__(self, tp: Transport, sc: Scenario, mission: str, out_dir: Path, *,
                 watch: MissionWatch | None = None, pose_hz: float = 30.0,
                 scene_hz: float = 10.0, flush_s: float = 5.0, live: int | None = None,
                 live_host: str = "127.0.0.1") -> None:
        route_sdk_logs()
        self._ctx = foxglove.Context()
        self.server: LiveView | None = None
        if live is not None:  # first: a port in use raises before anything is opened
            self.server = LiveView(f"viscover {mission}", live_host, live)
        out_dir.mkdir(parents=True, exist_ok=True)
        self.sc, self.mission, self.out_dir = sc, mission, out_dir
        self.path = mcap_path(out_dir)
        self.events_path = out_dir / fmt.EVENTS_NAME
        self._own_watch = watch is None
        self.watch = MissionWatch(tp, mission, sc, start=False) if watch is None else watch
        self.ids = [a.id for a in sc.agents]
        self._row = {a: i for i, a in enumerate(self.ids)}
        self._lm_ids = np.asarray(sc.landmark_ids, dtype=np.int64)
        self._periods = {"pose": 1.0 / pose_hz, "scene": 1.0 / scene_hz}
        self._flush_s = flush_s
        self._lock = threading.Lock()
        self._closed = False
        self.counts: dict[str, int] = {}
        self._next: dict[tuple[str, str], float] = {}
        self._pose: dict[str, tuple[np.ndarray, np.ndarray]] = {}
        self._label: dict[str, str] = {}
        self._owned_key: tuple[int, ...] | None = None
        self._started = time.time()
        self._next_flush = time.monotonic() + flush_s
        self._enc = msgspec.json.Encoder()
        self._events: IO[str] = self.events_path.open("a", encoding="utf-8")
        self._open_mcap()
        log = rate_limited_log()
        self._c_pub: Codec[Publication] = Codec(Publication, counter=self.watch.rejects, log=log)
        self._c_mocap: Codec[MocapPose] = Codec(MocapPose, counter=self.watch.rejects, log=log)
        self.event(Recording(source="recorder", level="info", text=f"recording mission "
                             f"{mission} ({sc.name}) into {self.path}", path=str(self.path)))
        self.watch.listeners.append(self.event)
        self.watch.state_listeners.append(self._on_state)
        if self._own_watch:
            self.watch.start()
        self._write_landmarks(self.watch.owners(), time.time())
        if self._captures is not None:  # an inspection: every landmark pending at the start
            self._write_captures("", b"", time.time())
        self._handles: list[Declared] = [
            tp.subscribe(keys.all_agents(mission, "pose"), self._on_pose),
            tp.subscribe(keys.all_agents(mission, "mocap"), self._on_mocap),
        ]

    def _open_mcap(self) -> None:
        """Open the MCAP writer and its channels; write the mission info, space, landmarks."""
        ctx = self._ctx
        self._writer = foxglove.open_mcap(
            self.path, context=ctx, writer_options=MCAPWriteOptions(
                compression=MCAPCompression.Zstd, compression_threads=0))

        def json_channel(topic: str, schema: str, latched: bool = False) -> Tee:
            """A JSON channel on ``topic`` with the named JSON schema."""
            data = json.dumps(fmt.SCHEMAS[schema]).encode()
            return Tee(lambda c: foxglove.Channel(
                topic, message_encoding="json", context=c,
                schema=foxglove.Schema(name=schema, encoding="jsonschema", data=data)),
                ctx, self.server, latched)

        def typed(kind: Any, topic: str, latched: bool = False) -> Tee:
            """A channel of a foxglove-sdk message ``kind`` (its channel class) on ``topic``."""
            return Tee(lambda c: kind(topic, context=c), ctx, self.server, latched)

        self._typed = typed
        self._info = json_channel(fmt.INFO_TOPIC, "viscover.MissionInfo", latched=True)
        self._coverage = json_channel(fmt.COVERAGE_TOPIC, "viscover.Coverage")
        self._json_channel = json_channel
        self._states: dict[str, Tee] = {}
        self._tracks: dict[str, Tee] = {}
        self._poses: dict[str, Tee] = {}
        self._mocap: dict[str, Tee] = {}
        self._frames: dict[str, tuple[Tee, Tee]] = {}
        for a in self.ids:
            self._add_drone(a)
        self._drones = typed(SceneUpdateChannel, fmt.DRONES_TOPIC)
        self._space = typed(SceneUpdateChannel, fmt.MISSION_TOPIC, latched=True)
        self._landmarks = typed(PointCloudChannel, fmt.LANDMARKS_TOPIC, latched=True)
        self._captures = None if self.sc.inspection is None else \
            (CaptureView(self.sc), typed(PointCloudChannel, fmt.CAPTURES_TOPIC, latched=True))
        self._log = typed(LogChannel, fmt.EVENTS_TOPIC)
        now = time.time()
        self._write(self._info, fmt.INFO_TOPIC,
                    self._enc.encode(fmt.info_document(self.sc, self.mission, self._started)))
        box = scene.space_update(np.asarray(self.sc.space.lo), np.asarray(self.sc.space.hi),
                                 now)
        if box is not None:
            self._write(self._space, fmt.MISSION_TOPIC, box)

    def _add_drone(self, aid: str) -> None:
        """The channels of drone ``aid`` (a scenario drone at the start, a drone that joined
        the mission at its first state)."""
        self._states[aid] = self._json_channel(fmt.state_topic(aid), "viscover.AgentState")
        self._tracks[aid] = self._json_channel(fmt.track_topic(aid), "viscover.Pose")
        self._poses[aid] = self._typed(PoseInFrameChannel, fmt.pose_topic(aid))
        self._mocap[aid] = self._typed(PoseInFrameChannel, fmt.mocap_topic(aid))
        self._frames[aid] = (self._typed(FrameTransformChannel, fmt.frame_topic(aid)),
                             self._typed(FrameTransformChannel, fmt.camera_frame_topic(aid)))
        self._row.setdefault(aid, len(self._row))

    def _joined(self, aid: str) -> None:
        """Channels for ``aid`` if the watch took it for a drone that joined (first state)."""
        with self._lock:
            if aid not in self._row and aid in self.watch.drones and not self._closed:
                self.ids.append(aid)
                self._add_drone(aid)

    # -- writing ---------------------------------------------------------------------------
    def _write(self, channel: Tee, topic: str, msg: Any) -> None:
        """Log ``msg`` on ``channel`` now (counted per topic); nothing once closed."""
        with self._lock:
            if self._closed:
                return
            self.counts[topic] = self.counts.get(topic, 0) + 1
            channel.log(msg, time.time_ns())
            if time.monotonic() >= self._next_flush:
                self._next_flush = time.monotonic() + self._flush_s
                self._writer.flush()

    def _due(self, aid: str, what: str) -> bool:
        """Whether the thinned view ``what`` of ``aid`` is due (and book the next one)."""
        now = time.monotonic()
        with self._lock:
            if now < self._next.get((aid, what), 0.0):
                return False
            self._next[(aid, what)] = now + self._periods[what]
            return True

    def event(self, ev: Event) -> None:
        """Record one event: a line of ``events.jsonl`` (with ``t`` [s since the recording
        started]) and a Foxglove log line."""
        ev = msgspec.structs.replace(ev, t=round(ev.time - self._started, 6))
        line = encode_event(ev).decode()
        with self._lock:
            if self._closed:
                return
            self._events.write(line + "\n")
            self._events.flush()
        self._write(self._log, fmt.EVENTS_TOPIC, scene.log_of(ev))

    def _write_landmarks(self, owner: np.ndarray, wall: float) -> None:
        """The landmark cloud coloured by ``owner`` at wall time ``wall`` [s since the epoch]."""
        self._write(self._landmarks, fmt.LANDMARKS_TOPIC,
                    scene.landmark_cloud(np.asarray(self.sc.q), self._lm_ids, owner, wall))

    def _write_captures(self, aid: str, bits: bytes, wall: float) -> None:
        """An inspection's landmarks by capture state, if ``aid``'s captured set ``bits``
        changed them."""
        if self._captures is not None \
                and (state := self._captures[0].update(aid, bits)) is not None:
            self._write(self._captures[1], fmt.CAPTURES_TOPIC,
                        capture_cloud(np.asarray(self.sc.q), self._lm_ids, state, wall))

    def _write_drones(self, wall: float) -> None:
        """The drone scene from each drone's latest pose and label."""
        with self._lock:
            have = [a for a in self.ids if a in self._pose]
            p = np.array([self._pose[a][0] for a in have]).reshape(-1, 3)
            v = np.array([self._pose[a][1] for a in have]).reshape(-1, 3)
            labels = [self._label.get(a, a) for a in have]
        if have:
            self._write(self._drones, fmt.DRONES_TOPIC, scene.drone_update(
                [self._row[a] for a in have], have, p, v, labels, wall, float(self.sc.d_opt),
                float(self.sc.params.r_s)))

    # -- inputs ----------------------------------------------------------------------------
    def _on_state(self, st: AgentState, claims: Claim, newer: bool) -> None:
        """A state: its JSON; if newest, landmarks (on change), coverage, drone scene."""
        aid = st.sender
        self._joined(aid)
        self._write(self._states[aid], fmt.state_topic(aid), self._enc.encode(
            fmt.state_document(st, sorted(claims[0]), sorted(claims[1]))))
        if not newer:
            return
        wall = time.time()
        with self._lock:
            self._pose[aid] = (np.asarray(st.p, dtype=np.float64),
                               np.asarray(st.v, dtype=np.float64))
            self._label[aid] = f"{aid} {st.phase} {len(claims[0])} lm vis {st.vision:.2f}"
        _ids, owner, p, v = self.watch.ownership()
        key = tuple(owner.tolist())
        if key != self._owned_key:
            self._owned_key = key
            self._write_landmarks(owner, wall)
        self._write_captures(aid, st.captured, wall)
        seen = fmt.seen_by_owner(np.asarray(self.sc.q), np.asarray(self.sc.u), owner, p, v)
        self._write(self._coverage, fmt.COVERAGE_TOPIC, self._enc.encode({
            "coverage": self.watch.observer.report.coverage, "seen": int(seen.sum()),
            "not_seen": int(((owner >= 0) & ~seen).sum()), "unowned": int((owner < 0).sum())}))
        if self._due(aid, "scene"):
            self._write_drones(wall)

    def _on_pose(self, key: str, payload: bytes) -> None:
        """A pose: its JSON, and the thinned PoseInFrame and drone scene."""
        msg = self._c_pub.decode(payload, key)
        if msg is None:
            return
        if isinstance(msg, Pose):
            self._joined(msg.sender)
        if not isinstance(msg, Pose) or keys.try_agent_of(key) != msg.sender \
                or msg.sender not in self._row:
            self._c_pub.reject("impossible", key, "not a pose of a mission agent")
            return
        aid = msg.sender
        self._write(self._tracks[aid], fmt.track_topic(aid),
                    self._enc.encode(fmt.pose_document(msg)))
        p, v = np.asarray(msg.p, dtype=np.float64), np.asarray(msg.v, dtype=np.float64)
        with self._lock:
            self._pose[aid] = (p, v)
        wall = time.time()
        if self._due(aid, "pose"):
            self._write(self._poses[aid], fmt.pose_topic(aid), scene.pose_in_frame(
                p, scene.camera_quaternions(v[None])[0], wall))
            body, camera = scene.frame_transforms(aid, p, v, wall)
            self._write(self._frames[aid][0], fmt.frame_topic(aid), body)
            self._write(self._frames[aid][1], fmt.camera_frame_topic(aid), camera)
        if self._due(aid, "scene"):
            self._write_drones(wall)

    def _on_mocap(self, key: str, payload: bytes) -> None:
        """A mocap pose as PoseInFrame, decoded only when its drone's thinned view is due."""
        aid = keys.try_agent_of(key)
        if aid not in self._row or not self._due(f"{aid}/mocap", "pose"):
            return
        msg = self._c_mocap.decode(payload, key)
        if msg is None or msg.drone != aid:
            return
        w, x, y, z = (float(c) for c in msg.q)
        self._write(self._mocap[aid], fmt.mocap_topic(aid), scene.pose_in_frame(
            np.asarray(msg.p, dtype=np.float64), np.array([x, y, z, w]), time.time()))

    # -- the end ---------------------------------------------------------------------------
    def close(self) -> None:
        """Stop listening, write the last event and the MCAP summary; idempotent."""
        with self._lock:
            if self._closed:
                return
        for h in self._handles:
            h.undeclare()
        if self.event in self.watch.listeners:
            self.watch.listeners.remove(self.event)
        if self._on_state in self.watch.state_listeners:
            self.watch.state_listeners.remove(self._on_state)
        if self._own_watch:
            self.watch.close()
        if self._captures is not None:  # the table may come after the last state: say it
            self._captures[0].settle()
            self._write_captures("", b"", time.time())
        rep = self.watch.observer.snapshot()
        rejected = rep.rejected + self.watch.rejects.total
        self.event(RecordingEnd(source="recorder", level="info", text=f"recording ended: "
                                f"{sum(self.counts.values())} messages, {rejected} payloads "
                                "rejected", messages=dict(self.counts), rejected=rejected))
        with self._lock:
            self._closed = True
            self._writer.close()
            if self.server is not None:
                self.server.close()
            self._events.flush()
            os.fsync(self._events.fileno())
            self._events.close()
