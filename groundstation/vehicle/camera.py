"""The simulated camera, answered where each autopilot answers it.

* ArduPilot 4.4+ (libraries/AP_Camera/AP_Camera.cpp ``handle_command``, AP_Camera_Backend.cpp;
  GCS_Common ``handle_command_camera``): AP_Camera on the autopilot component, present when
  CAM1_TYPE is set (1 Servo .. 5, 7; 6 MAVLinkCamV2, a separate camera the autopilot only
  forwards to, is not simulated). MAV_CMD_IMAGE_START_CAPTURE: param1 (camera id, 0 all, 1
  first) negative UNSUPPORTED; one picture when param3 = 1 or param2 = param3 = 0, ACCEPTED,
  or FAILED while CAM1_INTRVAL_MIN [s] has not passed since the last one (the picture is then
  taken as soon as it has); param3 = 0 with an interval: pictures every param2 [s] for ever,
  else param3 of them; FAILED for a camera that is not there (no camera, param1 ≥ 2).
  MAV_CMD_IMAGE_STOP_CAPTURE ACCEPTED. MAV_CMD_DO_DIGICAM_CONTROL: ACCEPTED, a picture when
  param5 = 1. Each picture: CAMERA_FEEDBACK (time_usec UTC, cam_idx 0, img_idx the image
  count since boot (1 for the first), lat/lng degE7 and alt_msl / alt_rel [m] of the EKF's
  position, the vehicle's roll/pitch/yaw [deg], flags PHOTO, completed_captures 0 as without
  a feedback pin). ArduPilot sends no CAMERA_IMAGE_CAPTURED (ardupilot_wiki
  dev/source/docs/mavlink-camera.rst: "not yet supported"). CAMERA_INFORMATION (flags
  CAPTURE_IMAGE, lens_id 0, gimbal_device_id 1 with a mount) and CAMERA_CAPTURE_STATUS
  (image_status 2 while an interval runs, image_count) on MAV_CMD_REQUEST_MESSAGE. ArduPilot
  itself fills vendor, model, sensor and focal length only from a camera-information script;
  this simulator sends :data:`INFO` as such a configured vehicle does.
* PX4 (docs camera_architecture.md: "PX4 does not have specific handling for MAVLink cameras
  that support the Camera Protocol v2"): the camera is its own component
  (MAV_COMP_ID_CAMERA, HEARTBEAT MAV_TYPE_CAMERA, autopilot INVALID) when the vehicle carries
  the payload, behaving as PX4 SITL's camera manager (PX4-SITL_gazebo-classic
  gazebo_camera_manager_plugin.cpp): commands addressed to it only; IMAGE_START_CAPTURE
  TEMPORARILY_REJECTED while capturing, param3 = 1 one picture, param3 ≥ 0 with param2 > 0
  an interval series (0: for ever), anything else DENIED; IMAGE_STOP_CAPTURE ACCEPTED;
  REQUEST_MESSAGE / REQUEST_CAMERA_INFORMATION / _CAPTURE_STATUS answered; a picture is
  CAMERA_IMAGE_CAPTURED (time_boot_ms, time_utc [µs], lat/lon degE7, alt [mm AMSL],
  relative_alt [mm above home], q = camera attitude in NED with the gimbal's pitch,
  image_index from 0, capture_result 1, file_url). REQUEST_MESSAGE of CAMERA_IMAGE_CAPTURED
  with param2 = an index sends that capture again (camera protocol); other commands
  UNSUPPORTED. The autopilot component answers camera commands UNSUPPORTED.

Shutter lag: the picture is exposed SHUTTER_LAG [s] after the command (the pose is read then).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from agent.wire.mavlink import mavlink as mav
from groundstation.vehicle.conventions import geodetic, utc_us
from groundstation.vehicle.inbound import MSG_ID, as_int

M = mav
SHUTTER_LAG = 0.05


@dataclass(frozen=True)
class CameraInfo:
    """CAMERA_INFORMATION: vendor, model, focal length [mm], sensor width, height [mm],
    resolution [px]."""

    vendor: bytes
    model: bytes
    focal_length: float
    sensor_h: float
    sensor_v: float
    res_h: int
    res_v: int

    @property
    def hfov(self) -> float:
        """Horizontal field of view [rad]."""
        return 2.0 * math.atan(self.sensor_h / (2.0 * self.focal_length))


#: A 1/2.3" 12 MP inspection camera: about 69° x 54° field of view.
INFO = CameraInfo(b"viscover", b"sim-rgb-12mp", 4.5, 6.17, 4.55, 4000, 3000)


@dataclass
class Capture:
    """One picture: index, time [s sim], lat/lon degE7, alt [mm AMSL], relative alt [mm],
    camera q (w, x, y, z) [NED], vehicle attitude (roll, pitch, yaw) [rad], file url."""

    index: int
    t: float
    lat: int
    lon: int
    alt: int
    rel_alt: int
    q: list[float]
    att: tuple[float, float, float]
    url: str


class Camera:
    """One vehicle's camera (module docstring)."""

    def __init__(self, ap: Any) -> None:
        self.ap = ap
        self.captures: list[Capture] = []
        self.count = 0  #: pictures taken since boot
        self.interval = 0.0  #: [s] of a running series
        self.remaining = 0  #: pictures left in the series (−1: for ever)
        self.next_shot: float | None = None
        self.shots: list[float] = []  #: exposure times scheduled [s sim]
        self.last_shot = -math.inf
        self.pending = False  #: ArduPilot: a picture waits for CAM1_INTRVAL_MIN
        self._next_heartbeat = 0.0

    @property
    def kind(self) -> str:
        """'autopilot' (ArduPilot AP_Camera), 'component' (PX4 with a MAVLink camera), 'none'."""
        return str(self.ap.flavour.camera_kind(self.ap))

    # -- ArduPilot: commands on the autopilot -------------------------------------------
    def autopilot_command(self, cmd: int, p: list[float], t: float) -> int:
        """IMAGE_START/STOP_CAPTURE and DO_DIGICAM_CONTROL sent to the autopilot."""
        if not self.ap.flavour.autopilot_camera_commands:
            return int(M.MAV_RESULT_UNSUPPORTED)
        if cmd == M.MAV_CMD_DO_DIGICAM_CONTROL:
            shot = as_int(p[4], (-(2**31), 2**31 - 1))
            if shot == 1 and self.kind == "autopilot":
                self._ardupilot_take(t)
            return int(M.MAV_RESULT_ACCEPTED)
        if math.isnan(p[0]) or p[0] < 0:
            return int(M.MAV_RESULT_DENIED if math.isnan(p[0]) else M.MAV_RESULT_UNSUPPORTED)
        if cmd == M.MAV_CMD_IMAGE_STOP_CAPTURE:
            self.remaining, self.next_shot = 0, None
            return int(M.MAV_RESULT_ACCEPTED)
        if not all(math.isfinite(x) for x in p[:3]):
            return int(M.MAV_RESULT_DENIED)
        if self.kind != "autopilot" or p[0] >= 2:
            return int(M.MAV_RESULT_FAILED)
        if p[2] == 1.0 or (p[1] == 0.0 and p[2] == 0.0):
            return int(M.MAV_RESULT_ACCEPTED if self._ardupilot_take(t) else M.MAV_RESULT_FAILED)
        self._series(p[1], p[2], t)
        return int(M.MAV_RESULT_ACCEPTED)

    def _ardupilot_take(self, t: float) -> bool:
        gap = float(self.ap.params_table["CAM1_INTRVAL_MIN"])
        if t - self.last_shot < gap:
            self.pending = True
            return False
        self.pending = False
        self._expose(t)
        return True

    def _series(self, interval: float, count: float, t: float) -> None:
        self.interval = max(interval, 0.0)
        self.remaining = -1 if count == 0 else int(count)
        self.next_shot = t

    # -- PX4: the camera component ------------------------------------------------------
    def component_command(self, m: Any, t: float) -> None:
        """A COMMAND_LONG / COMMAND_INT addressed to the camera component: one ACK."""
        cmd = int(m.command)
        p = [float(getattr(m, f"param{k}")) for k in range(1, 5)]
        after = None
        if cmd == M.MAV_CMD_IMAGE_START_CAPTURE:
            result = self.component_start(p, t)
        elif cmd == M.MAV_CMD_IMAGE_STOP_CAPTURE:
            self.remaining, self.next_shot = 0, None
            result = M.MAV_RESULT_ACCEPTED
        elif cmd == M.MAV_CMD_REQUEST_CAMERA_INFORMATION:
            result, after = M.MAV_RESULT_ACCEPTED, M.MAVLINK_MSG_ID_CAMERA_INFORMATION
        elif cmd == M.MAV_CMD_REQUEST_CAMERA_CAPTURE_STATUS:
            result, after = M.MAV_RESULT_ACCEPTED, M.MAVLINK_MSG_ID_CAMERA_CAPTURE_STATUS
        elif cmd == M.MAV_CMD_REQUEST_MESSAGE:
            msgid = as_int(p[0], MSG_ID)
            if msgid is None:
                result = M.MAV_RESULT_DENIED
            elif msgid in (M.MAVLINK_MSG_ID_CAMERA_INFORMATION,
                           M.MAVLINK_MSG_ID_CAMERA_CAPTURE_STATUS):
                result, after = M.MAV_RESULT_ACCEPTED, msgid
            elif msgid == M.MAVLINK_MSG_ID_CAMERA_IMAGE_CAPTURED:
                index = as_int(p[1], (0, 2**31 - 1))
                ok = index is not None and index < len(self.captures)
                result = M.MAV_RESULT_ACCEPTED if ok else M.MAV_RESULT_DENIED
                after = -1 - index if ok and index is not None else None
            else:
                result = M.MAV_RESULT_UNSUPPORTED
        elif cmd == M.MAV_CMD_SET_CAMERA_MODE:
            result = M.MAV_RESULT_ACCEPTED
        else:
            result = M.MAV_RESULT_UNSUPPORTED
        enc = self.ap.encoder(M.MAV_COMP_ID_CAMERA)
        enc.command_ack_send(cmd, result, 0, 0, m.get_srcSystem(), m.get_srcComponent())
        if after is not None:
            if after < 0:
                self._send_captured(self.captures[-1 - after])
            else:
                self.send(after, t)

    def component_start(self, p: list[float], t: float) -> int:
        """IMAGE_START_CAPTURE at the camera component (p: param1..param4; also a mission's
        capture item, which PX4 re-emits to the camera): the MAV_RESULT."""
        if self.shots or self.remaining != 0:
            return int(M.MAV_RESULT_TEMPORARILY_REJECTED)
        if p[2] == 1.0:
            self.shots.append(t + SHUTTER_LAG)
            return int(M.MAV_RESULT_ACCEPTED)
        if p[2] >= 0 and p[1] > 0 and math.isfinite(p[1]) and math.isfinite(p[2]):
            self._series(p[1], p[2], t + SHUTTER_LAG)
            return int(M.MAV_RESULT_ACCEPTED)
        return int(M.MAV_RESULT_DENIED)

    # -- shared -------------------------------------------------------------------------
    def step(self, t: float) -> None:
        """Heartbeat of the camera component (1 Hz), due exposures and series."""
        kind = self.kind
        if kind == "component" and t >= self._next_heartbeat:
            self._next_heartbeat = t + 1.0
            self.ap.encoder(M.MAV_COMP_ID_CAMERA).heartbeat_send(
                M.MAV_TYPE_CAMERA, M.MAV_AUTOPILOT_INVALID, 0, 0, M.MAV_STATE_ACTIVE)
        if kind == "none":
            return
        if self.pending and kind == "autopilot":
            self._ardupilot_take(t)
        while self.shots and self.shots[0] <= t:
            self._expose(self.shots.pop(0))
        if self.next_shot is not None and t >= self.next_shot and self.remaining != 0:
            if kind == "component" or self._ardupilot_take(t):
                if kind == "component":
                    self._expose(t)
                self.remaining = max(self.remaining - 1, -1) if self.remaining > 0 else -1
                self.next_shot = t + self.interval if self.remaining != 0 else None

    def _expose(self, t: float) -> None:
        """Take a picture at t: the pose then, and its message."""
        ap = self.ap
        p, _, att, _ = ap.estimate()
        lat, lon, alt = geodetic(ap.origin, p)
        rel = round((float(ap.home_ned()[2]) - float(p[2])) * 1000.0)
        a = (float(att[0]), float(att[1]), float(att[2]))
        index = self.count + ap.flavour.first_image_index
        url = f"file:///sim/{ap.name}/DSC{index:05d}.jpg"
        cap = Capture(index, t, lat, lon, alt, rel, ap.gimbal.camera_q(a), a, url)
        self.count += 1
        self.last_shot = t
        self.captures.append(cap)
        ap.event(t, "camera_capture")
        if self.kind == "component":
            self._send_captured(cap)
        else:
            self._send_feedback(cap)

    def _send_captured(self, c: Capture) -> None:
        self.ap.encoder(M.MAV_COMP_ID_CAMERA).camera_image_captured_send(
            _ms(c.t), utc_us(c.t), 0, c.lat, c.lon, c.alt, c.rel_alt, c.q, c.index, 1,
            c.url.encode())

    def _send_feedback(self, c: Capture) -> None:
        r, p, y = (math.degrees(a) for a in c.att)
        self.ap.mav.camera_feedback_send(utc_us(c.t), 0, 0, c.index, c.lat, c.lon,
                                         c.alt / 1000.0, c.rel_alt / 1000.0, r, p, y % 360.0,
                                         0.0, M.CAMERA_FEEDBACK_PHOTO, 0)

    def available(self, msgid: int) -> bool:
        """The autopilot answers REQUEST_MESSAGE of camera message ``msgid`` (ArduPilot)."""
        return self.kind == "autopilot" and (msgid != M.MAVLINK_MSG_ID_CAMERA_FEEDBACK
                                             or bool(self.captures))

    def send(self, msgid: int, t: float) -> None:
        """CAMERA_INFORMATION, CAMERA_CAPTURE_STATUS or (ArduPilot) the last CAMERA_FEEDBACK,
        from the component that answers for this camera."""
        comp = self.kind == "component"
        enc = self.ap.encoder(M.MAV_COMP_ID_CAMERA) if comp else self.ap.mav
        if msgid == M.MAVLINK_MSG_ID_CAMERA_INFORMATION:
            gimbal = 0 if comp else (1 if self.ap.gimbal.present else 0)
            enc.camera_information_send(
                _ms(t), _pad(INFO.vendor), _pad(INFO.model), 0x00000001, INFO.focal_length,
                INFO.sensor_h, INFO.sensor_v, INFO.res_h, INFO.res_v, 0,
                M.CAMERA_CAP_FLAGS_CAPTURE_IMAGE, 0, b"", gimbal, 0 if comp else 1)
        elif msgid == M.MAVLINK_MSG_ID_CAMERA_CAPTURE_STATUS:
            series = self.remaining != 0
            status = (3 if series else (1 if self.shots else 0)) if comp else (2 if series else 0)
            enc.camera_capture_status_send(_ms(t), status, 0, self.interval, 0, math.nan,
                                           self.count)
        elif msgid == M.MAVLINK_MSG_ID_CAMERA_FEEDBACK and self.captures:
            self._send_feedback(self.captures[-1])


def _ms(t: float) -> int:
    return int(max(t, 0.0) * 1000) & 0xFFFFFFFF


def _pad(name: bytes) -> list[int]:
    """A uint8[32] name field."""
    return list(name[:32].ljust(32, b"\0"))
