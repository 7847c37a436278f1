"""ArduCopter, simulated: every choice of :class:`~.base.SimFlavour` as ArduCopter makes it.
The sources behind each are in the docstring of the vehicle module named at the member's
group (:mod:`groundstation.vehicle.modes`, :mod:`~groundstation.vehicle.autopilot`,
:mod:`~groundstation.vehicle.control`, ...); mode numbers come from the agent-side flavour
(:class:`agent.wire.mavlink.ArduPilot`, or one derived from it), so a flavour that numbers
ArduCopter's modes otherwise is simulated by this class as it is.
"""

from __future__ import annotations

import math
from types import MappingProxyType
from typing import Any

import numpy as np

from agent.wire.mavlink import GUID_OPTIONS_REAL_THRUST, Autopilot
from agent.wire.mavlink import mavlink as mav
from groundstation.vehicle import battery, failsafe, inbound
from groundstation.vehicle import fence as fences
from groundstation.vehicle import gimbal as gimbals
from groundstation.vehicle import telemetry as tm
from groundstation.vehicle.conventions import ORIGIN
from groundstation.vehicle.ekf import ardupilot_sources, position_source
from groundstation.vehicle.flavours.ardupilot_mission import ArduPilotMission
from groundstation.vehicle.flavours.base import Params, SimFlavour
from groundstation.vehicle.params import ARDUPILOT_PARAMS, INDOOR, PAYLOAD

M = mav
#: The ArduCopter modes this simulator flies (ArduCopter/mode.h names).
SIMULATED = ("STABILIZE", "ALT_HOLD", "GUIDED", "LOITER", "RTL", "LAND", "BRAKE",
             "GUIDED_NOGPS", "AUTO")
#: ArduCopter 4.5.7 as AUTOPILOT_VERSION.flight_sw_version (major, minor, patch,
#: FIRMWARE_VERSION_TYPE_OFFICIAL = 255 in the low byte).
SW_VERSION = (4 << 24) | (5 << 16) | (7 << 8) | 255
#: FENCE_TYPE bits that make the geofence present in SYS_STATUS without an uploaded fence:
#: max altitude, circle, min altitude (AC_Fence.cpp ``present``).
AC_FENCE_TYPE_PRESENT = 0b1011
#: A vision message this recent keeps the VISION_POSITION health bit [s].
VISION_HEALTHY_S = 0.3


class SimArduPilot(SimFlavour):
    """ArduCopter as the simulated vehicle runs it (module docstring)."""

    # identity, wire, streams (groundstation.vehicle.telemetry, .inbound, .conventions)
    sitl_origin = ORIGIN["ardupilot"]
    sw_version = SW_VERSION
    version_capabilities = int(M.MAV_PROTOCOL_CAPABILITY_PARAM_FLOAT
                               | M.MAV_PROTOCOL_CAPABILITY_FLIGHT_TERMINATION)
    legacy_data_streams = True
    streams_odometry = False
    fuses_att_pos_mocap = True
    # parameters (groundstation.vehicle.params)
    param_specs = ARDUPILOT_PARAMS
    indoor_params = INDOOR["ardupilot"]
    payload_params = PAYLOAD["ardupilot"]
    #: the uploaded fence enforced: ArduPilot stores a fence with FENCE_ENABLE 0 but never
    #: acts on it
    field_params = MappingProxyType({"FENCE_ENABLE": 1.0})
    # modes (groundstation.vehicle.modes, .autopilot)
    refused = int(M.MAV_RESULT_FAILED)
    stream_gated_modes: frozenset[int] = frozenset()
    no_arm_kinds = frozenset({"land", "rtl"})
    home_message_at_arming = True
    # set-points (groundstation.vehicle.autopilot, .control)
    min_thrust = -1.0
    partial_body_rates = False
    reinit_on_bad_setpoint = True
    yaw_rate_feedforward = False
    waits_on_ground = True
    # gimbal, camera, missions (groundstation.vehicle.gimbal, .camera, .mission_exec)
    gimbal_device_id = 1
    gimbal_component = 1
    gimbal_attitude_device_id = 1
    gimbal_absent_result = int(M.MAV_RESULT_FAILED)
    gimbal_unset_result = int(M.MAV_RESULT_FAILED)
    gimbal_control_to_autopilot = False
    autopilot_camera_commands = True
    first_image_index = 1
    mission_class = ArduPilotMission

    def __init__(self, autopilot: Autopilot) -> None:
        super().__init__(autopilot)
        m = {name: autopilot.custom_mode(name) for name in SIMULATED}
        self.modes = m
        self.initial_mode = m["STABILIZE"]
        self.kinds = {m["GUIDED"]: "guided", m["GUIDED_NOGPS"]: "guided", m["LOITER"]: "hold",
                      m["BRAKE"]: "hold", m["ALT_HOLD"]: "alt", m["LAND"]: "land",
                      m["RTL"]: "rtl", m["AUTO"]: "auto"}
        self.known_modes = frozenset(m.values())
        self.needs_position = frozenset(m[n] for n in ("GUIDED", "LOITER", "RTL", "BRAKE",
                                                       "AUTO"))
        self.position_guided_modes = frozenset({m["GUIDED"]})
        #: modes with a user takeoff (``has_user_takeoff``); ALT_HOLD only if param3 != 0
        self.user_takeoff = frozenset(m[n] for n in ("GUIDED", "GUIDED_NOGPS", "LOITER"))
        self.land_mode, self.rtl_mode, self.mission_mode = m["LAND"], m["RTL"], m["AUTO"]
        self.hold_mode, self.loiter_mode = m["BRAKE"], m["LOITER"]

    # -- wire and streams -----------------------------------------------------------------
    def streams(self, telemetry_rate: float) -> dict[int, float]:
        return {tm.GLOBAL_POSITION_INT: 1.0 / telemetry_rate}  # its POSITION group

    def addressed_to(self, msg: Any, sysid: int) -> bool:
        return inbound.addressed_to(msg, sysid)

    def arm_request(self, param1: float, param2: float) -> tuple[bool, bool] | None:
        return inbound.arm_request(param1, param2)

    def heartbeat_state(self, ap: Any) -> tuple[int, int]:
        flags = M.MAV_MODE_FLAG_STABILIZE_ENABLED | M.MAV_MODE_FLAG_MANUAL_INPUT_ENABLED
        if ap.position_controlled:  # pos_control NE active
            flags |= M.MAV_MODE_FLAG_GUIDED_ENABLED
        return flags, M.MAV_STATE_STANDBY if ap.landed else M.MAV_STATE_ACTIVE

    def sensor_bits(self, ap: Any, t: float, base: int) -> tuple[int, int, int]:
        present = enabled = health = base
        armable = ap.armed or ap.arming_check(t)
        pt = ap.params_table
        present |= M.MAV_SYS_STATUS_PREARM_CHECK
        if int(pt["ARMING_CHECK"]) != 0:
            enabled |= M.MAV_SYS_STATUS_PREARM_CHECK
            if armable:
                health |= M.MAV_SYS_STATUS_PREARM_CHECK
        fence = M.MAV_SYS_STATUS_GEOFENCE
        store = getattr(ap, "fence", None)  # groundstation.vehicle.fence.Fence
        polygons = store is not None and bool(store.stored.get(M.MAV_MISSION_TYPE_FENCE))
        if int(pt["FENCE_TYPE"]) & AC_FENCE_TYPE_PRESENT or (int(pt["FENCE_TYPE"]) & 4
                                                             and polygons):
            present |= fence
            on = store.enabled if store is not None else int(pt["FENCE_ENABLE"]) == 1
            if on and int(pt["FENCE_ACTION"]) != 0:
                enabled |= fence
        if store is None or not store.breaches:
            health |= fence  # healthy unless breached
        if pt["VISO_TYPE"] > 0:
            vision = M.MAV_SYS_STATUS_SENSOR_VISION_POSITION
            present, enabled = present | vision, enabled | vision
            if t - ap.last_vision_t <= VISION_HEALTHY_S:
                health |= vision
        return present, enabled, health

    # -- parameters -----------------------------------------------------------------------
    def initial_values(self, params: Any, sysid: int) -> dict[str, float]:
        values = {"SYSID_THISMAV": float(sysid),
                  self.autopilot.hover_param: params.hover_thrust,
                  "LAND_SPEED": float(round(params.land_speed * 100.0)),
                  "WPNAV_SPEED_UP": params.pilot_speed * 100.0,
                  "BATT_CAPACITY": float(round(params.battery_mah))}  # the pack as configured
        if params.setpoint_timeout is not None:
            values["GUID_TIMEOUT"] = params.setpoint_timeout
        return values

    # -- modes ----------------------------------------------------------------------------
    def requested_mode(self, custom: int, sub: int) -> int:
        return custom

    def reads_sub_mode(self, custom: int) -> bool:
        return False

    def takeoff(self, ap: Any, p: list[float], t: float, frame: int | None) -> int:
        """``handle_MAV_CMD_NAV_TAKEOFF`` (groundstation.vehicle.modes docstring)."""
        if frame is not None and frame != M.MAV_FRAME_GLOBAL_RELATIVE_ALT:
            return int(M.MAV_RESULT_DENIED)
        alt = p[6]
        if not math.isfinite(alt):
            return int(M.MAV_RESULT_DENIED)
        must_navigate = p[2] == 0.0  # C's is_zero(param3): a NaN (MAVSDK's unused) is not zero
        allowed = ap.mode in self.user_takeoff or (ap.mode == self.modes["ALT_HOLD"]
                                                   and not must_navigate)
        height = float(ap.home[2]) - float(ap.truth().p[ap.i, 2])
        if not (ap.armed and ap.landed and allowed and alt > height):
            return int(M.MAV_RESULT_FAILED)
        ap.takeoff_z = float(ap.home[2]) - alt
        if ap.mode != self.modes["GUIDED_NOGPS"]:  # its angle controller ignores the takeoff
            st = ap.truth()
            ap.hold_p = np.array([st.p[ap.i, 0], st.p[ap.i, 1], ap.takeoff_z])
            ap.hold_z = ap.takeoff_z
        ap.event(t, "takeoff")
        return int(M.MAV_RESULT_ACCEPTED)

    def on_setpoint_timeout(self, ap: Any, t: float) -> None:
        """ArduCopter stays in GUIDED: it levels and holds its altitude (control)."""

    # -- set-point control ----------------------------------------------------------------
    def setpoint_timeout(self, pt: Params) -> float:
        return max(float(pt["GUID_TIMEOUT"]), 0.1)

    def thrust_is_climb_rate(self, pt: Params) -> bool:
        return int(pt["GUID_OPTIONS"]) & GUID_OPTIONS_REAL_THRUST == 0

    def land_speed(self, pt: Params) -> float:
        return pt["LAND_SPEED"] / 100.0

    def disarm_delay(self, pt: Params) -> float:
        return 0.0

    def rtl_altitude(self, pt: Params) -> float:
        return pt["RTL_ALT"] / 100.0

    def position_source(self, pt: Params, gnss: bool, vision_fresh: bool) -> str | None:
        return position_source(ardupilot_sources(pt), gnss, vision_fresh)

    # -- failsafes, battery, fence --------------------------------------------------------
    def failsafe(self, ap: Any, action: str, t: float) -> None:
        failsafe.at_once(ap, action, t)

    def battery_remaining(self, pt: Params, used: float, soc: float) -> float | None:
        return battery.ardupilot_remaining(pt, used)

    def battery_level(self, monitor: Any, reading: Any, t: float) -> int:
        return int(monitor.ardupilot_level(reading, t))

    def battery_action(self, pt: Params, level: int) -> str | None:
        return battery.ardupilot_action(pt, level)

    def fence_enabled(self, fence: Any) -> bool:
        return bool(fence.ardupilot_enabled())

    def fence_enable_command(self, fence: Any, p: list[float]) -> int:
        return int(fence.ardupilot_enable(p))

    def fence_bits(self, fence: Any, p: Any, home: Any) -> tuple[int, float]:
        return fence.ardupilot_bits(p, home)  # type: ignore[no-any-return]

    def fence_action(self, pt: Params, distance: float) -> str | None:
        return fences.ardupilot_action(pt, distance)

    # -- gimbal and camera ----------------------------------------------------------------
    def gimbal_present(self, pt: Params) -> bool:
        return int(pt["MNT1_TYPE"]) != 0

    def gimbal_limits(self, pt: Params) -> tuple[float, float, float, float, float, float]:
        return gimbals.ardupilot_limits(pt)

    def gimbal_command_refusal(self, gimbal: Any, p: list[float],
                               src: tuple[int, int]) -> int | None:
        dev = inbound.as_int(p[6], (0, 0xFF)) if math.isfinite(p[6]) else None
        if dev is None:
            return int(M.MAV_RESULT_DENIED)
        return None if dev in (0, 1) else int(M.MAV_RESULT_FAILED)

    def gimbal_message_taken(self, gimbal: Any, m: Any, src: tuple[int, int],
                             angles: tuple[float, float], rates: tuple[float, float]) -> bool:
        if int(m.gimbal_device_id) not in (0, 1):
            return False
        return any(math.isnan(a) for a in (*angles, *rates))  # not angle and rate at once

    def gimbal_device_flags(self, gimbal: Any) -> int:
        return int(gimbal.mount_flags())

    def camera_kind(self, ap: Any) -> str:
        cam = int(ap.params_table["CAM1_TYPE"])  # 6 MAVLinkCamV2 is not simulated
        return "autopilot" if cam != 0 and cam != 6 else "none"
