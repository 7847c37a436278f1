"""The camera client: which camera the vehicle advertises, a capture per request with the
landmark ids it is meant for, and a record per capture for the runtime to journal.

Discovery (:meth:`CameraClient.discover`): MAV_CMD_REQUEST_MESSAGE for CAMERA_INFORMATION
(259) to every camera component heard (HEARTBEAT type MAV_TYPE_CAMERA, or component
100-105), to MAV_COMP_ID_CAMERA (100) even if not heard yet (cameras send HEARTBEAT at
1 Hz), and to the autopilot; then the choice, from what answered:

1. a camera component whose CAMERA_INFORMATION has CAMERA_CAP_FLAGS_CAPTURE_IMAGE:
   MAV_CMD_IMAGE_START_CAPTURE to it (PX4 and MAVLink cameras; camera protocol v2);
2. the autopilot's own CAMERA_INFORMATION (ArduPilot 4.5+ answers for its AP_Camera
   backends): MAV_CMD_IMAGE_START_CAPTURE to the autopilot, param1 = camera_device_id
   (1-6), or 0 (all cameras) when it gives none (ArduPilot 4.4+ handles the command);
3. nothing, on a flavour with the legacy trigger (ArduPilot, every version):
   MAV_CMD_DO_DIGICAM_CONTROL to the autopilot, param5 = 1 (shoot);
4. otherwise no camera: every capture fails at once ("no camera").

Capture (:meth:`CameraClient.capture`): requests queue and are taken one at a time, so each
COMMAND_ACK and each captured message belongs to the one in flight. IMAGE_START_CAPTURE is
sent with param2 = 0 (interval), param3 = 1 (one image), param4 = our sequence number
(kept on a resend, so a camera that honours it does not take a second image). The capture
is done on its captured message: CAMERA_IMAGE_CAPTURED (time_boot_ms, time_utc [µs],
lat/lon [degE7], alt [mm AMSL], q (w, x, y, z) NED, image_index, capture_result 1 = ok,
file_url; PX4 streams it from ``camera_capture``) or, for ArduPilot's cameras, CAMERA_FEEDBACK
(time_usec, img_idx, lat/lng [degE7], alt_msl [m], roll/pitch/yaw [deg]; sent after every
picture by AP_Camera). A missing ACK (``ack_timeout_s``) resends; a refused ACK, a failed
capture_result or a missing captured message (``captured_timeout_s``) is a failed attempt;
after ``attempts`` attempts the capture is reported failed. Duplicate image indices (a
camera's retransmission) are ignored and counted. Times in simulation seconds. Only a
finished record with status ``captured`` makes an inspection's capture (the runner steps each
record into the agent core, :meth:`agent.runtime.shell.runtime.AgentRuntime.image_taken`):
PX4's capture_result -1 (its camera_capture ``result``: "camera does not provide feedback")
is no confirmation, and counts as a failed attempt.
"""

from __future__ import annotations

import collections
import logging
import math
import threading
from dataclasses import asdict, dataclass, field, replace
from typing import Any, Literal

from agent.flight.frames import quat_from_euler
from agent.flight.geodetic import Origin, geodetic_to_enu
from agent.flight.link import VehicleLink
from agent.wire.mavlink import mavlink

_log = logging.getLogger(f"viscover.{__name__}")

Method = Literal["image_start_capture", "digicam_control", "none"]
Status = Literal["captured", "failed"]
_INFO_ID = 259  # CAMERA_INFORMATION
_CAMERA_COMPONENTS = range(mavlink.MAV_COMP_ID_CAMERA, mavlink.MAV_COMP_ID_CAMERA6 + 1)
_COMMAND: dict[str, int] = {"image_start_capture": mavlink.MAV_CMD_IMAGE_START_CAPTURE,
                            "digicam_control": mavlink.MAV_CMD_DO_DIGICAM_CONTROL}


@dataclass(frozen=True)
class CameraConfig:
    """Time-outs [s sim] and the number of attempts per capture."""

    discover_timeout_s: float = 2.0
    ack_timeout_s: float = 1.0
    captured_timeout_s: float = 3.0
    attempts: int = 3


@dataclass(frozen=True)
class CameraChoice:
    """How captures are triggered: method, target component, param1 camera id, and why."""

    method: Method
    component: int = 0
    camera_id: int = 0
    why: str = "no camera"


@dataclass(frozen=True)
class CaptureRecord:
    """One capture's outcome, to journal: our ticket number, the landmark ids it was for,
    status, attempts, method; when asked and finished [s mission]; and from the captured
    message: image index, time_utc [µs] and time_boot_ms, latitude/longitude [degrees],
    altitude [m AMSL], attitude q (w, x, y, z) R_NED←camera, file url, position [m; world
    ENU] when a mission origin is known; ``reason`` says why a capture failed."""

    ticket: int
    landmark_ids: tuple[int, ...]
    status: Status
    attempts: int
    method: str
    t_requested: float
    t_done: float
    image_index: int | None = None
    time_utc_us: int = 0
    time_boot_ms: int = 0
    lat_deg: float | None = None
    lon_deg: float | None = None
    alt_m: float | None = None
    q_ned: tuple[float, float, float, float] | None = None
    file_url: str = ""
    p_world: tuple[float, float, float] | None = None
    reason: str = ""

    def to_dict(self) -> dict[str, Any]:
        """Plain data (JSON-able) for a journal."""
        d = asdict(self)
        d["landmark_ids"] = list(self.landmark_ids)
        return d


@dataclass
class CaptureTicket:
    """A capture in the queue or in flight; ``done`` is set with ``record``."""

    number: int
    landmark_ids: tuple[int, ...]
    t_requested: float
    attempts: int = 0
    seq: int = 0  #: IMAGE_START_CAPTURE param4 of the current attempt
    acked: bool = False
    deadline: float = math.inf  #: [s sim] of the current wait (ACK or captured message)
    record: CaptureRecord | None = None
    done: threading.Event = field(default_factory=threading.Event)

    def wait(self, timeout_wall_s: float | None = None) -> CaptureRecord | None:
        """Block until finished (at most ``timeout_wall_s`` wall seconds)."""
        self.done.wait(timeout_wall_s)
        return self.record


class CameraClient:
    """Triggers the vehicle's camera and matches what it reports (module docstring)."""

    def __init__(self, link: VehicleLink, config: CameraConfig | None = None,
                 origin: Origin | None = None) -> None:
        self.link = link
        self.cfg = config or CameraConfig()
        self.origin = origin  #: the mission origin, for records' world positions
        self.choice = CameraChoice("none")
        self.infos: dict[int, Any] = {}  #: component → its CAMERA_INFORMATION
        self.cameras: set[int] = set()  #: camera components heard
        self.duplicates = 0  #: captured messages seen before (retransmissions)
        self.unmatched = 0  #: captured messages with no capture in flight
        self._lock = threading.RLock()
        self._queue: collections.deque[CaptureTicket] = collections.deque()
        self._active: CaptureTicket | None = None
        self._finished: list[CaptureRecord] = []
        self._seen: set[tuple[str, int]] = set()
        self._numbers = 0
        self._seq = 0
        self._unsubs = [
            link.subscribe("HEARTBEAT", self._on_heartbeat),
            link.subscribe("CAMERA_INFORMATION", self._on_info),
            link.subscribe("COMMAND_ACK", self._on_ack),
            link.subscribe(("CAMERA_IMAGE_CAPTURED", "CAMERA_FEEDBACK"), self._on_captured),
            link.add_ticker(self.tick)]

    def close(self) -> None:
        """Stop listening; captures still queued are not sent."""
        for u in self._unsubs:
            u()

    # -- discovery ------------------------------------------------------------------------------
    def _on_heartbeat(self, msg: Any) -> None:
        comp = int(msg.get_srcComponent())
        if int(msg.type) == mavlink.MAV_TYPE_CAMERA or comp in _CAMERA_COMPONENTS:
            self.cameras.add(comp)

    def _on_info(self, msg: Any) -> None:
        with self._lock:
            self.infos[int(msg.get_srcComponent())] = msg

    def discover(self) -> CameraChoice:
        """Ask every camera and the autopilot for CAMERA_INFORMATION, then choose (module
        docstring); the choice is logged and kept in ``choice``."""
        link = self.link
        heard = {c for c, t in dict(link.components).items()
                 if t == mavlink.MAV_TYPE_CAMERA or c in _CAMERA_COMPONENTS}
        self.cameras |= heard
        targets = sorted(self.cameras | {mavlink.MAV_COMP_ID_CAMERA, link.cfg.target_component})
        for comp in targets:
            link.send_command(mavlink.MAV_CMD_REQUEST_MESSAGE, float(_INFO_ID), component=comp)
        link.wait(lambda: all(c in self.infos for c in targets), self.cfg.discover_timeout_s)
        self.choice = self._choose()
        _log.info("camera: %s", self.choice.why)
        return self.choice

    def _choose(self) -> CameraChoice:
        ap = self.link.cfg.target_component
        with self._lock:
            able = {c: m for c, m in self.infos.items()
                    if int(m.flags) & mavlink.CAMERA_CAP_FLAGS_CAPTURE_IMAGE}
        for comp in sorted(c for c in able if c != ap):
            m = able[comp]
            return CameraChoice("image_start_capture", comp, 0,
                                f"camera component {comp} ({_name(m)}): IMAGE_START_CAPTURE")
        if ap in able:
            dev = int(getattr(able[ap], "camera_device_id", 0))
            cid = dev if 1 <= dev <= 6 else 0
            return CameraChoice("image_start_capture", ap, cid,
                                f"autopilot camera {cid or 'all'} ({_name(able[ap])}): "
                                "IMAGE_START_CAPTURE")
        if self.link.flavour.digicam_fallback:
            return CameraChoice("digicam_control", ap, 0,
                                "no CAMERA_INFORMATION: DO_DIGICAM_CONTROL to the autopilot")
        return CameraChoice("none", 0, 0, "no camera advertised (no CAMERA_INFORMATION)")

    # -- captures -----------------------------------------------------------------------------
    def capture(self, landmark_ids: tuple[int, ...] | list[int]) -> CaptureTicket:
        """Queue a capture for ``landmark_ids``; returns its ticket at once (the record
        comes with :meth:`drain` or ``ticket.wait()``)."""
        with self._lock:
            self._numbers += 1
            t = CaptureTicket(self._numbers, tuple(int(i) for i in landmark_ids),
                              self.link.clock.now())
            self._queue.append(t)
        self.tick()
        return t

    def drain(self) -> list[CaptureRecord]:
        """The records finished since the last call, in order."""
        with self._lock:
            out, self._finished = self._finished, []
        return out

    def pending(self) -> int:
        """Captures queued or in flight."""
        with self._lock:
            return len(self._queue) + (self._active is not None)

    def tick(self) -> None:
        """Start the next capture, resend or retry on a time-out (the link's tick thread)."""
        now = self.link.clock.now()
        with self._lock:
            t = self._active
            if t is None:
                if not self._queue:
                    return
                t = self._active = self._queue.popleft()
                self._attempt(t, now, new_seq=True)
                return
            if now < t.deadline:
                return
            if not t.acked and t.attempts < self.cfg.attempts:
                self._attempt(t, now, new_seq=False)  # no ACK: the same capture again
            elif t.acked:
                self._retry(t, now, "no captured message")
            else:
                self._finish(t, None, f"no COMMAND_ACK after {t.attempts} attempts")

    def _attempt(self, t: CaptureTicket, now: float, new_seq: bool) -> None:
        if self.choice.method == "none":
            self._finish(t, None, self.choice.why)
            return
        if new_seq:
            self._seq += 1
            t.seq = self._seq
        t.attempts += 1
        t.acked = False
        t.deadline = now + self.cfg.ack_timeout_s
        c = self.choice
        command = _COMMAND[c.method]
        self.link.forget_ack(command, c.component)
        if c.method == "image_start_capture":
            self.link.send_command(command, float(c.camera_id), 0.0, 1.0, float(t.seq),
                                   component=c.component)
        else:
            self.link.send_command(command, 0.0, 0.0, 0.0, 0.0, 1.0, float(t.seq % 256),
                                   component=c.component)

    def _retry(self, t: CaptureTicket, now: float, why: str) -> None:
        if t.attempts >= self.cfg.attempts:
            self._finish(t, None, f"{why} after {t.attempts} attempts")
        else:
            _log.info("capture %d: %s, trying again", t.number, why)
            self._attempt(t, now, new_seq=True)

    def _finish(self, t: CaptureTicket, msg: Any, reason: str = "") -> None:
        rec = self._record(t, msg, reason)
        t.record = rec
        self._finished.append(rec)
        self._active = None
        t.done.set()
        if rec.status == "failed":
            _log.warning("capture %d of landmarks %s failed: %s", t.number,
                         list(t.landmark_ids), reason)

    def _on_ack(self, msg: Any) -> None:
        c = self.choice
        if c.method == "none" or int(msg.command) != _COMMAND[c.method] \
                or int(msg.get_srcComponent()) != c.component or not self.link.ack_is_ours(msg):
            return
        result = int(msg.result)
        with self._lock:
            t = self._active
            if t is None or t.acked:
                return
            now = self.link.clock.now()
            if result == mavlink.MAV_RESULT_ACCEPTED:
                t.acked, t.deadline = True, now + self.cfg.captured_timeout_s
            elif result == mavlink.MAV_RESULT_IN_PROGRESS:
                t.deadline = now + self.cfg.captured_timeout_s
            else:
                self._retry(t, now, f"refused (MAV_RESULT {result})")

    def _on_captured(self, msg: Any) -> None:
        kind = msg.get_type()
        index = int(msg.image_index if kind == "CAMERA_IMAGE_CAPTURED" else msg.img_idx)
        key = (f"{kind}:{msg.get_srcComponent()}", index)
        with self._lock:
            if key in self._seen:
                self.duplicates += 1
                return
            self._seen.add(key)
            t = self._active
            if t is None:
                self.unmatched += 1
                return
            if kind == "CAMERA_IMAGE_CAPTURED" and int(msg.capture_result) != 1:
                self._retry(t, self.link.clock.now(), "the camera reports a failed capture")
                return
            self._finish(t, msg)

    def _record(self, t: CaptureTicket, msg: Any, reason: str) -> CaptureRecord:
        rec = CaptureRecord(t.number, t.landmark_ids, "failed", t.attempts, self.choice.method,
                            t.t_requested, self.link.clock.now(), reason=reason)
        if msg is None:
            return rec
        if msg.get_type() == "CAMERA_IMAGE_CAPTURED":
            lat, lon, alt = int(msg.lat) * 1e-7, int(msg.lon) * 1e-7, int(msg.alt) * 1e-3
            q = tuple(float(a) for a in msg.q)
            rec = replace(rec, image_index=int(msg.image_index), time_utc_us=int(msg.time_utc),
                          time_boot_ms=int(msg.time_boot_ms), file_url=_text(msg.file_url))
        else:  # ArduPilot's CAMERA_FEEDBACK
            lat, lon, alt = int(msg.lat) * 1e-7, int(msg.lng) * 1e-7, float(msg.alt_msl)
            rpy = [math.radians(float(a)) for a in (msg.roll, msg.pitch, msg.yaw)]
            q = tuple(float(a) for a in quat_from_euler(*rpy))
            rec = replace(rec, image_index=int(msg.img_idx), time_utc_us=int(msg.time_usec))
        p_world = None
        if self.origin is not None and (lat, lon) != (0.0, 0.0) and math.isfinite(alt):
            p = geodetic_to_enu(lat, lon, alt, self.origin)
            p_world = (float(p[0]), float(p[1]), float(p[2]))
        return replace(rec, status="captured", reason="", lat_deg=lat, lon_deg=lon, alt_m=alt,
                       q_ned=q if len(q) == 4 else None, p_world=p_world)


def _text(raw: Any) -> str:
    """A MAVLink char array as text (pymavlink gives str or bytes, NUL-padded)."""
    if isinstance(raw, bytes):
        raw = raw.decode("utf-8", "replace")
    return str(raw).split("\x00", 1)[0]


def _name(info: Any) -> str:
    """'vendor model' of a CAMERA_INFORMATION (byte arrays, NUL-padded)."""
    def txt(v: Any) -> str:
        return _text(bytes(v) if isinstance(v, list | tuple) else v).strip()

    name = f"{txt(info.vendor_name)} {txt(info.model_name)}".strip()
    return name or "unnamed"
