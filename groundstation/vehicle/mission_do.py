"""The DO items of a mission flown in AUTO (:mod:`groundstation.vehicle.mission_exec`): what
each does to the simulated camera, gimbal and speeds, per flavour.

* Camera. ArduPilot: AP_Mission's own camera commands (libraries/AP_Mission/
  AP_Mission_Commands.cpp ``start_command_camera``) go to AP_Camera as the command would
  (:meth:`.camera.Camera.autopilot_command`): IMAGE_START_CAPTURE (4.4+; param3 = 1 one
  picture), IMAGE_STOP_CAPTURE, DO_DIGICAM_CONTROL (every version; param5 = 1 shoots), each
  answered by a CAMERA_FEEDBACK. PX4 re-emits camera items to the camera component
  (navigator ``publish_vehicle_command``: target component 100; a single capture goes through
  camera_trigger, which sends the camera IMAGE_START_CAPTURE with param3 = 1): the camera
  component takes the picture (:meth:`.camera.Camera.component_start`) and sends
  CAMERA_IMAGE_CAPTURED with the pose at the shutter; DO_DIGICAM_CONTROL with param5 = 1 is
  such a single capture too.
* Gimbal. MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW (param5 = x the flags, param7 = z the gimbal
  device id) as the command would set it (:meth:`.gimbal.Gimbal.command_pitchyaw`). ArduPilot
  (``start_command_do_gimbal_manager_pitchyaw``) sets the mount's target with no control
  check. PX4's gimbal module takes it only from the primary control, and the mission's
  command comes from the autopilot itself (system id, component 1): a plan for PX4 first
  gives the autopilot control with MAV_CMD_DO_GIMBAL_MANAGER_CONFIGURE (param1/param2 −2,
  "set itself in control", as MAVSDK's mission plugin does), else its gimbal items are
  refused (src/modules/gimbal/input_mavlink.cpp: "GIMBAL_MANAGER_PITCHYAW from 1/1 denied").
  ArduPilot's mission does not take the configure item ("Skipping invalid cmd").
  MAV_CMD_DO_MOUNT_CONTROL (param1 pitch, param3 yaw [deg], body frame; ArduCopter
  ``do_mount_control``; PX4 first acquires the gimbal for it, mission_block.cpp).
* MAV_CMD_DO_CHANGE_SPEED: ArduCopter param1 speed type (0/1 horizontal, 2 climb, 3 descent)
  and param2 [m/s] > 0 (``do_change_speed``); PX4 param2 [m/s] > 0 the horizontal speed,
  −1 back to the default. Only the horizontal speed is simulated.

Unknown DO items: ArduCopter says "Skipping invalid cmd #N" and moves on; PX4 moves on.
"""

from __future__ import annotations

import math
from typing import Any

from agent.wire.mavlink import mavlink as mav
from groundstation.vehicle import failsafe

M = mav
GIMBAL_PITCHYAW = M.MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW
GIMBAL_CONFIGURE = M.MAV_CMD_DO_GIMBAL_MANAGER_CONFIGURE
CAMERA = (M.MAV_CMD_IMAGE_START_CAPTURE, M.MAV_CMD_IMAGE_STOP_CAPTURE,
          M.MAV_CMD_DO_DIGICAM_CONTROL)
#: DO items ArduCopter verifies itself (ModeAuto::verify_command: "do commands (always return
#: true)"), each followed by a MISSION_ITEM_REACHED; AP_Mission's own (camera, gimbal, servos)
#: complete without one (AP_Mission::verify_command).
AP_COPTER_DO = {M.MAV_CMD_DO_CHANGE_SPEED, M.MAV_CMD_DO_SET_HOME, M.MAV_CMD_DO_SET_ROI_LOCATION,
                M.MAV_CMD_DO_SET_ROI_NONE, M.MAV_CMD_DO_SET_ROI, M.MAV_CMD_DO_MOUNT_CONTROL,
                M.MAV_CMD_DO_FENCE_ENABLE, M.MAV_CMD_DO_RETURN_PATH_START,
                M.MAV_CMD_DO_LAND_START}
AP_MISSION_COMMON = {*CAMERA, GIMBAL_PITCHYAW, M.MAV_CMD_DO_DIGICAM_CONFIGURE,
                     M.MAV_CMD_DO_SET_CAM_TRIGG_DIST, M.MAV_CMD_VIDEO_START_CAPTURE,
                     M.MAV_CMD_VIDEO_STOP_CAPTURE, M.MAV_CMD_DO_SET_SERVO,
                     M.MAV_CMD_DO_SET_RELAY, M.MAV_CMD_DO_REPEAT_SERVO,
                     M.MAV_CMD_DO_REPEAT_RELAY, M.MAV_CMD_DO_GRIPPER}


def item_params(it: Any) -> list[float]:
    """param1..param7 of a stored mission item (:class:`.fence.Item`): x, y as numbers (the
    integers of MAV_FRAME_MISSION items), z."""
    return [*map(float, it.params), float(it.x), float(it.y), float(it.z)]


def run(ex: Any, it: Any, t: float) -> tuple[bool, float | None]:
    """Execute DO item ``it`` of mission ``ex`` (:class:`.mission_exec.MissionExec`, whose
    flavour decides what differs) at t [s sim]: (whether it is reported with
    MISSION_ITEM_REACHED, the new horizontal speed [m/s] or None (unchanged; NaN: back to the
    default))."""
    ap = ex.ap
    p = item_params(it)
    cmd = it.command
    me = (ap.sysid, 1)
    speed: float | None = None
    if cmd in CAMERA:
        ex.camera_item(cmd, p, t)
    elif cmd == GIMBAL_PITCHYAW:
        result = ap.gimbal.command_pitchyaw(p, me)
        if result != M.MAV_RESULT_ACCEPTED:
            ap.event(t, "mission_gimbal_refused")
    elif cmd == GIMBAL_CONFIGURE and ap.flavour.autopilot.mission_gimbal_configure:
        ap.gimbal.command_configure(p, me)
    elif cmd == M.MAV_CMD_DO_MOUNT_CONTROL:
        if ex.mount_takes_gimbal:
            ap.gimbal.command_configure([float(ap.sysid), 1.0, -1.0, -1.0], me)
        ap.gimbal.command_pitchyaw([p[0], p[2], math.nan, math.nan, 0.0, 0.0, 0.0], me)
    elif cmd == M.MAV_CMD_DO_CHANGE_SPEED:
        speed = ex.speed_item(p)
    elif not ex.do_known(cmd):
        failsafe.statustext(ap, M.MAV_SEVERITY_WARNING, f"Skipping invalid cmd #{cmd}")
    # else: accepted with no effect in this simulator (ROI, servos, fence, home...)
    ap.event(t, f"mission_do_{cmd}")
    return ex.do_reported(cmd), speed


def ardupilot_known(cmd: int) -> bool:
    """A DO item ArduCopter's mission carries out (others: "Skipping invalid cmd")."""
    return cmd in AP_COPTER_DO or cmd in AP_MISSION_COMMON


def ardupilot_reported(cmd: int) -> bool:
    """ArduCopter reports the DO items it verifies itself, not AP_Mission's own."""
    return cmd in AP_COPTER_DO or cmd not in AP_MISSION_COMMON


def component_camera(ap: Any, cmd: int, p: list[float], t: float) -> None:
    """PX4: a mission's camera item re-emitted to the camera component."""
    cam = ap.camera
    if cam.kind != "component":
        ap.event(t, "mission_camera_missing")
        return
    if cmd == M.MAV_CMD_IMAGE_STOP_CAPTURE:
        cam.remaining, cam.next_shot = 0, None
    elif cmd == M.MAV_CMD_DO_DIGICAM_CONTROL:
        if p[4] == 1.0:
            cam.component_start([0.0, 0.0, 1.0, 0.0], t)
    elif cam.component_start(p[:4], t) != M.MAV_RESULT_ACCEPTED:
        ap.event(t, "mission_camera_refused")


def ardupilot_speed(p: list[float]) -> float | None:
    """ArduCopter's DO_CHANGE_SPEED: param1 0/1 horizontal, param2 [m/s] > 0 (None:
    unchanged)."""
    kind = int(p[0]) if math.isfinite(p[0]) else -1
    if kind in (0, 1) and math.isfinite(p[1]) and p[1] > 0:
        return p[1]
    return None


def px4_speed(p: list[float]) -> float | None:
    """PX4's: param2 [m/s] > 0, −1 back to the default (NaN); None unchanged."""
    if p[1] == -1.0:
        return math.nan
    return p[1] if math.isfinite(p[1]) and p[1] > 0 else None
