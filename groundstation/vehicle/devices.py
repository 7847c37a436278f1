"""The simulated autopilot's outdoor equipment wired into it: camera, gimbal, fence, battery
monitor, GNSS-aided EKF (one module each), their commands, messages and streams.

Components: the autopilot answers on component 1; PX4's camera is its own component
(MAV_COMP_ID_CAMERA) and its gimbal device attitude comes from MAV_COMP_ID_GIMBAL (see
:mod:`.camera`, :mod:`.gimbal`). A command addressed to the camera component goes to the
camera only (one ACK from it); messages addressed to another component are not processed.
The equipment is checked every tick (:meth:`Devices.supervise`): gimbal slew, exposures, fence
(10 Hz), battery failsafe levels, PX4's delayed failsafe actions and the stored mission
(:mod:`.mission_exec`: MISSION_SET_CURRENT, MAV_CMD_MISSION_START, MISSION_CURRENT).

Extra messages (encoders registered with :mod:`.telemetry`), each only where it exists:
GPS_RAW_INT (5 Hz with a GNSS receiver), GPS_GLOBAL_ORIGIN (on request), ODOMETRY (PX4, on
request: pose and velocity NED, body rates), FENCE_STATUS (ArduPilot, 1 Hz while the
fence is enabled), CAMERA_INFORMATION / CAMERA_CAPTURE_STATUS / CAMERA_FEEDBACK (ArduPilot's
AP_Camera, on request), GIMBAL_MANAGER_INFORMATION / GIMBAL_DEVICE_INFORMATION (on request),
GIMBAL_MANAGER_STATUS (1 Hz) and GIMBAL_DEVICE_ATTITUDE_STATUS (10 Hz) with a gimbal.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import numpy as np

from agent.flight.frames import quat_from_euler
from agent.wire.mavlink import mavlink as mav
from groundstation.vehicle import failsafe
from groundstation.vehicle import telemetry as tm
from groundstation.vehicle.battery import BatteryMonitor, Reading
from groundstation.vehicle.camera import Camera
from groundstation.vehicle.conventions import body_rates, geodetic, heading_cdeg
from groundstation.vehicle.ekf import GnssEkf, GnssModel
from groundstation.vehicle.fence import Fence
from groundstation.vehicle.gimbal import Gimbal
from groundstation.vehicle.mission_exec import MissionExec

if TYPE_CHECKING:
    from groundstation.vehicle.flavours.base import SimFlavour

M = mav
#: Messages of the mission protocol and the gimbal manager the autopilot takes.
MISSION = ("MISSION_COUNT", "MISSION_ITEM_INT", "MISSION_ITEM", "MISSION_REQUEST_LIST",
           "MISSION_REQUEST_INT", "MISSION_REQUEST", "MISSION_CLEAR_ALL", "MISSION_SET_CURRENT")
CAMERA_CMDS = (M.MAV_CMD_IMAGE_START_CAPTURE, M.MAV_CMD_IMAGE_STOP_CAPTURE,
               M.MAV_CMD_DO_DIGICAM_CONTROL)


class Devices:
    """Outdoor equipment of :class:`groundstation.vehicle.autopilot.Autopilot` (mixin)."""

    flavour: SimFlavour
    sysid: int
    params: Any
    params_table: Any
    link: Any
    armed: bool
    last_vision_t: float
    cmd_src: tuple[int, int]
    truth: Callable[[], Any]
    i: int

    def init_devices(self, seed: int) -> None:
        """Create the equipment (call once the parameters and the controls exist)."""
        self._encoders: dict[int, mav.MAVLink] = {}
        self.t_now = 0.0
        self.failsafe_pending: tuple[float, str] | None = None
        gnss = self.params.gnss
        self.gnss = None if gnss is None else GnssEkf(
            GnssModel.preset(gnss, self.params.gnss_noise), (seed, self.i))
        self.camera = Camera(self)
        self.gimbal = Gimbal(self)
        self.fence = Fence(self)
        self.battery_monitor = BatteryMonitor(self)
        self.mission: MissionExec = self.flavour.mission_class(self)

    def encoder(self, component: int) -> mav.MAVLink:
        """MAVLink encoder sending as ``component`` of this system on the vehicle's link."""
        if component == 1:
            return self.mav  # type: ignore[attr-defined]
        enc = self._encoders.get(component)
        if enc is None:
            enc = mav.MAVLink(self.link, srcSystem=self.sysid, srcComponent=component)
            self._encoders[component] = enc
        return enc

    # -- what the EKF knows -------------------------------------------------------------
    def pose_source(self, t: float) -> str | None:
        """'vision', 'gnss' or None (:func:`groundstation.vehicle.ekf.position_source`)."""
        fresh = t - self.last_vision_t <= 1.0
        return self.flavour.position_source(self.params_table, self.gnss is not None, fresh)

    # -- inbound ------------------------------------------------------------------------
    def route_device(self, msg: Any, t: float) -> bool:
        """Handle ``msg`` if it is addressed to one of the vehicle's other components."""
        if msg.get_type() not in ("COMMAND_LONG", "COMMAND_INT"):
            return False
        if int(getattr(msg, "target_component", 0)) != M.MAV_COMP_ID_CAMERA:
            return False
        if int(msg.target_system) == self.sysid and self.camera.kind == "component":
            self.camera.component_command(msg, t)
        return True  # another component's: never the autopilot's

    def on_mission(self, msg: Any, t: float) -> None:
        """MISSION_* addressed to the autopilot (storage: :mod:`.fence`; MISSION_SET_CURRENT:
        :mod:`.mission_exec`)."""
        if msg.get_type() == "MISSION_SET_CURRENT":
            self.mission.on_set_current(msg, t)
        else:
            self.fence.on_message(msg, t)

    def on_gimbal_set_pitchyaw(self, msg: Any, _t: float) -> None:
        """GIMBAL_MANAGER_SET_PITCHYAW (:mod:`.gimbal`)."""
        self.gimbal.on_set_pitchyaw(msg)

    def device_commands(self) -> dict[int, Callable[[list[float], float], int]]:
        """The command handlers of the equipment (merged into the autopilot's table)."""
        table = {c: self._camera_command(c) for c in CAMERA_CMDS}
        table[M.MAV_CMD_REQUEST_CAMERA_INFORMATION] = self._cmd_camera_information
        table[M.MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW] = \
            lambda p, _t: self.gimbal.command_pitchyaw(p, self.cmd_src)
        table[M.MAV_CMD_DO_GIMBAL_MANAGER_CONFIGURE] = \
            lambda p, _t: self.gimbal.command_configure(p, self.cmd_src)
        table[M.MAV_CMD_DO_FENCE_ENABLE] = lambda p, _t: self.fence.command_enable(p)
        table[M.MAV_CMD_MISSION_START] = self.mission.mission_start
        return table

    def _camera_command(self, cmd: int) -> Callable[[list[float], float], int]:
        def handle(p: list[float], t: float) -> int:
            return self.camera.autopilot_command(cmd, p, t)
        return handle

    def _cmd_camera_information(self, _p: list[float], _t: float) -> int:
        msgid = M.MAVLINK_MSG_ID_CAMERA_INFORMATION
        if not self.camera.available(msgid):
            return int(M.MAV_RESULT_UNSUPPORTED)
        self._requested.append(msgid)  # type: ignore[attr-defined]
        return int(M.MAV_RESULT_ACCEPTED)

    # -- every tick ---------------------------------------------------------------------
    def supervise(self, t: float) -> None:
        """Gimbal, camera, fence, battery and pending failsafes at simulation time t [s]."""
        self.t_now = t
        self.gimbal.step(t, float(self.truth().att[self.i, 2]))
        self.camera.step(t)
        self.fence.check(t)
        self.battery_monitor.update(t)
        failsafe.due(self, t)
        self.mission.update(t)

    def battery_reading(self) -> Reading:
        """The battery monitor's reading (:mod:`.battery`)."""
        return self.battery_monitor.read()


# -- encoders of the extra messages ------------------------------------------------------
def _ms(t: float) -> int:
    return int(max(t, 0.0) * 1000) & 0xFFFFFFFF


def _gps_raw_int(v: Any, t: float) -> None:
    """The receiver: fix, lat/lon degE7, alt mm AMSL, HDOP/VDOP x100, speed cm/s, course cdeg,
    accuracies mm (mm/s)."""
    st = v.truth()
    g = v.gnss
    p = g.receiver(t, st.p[v.i])
    vel = st.v[v.i]
    lat, lon, alt = geodetic(v.origin, p)
    speed = float(np.hypot(vel[0], vel[1]))
    cog = heading_cdeg(math.atan2(float(vel[1]), float(vel[0]))) if speed > 0.1 else 65535
    m = g.model
    v.mav.gps_raw_int_send(int(t * 1e6), m.fix_type, lat, lon, alt, round(m.hdop * 100),
                           round(m.vdop * 100), round(speed * 100), cog, m.satellites, alt,
                           round(m.h_acc * 1000), round(m.v_acc * 1000),
                           round(m.vel_noise * 1000), 0, 0)


def _gps_global_origin(v: Any, t: float) -> None:
    lat, lon, alt = geodetic(v.origin, np.zeros(3))
    v.mav.gps_global_origin_send(lat, lon, alt, int(t * 1e6))


def _odometry(v: Any, t: float) -> None:
    """ODOMETRY as PX4's stream sends EKF2's vehicle_odometry (mavlink/streams/ODOMETRY.hpp):
    frame LOCAL_NED, velocity NED (child frame LOCAL_NED), q NED→FRD, body rates [rad/s],
    estimator AUTOPILOT; covariances NaN but the variances [m², rad², m²/s²] on the diagonal."""
    p, vel, att, rates = v.estimate()
    q = quat_from_euler(float(att[0]), float(att[1]), float(att[2]))
    g = v.gnss.model if v.gnss is not None and v.pose_source(t) == "gnss" else None
    pos_var = [g.pos_noise_h**2 + g.drift_h**2] * 2 + [g.pos_noise_v**2 + g.drift_v**2] \
        if g is not None else [v.params.sensor_noise_pos**2] * 3
    att_var = [g.att_noise**2, g.att_noise**2, g.yaw_noise**2] if g is not None \
        else [v.params.sensor_noise_att**2] * 3
    vel_var = [g.vel_noise**2] * 3 if g is not None else [math.nan] * 3
    pose_cov = [math.nan] * 21
    for k, var in zip((0, 6, 11, 15, 18, 20), pos_var + att_var, strict=True):
        pose_cov[k] = var
    vel_cov = [math.nan] * 21
    for k, var in zip((0, 6, 11), vel_var, strict=True):
        vel_cov[k] = var
    b = body_rates(att, rates)
    v.mav.odometry_send(int(t * 1e6), M.MAV_FRAME_LOCAL_NED, M.MAV_FRAME_LOCAL_NED,
                        *(float(a) for a in p), [float(a) for a in q],
                        *(float(a) for a in vel), *b, pose_cov, vel_cov, 0,
                        M.MAV_ESTIMATOR_TYPE_AUTOPILOT, 0)


def _fence_status(v: Any, t: float) -> None:
    v.mav.fence_status_send(*v.fence.status_fields(), 0)


def _camera(msgid: int) -> Callable[[Any, float], None]:
    def send(v: Any, t: float) -> None:
        v.camera.send(msgid, t)
    return send


def _camera_available(msgid: int) -> Callable[[Any], bool]:
    def check(v: Any) -> bool:
        return bool(v.camera.available(msgid))
    return check


tm.register(M.MAVLINK_MSG_ID_GPS_RAW_INT, _gps_raw_int, lambda v: v.gnss is not None, 0.2)
tm.register(M.MAVLINK_MSG_ID_GPS_GLOBAL_ORIGIN, _gps_global_origin)
tm.register(M.MAVLINK_MSG_ID_ODOMETRY, _odometry, lambda v: v.flavour.streams_odometry)
tm.register(M.MAVLINK_MSG_ID_FENCE_STATUS, _fence_status,
            lambda v: v.flavour.autopilot.fence_status_message and v.fence.enabled, 1.0)
for _id in (M.MAVLINK_MSG_ID_CAMERA_INFORMATION, M.MAVLINK_MSG_ID_CAMERA_CAPTURE_STATUS,
            M.MAVLINK_MSG_ID_CAMERA_FEEDBACK):
    tm.register(_id, _camera(_id), _camera_available(_id))
tm.register(M.MAVLINK_MSG_ID_GIMBAL_MANAGER_INFORMATION,
            lambda v, t: v.gimbal.send_manager_information(_ms(t)), lambda v: v.gimbal.present)
tm.register(M.MAVLINK_MSG_ID_GIMBAL_MANAGER_STATUS,
            lambda v, t: v.gimbal.send_manager_status(_ms(t)), lambda v: v.gimbal.present, 1.0)
tm.register(M.MAVLINK_MSG_ID_GIMBAL_DEVICE_INFORMATION,
            lambda v, t: v.gimbal.send_device_information(_ms(t)), lambda v: v.gimbal.present)
tm.register(M.MAVLINK_MSG_ID_GIMBAL_DEVICE_ATTITUDE_STATUS,
            lambda v, t: v.gimbal.send_attitude(_ms(t)), lambda v: v.gimbal.present, 0.1)
