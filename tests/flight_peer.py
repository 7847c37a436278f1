"""A small scripted MAVLink peer for the flight clients' tests: one autopilot (ArduPilot or
PX4) on loopback UDP that answers what the clients ask the way the autopilots' own sources
do (cited in :mod:`agent.flight.camera`, :mod:`~agent.flight.gimbal`,
:mod:`~agent.flight.fence`, :mod:`~agent.flight.mission_protocol`), with extra components
(a PX4 MAVLink camera at component 100, a gimbal device at 154) sharing its socket.

Not a vehicle simulation: positions, attitudes and batteries are whatever the test sets.
Knobs: ``drop_acks`` (command → how many of its ACKs to swallow), ``drop_captured`` (how many
captured messages to swallow), ``capture_result`` (CAMERA_IMAGE_CAPTURED's), ``log`` (every
message received, as (type, msg)).
"""

from __future__ import annotations

import math
import struct
import threading
import time
from typing import Any

from agent.flight.frames import quat_from_euler
from agent.wire.mavlink import mavlink, mavutil, px4_custom_mode

CAP = mavlink.CAMERA_CAP_FLAGS_CAPTURE_IMAGE
GLOBAL_FRAMES = (mavlink.MAV_FRAME_GLOBAL, mavlink.MAV_FRAME_GLOBAL_INT,
                 mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT, mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT)


class Peer:
    """One scripted autopilot (``flavour`` 'ardupilot' or 'px4'); ``ardupilot_version``
    (major, minor) decides its camera interface (4.4: IMAGE_START_CAPTURE, 4.5:
    CAMERA_INFORMATION); ``camera``/``gimbal`` whether it has them."""

    def __init__(self, flavour: str = "ardupilot", sysid: int = 1, camera: bool = True,
                 gimbal: bool = True, ardupilot_version: tuple[int, int] = (4, 5)) -> None:
        self.flavour = flavour
        self.px4 = flavour == "px4"
        self.sysid = sysid
        self.conn: Any = mavutil.mavlink_connection("udpin:127.0.0.1:0", source_system=sysid,
                                                    source_component=1)
        self.port = int(self.conn.port.getsockname()[1])
        self.cam_mav = mavlink.MAVLink(self.conn, srcSystem=sysid, srcComponent=100)
        self.gimbal_mav = mavlink.MAVLink(self.conn, srcSystem=sysid, srcComponent=154)
        self.has_camera, self.has_gimbal, self.ap_version = camera, gimbal, ardupilot_version
        self.params: dict[str, float] = {"FENCE_ENABLE": 1, "FENCE_ACTION": 1, "FENCE_TYPE": 2,
                                         "FENCE_ALT_MAX": 100, "GUID_OPTIONS": 0,
                                         "GF_ACTION": 2, "GF_MAX_VER_DIST": 120,
                                         "COM_OF_LOSS_T": 0.5, "COM_OBL_RC_ACT": 4,
                                         "MOT_THST_HOVER": 0.35, "MPC_THR_HOVER": 0.5,
                                         "ARMING_CHECK": 1}
        self.int_params = {"FENCE_ENABLE", "FENCE_ACTION", "FENCE_TYPE", "GUID_OPTIONS",
                           "GF_ACTION", "COM_OBL_RC_ACT", "ARMING_CHECK"}
        self.custom_mode = 0
        self.armed = False
        self.log: list[tuple[str, Any]] = []
        self.drop_acks: dict[int, int] = {}
        self.drop_captured = 0
        self.capture_result = 1
        self.image_index = 0  # ArduPilot counts from 1 (image_index++ before feedback)
        self.fence: list[Any] = []
        self._upload: list[Any | None] | None = None
        self._gcs = (0, 0)
        self.fence_breach = (0, 0, 0)  # (status, count, type)
        self.origin = (473977420, 85455940, 488000)  # degE7, degE7, mm AMSL (Zurich)
        self.home = (473977420, 85455940, 488000)
        self.pose_ned = [0.0, 0.0, -1.0, 0.0, 0.0, 0.0]  # x, y, z [m], vx, vy, vz [m/s]
        self.rpy = [0.0, 0.0, 0.0]
        self.stream_pose = True
        self.odometry = False
        self.battery = {"pct": 80, "mv": 15800, "ca": 1200, "mah": 900}
        self.gimbal_pitch = 0.0  # [rad]
        self.gimbal_target = 0.0
        self.gimbal_primary = (0, 0)
        self.last_setpoint = -1e9
        self._boot = time.monotonic()
        self._stop = threading.Event()
        self._threads = [threading.Thread(target=self._rx, daemon=True),
                         threading.Thread(target=self._tx, daemon=True)]
        for th in self._threads:
            th.start()

    @property
    def conn_str(self) -> str:
        """The driver's connection string to this peer."""
        return f"udpout:127.0.0.1:{self.port}"

    def close(self) -> None:
        self._stop.set()
        for th in self._threads:
            th.join(2.0)
        self.conn.close()

    def __enter__(self) -> Peer:
        return self

    def __exit__(self, *_exc: object) -> None:
        self.close()

    def ms(self) -> int:
        return int((time.monotonic() - self._boot) * 1000) & 0xFFFFFFFF

    def received(self, kind: str) -> list[Any]:
        return [m for k, m in list(self.log) if k == kind]

    def commands(self, command: int) -> list[Any]:
        return [m for m in self.received("COMMAND_LONG") if m.command == command]

    # -- sending ------------------------------------------------------------------------------
    def ack(self, msg: Any, result: int, mav: Any = None) -> None:
        left = self.drop_acks.get(int(msg.command), 0)
        if left > 0:
            self.drop_acks[int(msg.command)] = left - 1
            return
        (mav or self.conn.mav).command_ack_send(int(msg.command), result, 0, 0,
                                                msg.get_srcSystem(), msg.get_srcComponent())

    def param_value(self, name: str) -> None:
        v = self.params[name]
        ptype = mavlink.MAV_PARAM_TYPE_REAL32
        if self.px4 and name in self.int_params:  # PX4: integers byte-wise in the float
            ptype = mavlink.MAV_PARAM_TYPE_INT32
            v = struct.unpack("<f", struct.pack("<i", int(v)))[0]
        self.conn.mav.param_value_send(name.encode(), v, ptype, len(self.params), 0)

    def statustext(self, text: str, severity: int = mavlink.MAV_SEVERITY_CRITICAL) -> None:
        self.conn.mav.statustext_send(severity, text.encode())

    def _tx(self) -> None:
        n = 0
        while not self._stop.is_set():
            if not self.conn.clients:  # no driver yet
                self._stop.wait(0.02)
                continue
            if n % 20 == 0:
                ap = mavlink.MAV_AUTOPILOT_PX4 if self.px4 else mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA
                base = mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | (
                    mavlink.MAV_MODE_FLAG_SAFETY_ARMED if self.armed else 0)
                try:
                    self.conn.mav.heartbeat_send(mavlink.MAV_TYPE_QUADROTOR, ap, base,
                                                 self.custom_mode, mavlink.MAV_STATE_ACTIVE)
                except RuntimeError:  # a client joined while we sent to all: next time
                    pass
                if self.px4 and self.has_camera:
                    self.cam_mav.heartbeat_send(mavlink.MAV_TYPE_CAMERA,
                                                mavlink.MAV_AUTOPILOT_INVALID, 0, 0,
                                                mavlink.MAV_STATE_ACTIVE)
            try:
                if n % 10 == 0:
                    self._slow()
                if self.stream_pose:
                    self._pose()
                if self.has_gimbal and n % 2 == 0:
                    self._gimbal_status()
            except RuntimeError:  # pymavlink's udpin: a client joined while we sent to all
                pass
            n += 1
            self._stop.wait(0.05)

    def _slow(self) -> None:
        b = self.battery
        cells = [b["mv"]] + [65535] * 9
        self.conn.mav.battery_status_send(0, 0, 0, 2500, cells, b["ca"], b["mah"], -1,
                                          b["pct"], 0, 0, [0, 0, 0, 0], 0, 0)
        bit = mavlink.MAV_SYS_STATUS_GEOFENCE if not self.px4 and self.params["FENCE_ENABLE"] \
            else 0
        health = 0 if self.fence_breach[0] else bit
        self.conn.mav.sys_status_send(bit, bit, health, 0, b["mv"], b["ca"], b["pct"],
                                      0, 0, 0, 0, 0, 0)
        if not self.px4 and self.params["FENCE_ENABLE"]:
            st, cnt, typ = self.fence_breach
            self.conn.mav.fence_status_send(st, cnt, typ, self.ms(), 0)

    def _pose(self) -> None:
        ms = self.ms()
        p = self.pose_ned
        if self.odometry:
            q = [float(a) for a in quat_from_euler(*self.rpy)]
            nan21 = [math.nan] * 21
            self.conn.mav.odometry_send(ms * 1000, mavlink.MAV_FRAME_LOCAL_NED,
                                        mavlink.MAV_FRAME_LOCAL_NED, p[0], p[1], p[2], q,
                                        p[3], p[4], p[5], 0, 0, 0, nan21, nan21, 0,
                                        mavlink.MAV_ESTIMATOR_TYPE_AUTOPILOT, 100)
            return
        self.conn.mav.attitude_send(ms, *self.rpy, 0.0, 0.0, 0.0)
        self.conn.mav.local_position_ned_send(ms, *p)

    def _gimbal_status(self) -> None:
        step = math.radians(60.0) * 0.1  # 60 deg/s at 10 Hz
        d = self.gimbal_target - self.gimbal_pitch
        self.gimbal_pitch += max(-step, min(step, d))
        q = [float(a) for a in quat_from_euler(0.0, self.gimbal_pitch, 0.0)]
        mav, dev = (self.gimbal_mav, 0) if self.px4 else (self.conn.mav, 1)
        mav.gimbal_device_attitude_status_send(0, 0, self.ms(), 0, q, math.nan, math.nan,
                                               math.nan, 0, math.nan, math.nan, dev)

    # -- receiving ----------------------------------------------------------------------------
    def _rx(self) -> None:
        while not self._stop.is_set():
            try:
                msg = self.conn.recv_match(blocking=True, timeout=0.05)
            except OSError:
                continue
            if msg is None or msg.get_type() == "BAD_DATA":
                continue
            self.log.append((msg.get_type(), msg))
            handler = getattr(self, f"_on_{msg.get_type().lower()}", None)
            if handler is not None:
                handler(msg)

    def _on_set_attitude_target(self, _msg: Any) -> None:
        self.last_setpoint = time.monotonic()

    def _on_param_request_read(self, msg: Any) -> None:
        name = str(msg.param_id)
        if name in self.params:
            self.param_value(name)

    def _on_param_set(self, msg: Any) -> None:
        name = str(msg.param_id)
        if name in self.params:
            self.params[name] = float(msg.param_value)
            self.param_value(name)

    def _on_command_long(self, msg: Any) -> None:
        cmd, comp = int(msg.command), int(msg.target_component)
        if comp == 100:
            if self.px4 and self.has_camera:
                self._camera_component(msg)
            return
        if comp not in (0, 1):
            return
        handler = getattr(self, f"_cmd_{cmd}", None)
        if handler is None:
            self.ack(msg, mavlink.MAV_RESULT_UNSUPPORTED)
        else:
            handler(msg)

    def _cmd_176(self, msg: Any) -> None:  # DO_SET_MODE
        if self.px4:
            mode = px4_custom_mode(int(msg.param2), int(msg.param3))
            if int(msg.param2) == 6 and time.monotonic() - self.last_setpoint > 0.5:
                self.ack(msg, mavlink.MAV_RESULT_DENIED)  # OFFBOARD needs a live stream
                return
        else:
            mode = int(msg.param2)
        self.custom_mode = mode
        self.ack(msg, mavlink.MAV_RESULT_ACCEPTED)

    def _cmd_400(self, msg: Any) -> None:  # COMPONENT_ARM_DISARM
        self.armed = msg.param1 == 1
        self.ack(msg, mavlink.MAV_RESULT_ACCEPTED)

    def _cmd_512(self, msg: Any) -> None:  # REQUEST_MESSAGE
        mid = int(msg.param1)
        answers = {49: self._origin, 242: self._home, 259: self._camera_info_ap,
                   280: self._gimbal_info}
        fn = answers.get(mid)
        ok = fn is not None and fn()
        self.ack(msg, mavlink.MAV_RESULT_ACCEPTED if ok else mavlink.MAV_RESULT_FAILED)

    def _origin(self) -> bool:
        lat, lon, alt = self.origin
        self.conn.mav.gps_global_origin_send(lat, lon, alt, 0)
        return True

    def _home(self) -> bool:
        lat, lon, alt = self.home
        self.conn.mav.home_position_send(lat, lon, alt, 0, 0, 0, [1, 0, 0, 0], 0, 0, 0, 0)
        return True

    def _camera_info(self, mav: Any, device_id: int = 0) -> None:
        mav.camera_information_send(self.ms(), b"Acme".ljust(32, b"\0"),
                                    b"Inspect-1".ljust(32, b"\0"), 0, math.nan, math.nan,
                                    math.nan, 0, 0, 0, CAP, 0, b"", 0, device_id)

    def _camera_info_ap(self) -> bool:
        """ArduPilot 4.5+: the autopilot answers for its AP_Camera backends (lens_id =
        instance); PX4 has no CAMERA_INFORMATION of its own."""
        if self.px4 or not self.has_camera or self.ap_version < (4, 5):
            return False
        self._camera_info(self.conn.mav)
        return True

    def _gimbal_info(self) -> bool:
        if not self.has_gimbal:
            return False
        lo, hi = math.radians(-90.0), math.radians(20.0)
        self.conn.mav.gimbal_manager_information_send(self.ms(), 0, 0 if self.px4 else 1,
                                                      0, 0, lo, hi, -math.pi, math.pi)
        return True

    def _cmd_2000(self, msg: Any) -> None:  # IMAGE_START_CAPTURE, ArduPilot 4.4+
        if not self.has_camera or self.px4 or self.ap_version < (4, 4):
            self.ack(msg, mavlink.MAV_RESULT_UNSUPPORTED)
            return
        self.ack(msg, mavlink.MAV_RESULT_ACCEPTED)
        self._feedback()

    def _cmd_203(self, msg: Any) -> None:  # DO_DIGICAM_CONTROL, every ArduPilot
        if self.px4:
            self.ack(msg, mavlink.MAV_RESULT_UNSUPPORTED)
            return
        self.ack(msg, mavlink.MAV_RESULT_ACCEPTED)
        if msg.param5 == 1 and self.has_camera:
            self._feedback()

    def _feedback(self) -> None:
        """AP_Camera_Backend: image_index++ then CAMERA_FEEDBACK (deg, m)."""
        self.image_index += 1
        if self.drop_captured > 0:
            self.drop_captured -= 1
            return
        lat, lon, alt = self.origin
        self.conn.mav.camera_feedback_send(int(time.time() * 1e6), 0, 0, self.image_index,
                                           lat, lon, alt / 1000.0 + 1.0, 1.0, 0.0, -10.0,
                                           90.0, 0.0, 0, self.image_index)

    def _camera_component(self, msg: Any) -> None:
        """A PX4 MAVLink camera (camera protocol v2) at component 100."""
        cmd = int(msg.command)
        if cmd == mavlink.MAV_CMD_REQUEST_MESSAGE and int(msg.param1) == 259:
            self.ack(msg, mavlink.MAV_RESULT_ACCEPTED, self.cam_mav)
            self._camera_info(self.cam_mav)
        elif cmd == mavlink.MAV_CMD_IMAGE_START_CAPTURE:
            self.ack(msg, mavlink.MAV_RESULT_ACCEPTED, self.cam_mav)
            if self.drop_captured > 0:
                self.drop_captured -= 1
                return
            lat, lon, alt = self.origin
            self.cam_mav.camera_image_captured_send(
                self.ms(), int(time.time() * 1e6), 1, lat, lon, alt + 1000, 1000,
                [1.0, 0.0, 0.0, 0.0], self.image_index, self.capture_result,
                f"file:///dcim/{self.image_index:04d}.jpg".encode())
            self.image_index += 1
        else:
            self.ack(msg, mavlink.MAV_RESULT_UNSUPPORTED, self.cam_mav)

    def _cmd_1001(self, msg: Any) -> None:  # DO_GIMBAL_MANAGER_CONFIGURE
        if not self.has_gimbal:
            self.ack(msg, mavlink.MAV_RESULT_FAILED)
            return
        self.gimbal_primary = (int(msg.param1), int(msg.param2))
        self.ack(msg, mavlink.MAV_RESULT_ACCEPTED)

    def _cmd_1000(self, msg: Any) -> None:  # DO_GIMBAL_MANAGER_PITCHYAW
        if not self.has_gimbal:
            self.ack(msg, mavlink.MAV_RESULT_FAILED)
            return
        if self.px4 and (msg.get_srcSystem(), msg.get_srcComponent()) != self.gimbal_primary:
            self.ack(msg, mavlink.MAV_RESULT_DENIED)  # PX4: only the primary control
            return
        if math.isnan(msg.param1) or math.isnan(msg.param2):
            self.ack(msg, mavlink.MAV_RESULT_FAILED)  # ArduPilot: both angles needed
            return
        self.gimbal_target = max(math.radians(-90.0), min(math.radians(20.0),
                                                          math.radians(msg.param1)))
        self.ack(msg, mavlink.MAV_RESULT_ACCEPTED)

    # -- mission protocol (fence) -------------------------------------------------------------
    def _request_item(self, seq: int) -> None:
        """ArduPilot asks with MISSION_REQUEST, PX4 (int mode) with MISSION_REQUEST_INT."""
        send = self.conn.mav.mission_request_int_send if self.px4 else \
            self.conn.mav.mission_request_send
        send(*self._gcs, seq, mavlink.MAV_MISSION_TYPE_FENCE)

    def _on_mission_count(self, msg: Any) -> None:
        if int(msg.mission_type) != mavlink.MAV_MISSION_TYPE_FENCE:
            return
        self._gcs = (msg.get_srcSystem(), msg.get_srcComponent())
        self._upload = [None] * int(msg.count)
        if msg.count == 0:
            self.fence = []
            self.conn.mav.mission_ack_send(*self._gcs, mavlink.MAV_MISSION_ACCEPTED,
                                           mavlink.MAV_MISSION_TYPE_FENCE)
            return
        self._request_item(0)

    def _on_mission_item_int(self, msg: Any) -> None:
        up = self._upload
        if up is None or int(msg.mission_type) != mavlink.MAV_MISSION_TYPE_FENCE:
            return
        if int(msg.frame) not in GLOBAL_FRAMES:
            self._upload = None
            self.conn.mav.mission_ack_send(*self._gcs, mavlink.MAV_MISSION_UNSUPPORTED_FRAME,
                                           mavlink.MAV_MISSION_TYPE_FENCE)
            return
        up[int(msg.seq)] = msg
        nxt = next((k for k, m in enumerate(up) if m is None), None)
        if nxt is None:
            self.fence, self._upload = list(up), None
            self.conn.mav.mission_ack_send(*self._gcs, mavlink.MAV_MISSION_ACCEPTED,
                                           mavlink.MAV_MISSION_TYPE_FENCE)
        else:
            self._request_item(nxt)

    def _on_mission_request_list(self, msg: Any) -> None:
        if int(msg.mission_type) == mavlink.MAV_MISSION_TYPE_FENCE:
            self.conn.mav.mission_count_send(msg.get_srcSystem(), msg.get_srcComponent(),
                                             len(self.fence), mavlink.MAV_MISSION_TYPE_FENCE)

    def _on_mission_request_int(self, msg: Any) -> None:
        if int(msg.mission_type) != mavlink.MAV_MISSION_TYPE_FENCE or msg.seq >= len(self.fence):
            return
        it = self.fence[int(msg.seq)]
        frame = int(it.frame) if self.px4 else 0  # ArduPilot stores no frame: 0
        self.conn.mav.mission_item_int_send(msg.get_srcSystem(), msg.get_srcComponent(),
                                            it.seq, frame, it.command, 0, 0, it.param1, 0, 0,
                                            0, it.x, it.y, 0, mavlink.MAV_MISSION_TYPE_FENCE)


def decoded(msg: Any, src: int = 1, comp: int = 1) -> Any:
    """``msg`` as if received from system ``src``, component ``comp`` (packed and parsed)."""
    buf = msg.pack(mavlink.MAVLink(None, srcSystem=src, srcComponent=comp))
    return mavlink.MAVLink(None).parse_char(bytes(buf))
