"""PX4, simulated: every choice of :class:`~.base.SimFlavour` as PX4 makes it. The sources
behind each are in the docstring of the vehicle module named at the member's group
(:mod:`groundstation.vehicle.modes`, :mod:`~groundstation.vehicle.autopilot`,
:mod:`~groundstation.vehicle.control`, ...); mode numbers come from the agent-side flavour
(:class:`agent.wire.mavlink.PX4`: main mode, ``AUTO.<sub mode>``).
"""

from __future__ import annotations

import math
from types import MappingProxyType
from typing import Any

from agent.wire.mavlink import PX4_MAIN_AUTO, Autopilot
from agent.wire.mavlink import mavlink as mav
from groundstation.vehicle import battery, failsafe, inbound
from groundstation.vehicle import fence as fences
from groundstation.vehicle import gimbal as gimbals
from groundstation.vehicle import telemetry as tm
from groundstation.vehicle.conventions import ORIGIN
from groundstation.vehicle.ekf import position_source, px4_sources
from groundstation.vehicle.flavours.base import Params, SimFlavour
from groundstation.vehicle.flavours.px4_mission import PX4Mission
from groundstation.vehicle.params import INDOOR, PAYLOAD, PX4_PARAMS

M = mav
#: The PX4 modes this simulator flies (main mode, or AUTO.<sub mode>).
SIMULATED = ("MANUAL", "ALTCTL", "POSCTL", "OFFBOARD", "STABILIZED", "AUTO.LAND",
             "AUTO.LOITER", "AUTO.RTL", "AUTO.TAKEOFF", "AUTO.MISSION")
#: PX4 1.15.0 as AUTOPILOT_VERSION.flight_sw_version (major, minor, patch,
#: FIRMWARE_VERSION_TYPE_OFFICIAL = 255 in the low byte).
SW_VERSION = (1 << 24) | (15 << 16) | (0 << 8) | 255


class SimPX4(SimFlavour):
    """PX4 as the simulated vehicle runs it (module docstring)."""

    # identity, wire, streams (groundstation.vehicle.telemetry, .inbound, .conventions)
    sitl_origin = ORIGIN["px4"]
    sw_version = SW_VERSION
    version_capabilities = int(M.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE)
    legacy_data_streams = False
    streams_odometry = True
    fuses_att_pos_mocap = False  # EKF2 does not take ATT_POS_MOCAP
    # parameters (groundstation.vehicle.params)
    param_specs = PX4_PARAMS
    indoor_params = INDOOR["px4"]
    payload_params = PAYLOAD["px4"]
    field_params: Params = MappingProxyType({})  # GF_ACTION's default (2 Hold) enforces it
    # modes (groundstation.vehicle.modes, .autopilot)
    refused = int(M.MAV_RESULT_TEMPORARILY_REJECTED)
    position_guided_modes: frozenset[int] = frozenset()
    no_arm_kinds: frozenset[str] = frozenset()
    home_message_at_arming = False  # it streams HOME_POSITION
    # set-points (groundstation.vehicle.autopilot, .control)
    min_thrust = 0.0
    partial_body_rates = True
    reinit_on_bad_setpoint = False
    yaw_rate_feedforward = True
    waits_on_ground = False
    # gimbal, camera, missions (groundstation.vehicle.gimbal, .camera, .mission_exec)
    gimbal_device_id = int(M.MAV_COMP_ID_GIMBAL)
    gimbal_component = int(M.MAV_COMP_ID_GIMBAL)
    gimbal_attitude_device_id = 0
    gimbal_absent_result = int(M.MAV_RESULT_UNSUPPORTED)
    gimbal_unset_result = int(M.MAV_RESULT_ACCEPTED)
    gimbal_control_to_autopilot = True
    autopilot_camera_commands = False
    first_image_index = 0
    mission_class = PX4Mission

    def __init__(self, autopilot: Autopilot) -> None:
        super().__init__(autopilot)
        m = {name: autopilot.custom_mode(name) for name in SIMULATED}
        self.modes = m
        self.initial_mode = m["MANUAL"]
        self.kinds = {m["OFFBOARD"]: "guided", m["POSCTL"]: "hold", m["AUTO.LOITER"]: "hold",
                      m["ALTCTL"]: "alt", m["AUTO.LAND"]: "land", m["AUTO.RTL"]: "rtl",
                      m["AUTO.TAKEOFF"]: "takeoff", m["AUTO.MISSION"]: "auto"}
        self.known_modes = frozenset(m.values())
        self.needs_position = frozenset(m[n] for n in ("POSCTL", "AUTO.LOITER", "AUTO.RTL",
                                                       "AUTO.TAKEOFF", "AUTO.MISSION"))
        self.stream_gated_modes = frozenset({m["OFFBOARD"]})
        self.land_mode, self.rtl_mode = m["AUTO.LAND"], m["AUTO.RTL"]
        self.hold_mode = self.loiter_mode = m["AUTO.LOITER"]
        self.mission_mode = m["AUTO.MISSION"]

    # -- wire and streams -----------------------------------------------------------------
    def streams(self, telemetry_rate: float) -> dict[int, float]:
        # its "normal" MAVLink mode (mavlink_main.cpp configure_streams_to_default)
        return {tm.HOME_POSITION: 2.0, tm.GLOBAL_POSITION_INT: 0.2,
                tm.ATTITUDE_QUATERNION: 0.1}

    def addressed_to(self, msg: Any, sysid: int) -> bool:
        return inbound.px4_addressed_to(msg, sysid)

    def arm_request(self, param1: float, param2: float) -> tuple[bool, bool] | None:
        return inbound.px4_arm_request(param1, param2)

    def heartbeat_state(self, ap: Any) -> tuple[int, int]:
        kind = ap.kind
        if kind in ("guided", "land", "rtl", "takeoff", "auto") or ap.mode == self.loiter_mode:
            flags = (M.MAV_MODE_FLAG_AUTO_ENABLED | M.MAV_MODE_FLAG_STABILIZE_ENABLED
                     | M.MAV_MODE_FLAG_GUIDED_ENABLED)
        else:
            flags = M.MAV_MODE_FLAG_MANUAL_INPUT_ENABLED | M.MAV_MODE_FLAG_STABILIZE_ENABLED
            if ap.mode == self.modes["POSCTL"]:
                flags |= M.MAV_MODE_FLAG_GUIDED_ENABLED
        return flags, M.MAV_STATE_ACTIVE if ap.armed else M.MAV_STATE_STANDBY

    def sensor_bits(self, ap: Any, t: float, base: int) -> tuple[int, int, int]:
        present = enabled = health = base
        armable = ap.armed or ap.arming_check(t)
        kind_ok = ap.mode not in (self.land_mode, self.rtl_mode)  # mode_req_prevent_arming
        if ap.mode == self.mission_mode:
            kind_ok = ap.mission.present()  # mode_req_mission
        if ap.mode in self.stream_gated_modes:
            kind_ok = ap.fresh_setpoint(t)
        if ap.armed or (armable and kind_ok):
            health |= M.MAV_SYS_STATUS_PREARM_CHECK
        return present, enabled, health  # no geofence bits

    # -- parameters -----------------------------------------------------------------------
    def initial_values(self, params: Any, sysid: int) -> dict[str, float]:
        values = {"MAV_SYS_ID": float(sysid),
                  self.autopilot.hover_param: params.hover_thrust,
                  "MPC_LAND_SPEED": params.land_speed,
                  "BAT1_N_CELLS": float(params.battery_cells)}  # the pack as configured
        if params.setpoint_timeout is not None:
            values["COM_OF_LOSS_T"] = params.setpoint_timeout
        return values

    # -- modes ----------------------------------------------------------------------------
    def requested_mode(self, custom: int, sub: int) -> int:
        """COMMAND_LONG carries main and sub mode; SET_MODE the packed custom_mode."""
        if custom > 0xFFFF:
            return custom
        return self.autopilot.set_mode_params(custom, sub if custom == PX4_MAIN_AUTO else 0)[1]

    def reads_sub_mode(self, custom: int) -> bool:
        return custom == PX4_MAIN_AUTO

    def takeoff(self, ap: Any, p: list[float], t: float, frame: int | None) -> int:
        """Commander's NAV_TAKEOFF: AUTO.TAKEOFF to param7 [m AMSL] (NaN: MIS_TAKEOFF_ALT)."""
        alt_amsl = p[6]
        ap.takeoff_z = ap.origin[2] - alt_amsl if math.isfinite(alt_amsl) else None
        return int(ap._switch(self.modes["AUTO.TAKEOFF"], t))

    def on_setpoint_timeout(self, ap: Any, t: float) -> None:
        """The offboard-loss failsafe: COM_OBL_RC_ACT (groundstation.vehicle.autopilot)."""
        action = int(ap.params_table["COM_OBL_RC_ACT"])
        pos = ap.position_ok(t)
        if action in (6, 7):
            ap.armed = False
            ap.event(t, "disarmed")
            return
        m = self.modes
        land = m["AUTO.LAND"]
        new = {0: m["POSCTL"] if pos else m["ALTCTL"], 1: m["ALTCTL"], 2: m["ALTCTL"],
               3: m["AUTO.RTL"] if pos else land, 4: land,
               5: m["AUTO.LOITER"] if pos else land}.get(action, land)
        ap.enter_mode(new, t)
        ap.failsafe = True

    # -- set-point control ----------------------------------------------------------------
    def setpoint_timeout(self, pt: Params) -> float:
        return float(pt["COM_OF_LOSS_T"])

    def thrust_is_climb_rate(self, pt: Params) -> bool:
        return False

    def land_speed(self, pt: Params) -> float:
        return pt["MPC_LAND_SPEED"]

    def disarm_delay(self, pt: Params) -> float:
        return float(pt["COM_DISARM_LAND"])

    def rtl_altitude(self, pt: Params) -> float:
        return pt["RTL_RETURN_ALT"]

    def position_source(self, pt: Params, gnss: bool, vision_fresh: bool) -> str | None:
        return position_source(px4_sources(pt), gnss, vision_fresh)

    # -- failsafes, battery, fence --------------------------------------------------------
    def failsafe(self, ap: Any, action: str, t: float) -> None:
        failsafe.after_hold(ap, action, t)

    def battery_remaining(self, pt: Params, used: float, soc: float) -> float | None:
        return battery.px4_remaining(pt, used, soc)

    def battery_level(self, monitor: Any, reading: Any, t: float) -> int:
        return int(monitor.px4_level(reading))

    def battery_action(self, pt: Params, level: int) -> str | None:
        return battery.px4_action(pt, level)

    def fence_enabled(self, fence: Any) -> bool:
        return int(fence.ap.params_table["GF_ACTION"]) != 0

    def fence_enable_command(self, fence: Any, p: list[float]) -> int:
        return int(M.MAV_RESULT_UNSUPPORTED)

    def fence_bits(self, fence: Any, p: Any, home: Any) -> tuple[int, float]:
        return fence.px4_bits(p, home)  # type: ignore[no-any-return]

    def fence_action(self, pt: Params, distance: float) -> str | None:
        return fences.px4_action(pt)

    # -- gimbal and camera ----------------------------------------------------------------
    def gimbal_present(self, pt: Params) -> bool:
        return int(pt["MNT_MODE_IN"]) == 4  # gimbal protocol v2

    def gimbal_limits(self, pt: Params) -> tuple[float, float, float, float, float, float]:
        return gimbals.px4_limits(pt)

    def gimbal_command_refusal(self, gimbal: Any, p: list[float],
                               src: tuple[int, int]) -> int | None:
        return None if src == gimbal.control else int(M.MAV_RESULT_DENIED)

    def gimbal_message_taken(self, gimbal: Any, m: Any, src: tuple[int, int],
                             angles: tuple[float, float], rates: tuple[float, float]) -> bool:
        return bool(src == gimbal.control)

    def gimbal_device_flags(self, gimbal: Any) -> int:
        return gimbals.PX4_DEVICE_FLAGS

    def camera_kind(self, ap: Any) -> str:
        return "component" if ap.params.payload else "none"
