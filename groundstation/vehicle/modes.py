"""Mode changes, arming checks, takeoff and SYS_STATUS health of the simulated autopilot.

Each rule is the autopilot's own (sources read with the ``search`` tool):

* Mode changes while disarmed. ArduCopter (ArduCopter/mode.cpp ``Copter::set_mode``:
  ``ignore_checks = !motors->armed()``) and PX4 (commander/UserModeIntention.cpp: "Always
  allow mode change while disarmed") take any known mode on the ground; the position a mode
  needs is checked when arming (ArduCopter AP_Arming_Copter ``mandatory_gps_checks``: "Need
  Position Estimate", MAV_RESULT_FAILED; PX4 ``canArm`` for the mode:
  TEMPORARILY_REJECTED) and, once armed, at the mode change (ArduCopter "requires position":
  FAILED; PX4 ``canRun``: TEMPORARILY_REJECTED). PX4 OFFBOARD still wants a set-point newer
  than COM_OF_LOSS_T at the switch (kept from earlier versions of this simulator; PX4 ≥ 1.14
  only checks it when arming).
* MAV_CMD_NAV_TAKEOFF. ArduCopter (GCS_MAVLINK_Copter ``handle_MAV_CMD_NAV_TAKEOFF``;
  COMMAND_LONG is read in MAV_FRAME_GLOBAL_RELATIVE_ALT, a COMMAND_INT in another frame is
  DENIED; ``Mode::do_user_takeoff_U_m``): FAILED unless armed, landed, in a mode with a user
  takeoff (GUIDED, GUIDED_NOGPS, LOITER; ALT_HOLD only when param3 is not 0) and param7 [m
  above home] above the vehicle (a non-finite param7 is DENIED, :mod:`.inbound`'s rule); it
  climbs there and holds (GUIDED_NOGPS takes the command but its angle controller never
  flies it). PX4 (Commander ``VEHICLE_CMD_NAV_TAKEOFF``): the mode
  AUTO.TAKEOFF, ACCEPTED or TEMPORARILY_REJECTED as any mode change (it needs a local
  position once armed); it climbs to max(param7 [m AMSL], home + MIS_TAKEOFF_ALT)
  (navigator/takeoff.cpp) and then holds in AUTO.LOITER.
* The mission modes, ArduCopter AUTO and PX4 AUTO.MISSION, need a position once armed like
  the others, and a stored mission (:mod:`groundstation.vehicle.mission_exec` says what else
  each refuses and how the mission is flown).
* MAV_CMD_GET_HOME_POSITION (deprecated for REQUEST_MESSAGE): ACCEPTED, then HOME_POSITION
  (ArduPilot GCS_Common ``handle_command_get_home_position``; PX4 mavlink_receiver.cpp
  answers it as REQUEST_MESSAGE of HOME_POSITION). The simulated EKF has its position and
  the fixed origin from the start, so home is always set: the start position, then where the
  vehicle was armed (both autopilots reset home at arming).
* SYS_STATUS bits. ArduPilot (libraries/GCS_MAVLink/GCS.cpp ``get_sensor_status_flags``):
  PREARM_CHECK present, enabled when ARMING_CHECK != 0, healthy when armed or the pre-arm
  checks pass; GEOFENCE present when FENCE_TYPE has circle or altitude fences or polygons
  with a fence uploaded (AC_Fence.cpp ``present``), enabled with
  FENCE_ENABLE (and FENCE_ACTION not report-only), healthy unless breached
  (:mod:`groundstation.vehicle.fence`); VISION_POSITION present and enabled with VISO_TYPE,
  healthy with a vision message within 0.3 s. PX4 (mavlink/streams/SYS_STATUS.hpp): PREARM_CHECK
  healthy only when the current mode can arm (``can_arm_mode_flags``), no geofence bits.
  MAVSDK's ``health.is_armable`` is that health bit (telemetry_impl.cpp).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np

from agent.wire.mavlink import ARDUPILOT_MODES as APM
from agent.wire.mavlink import (
    PX4_MAIN_ALTCTL,
    PX4_MAIN_AUTO,
    PX4_MAIN_MANUAL,
    PX4_MAIN_OFFBOARD,
    PX4_MAIN_POSCTL,
    PX4_MAIN_STABILIZED,
    PX4_SUB_AUTO_LAND,
    PX4_SUB_AUTO_LOITER,
    PX4_SUB_AUTO_RTL,
    px4_custom_mode,
)
from agent.wire.mavlink import mavlink as mav

P_OFFBOARD = px4_custom_mode(PX4_MAIN_OFFBOARD)
P_LAND = px4_custom_mode(PX4_MAIN_AUTO, PX4_SUB_AUTO_LAND)
P_LOITER = px4_custom_mode(PX4_MAIN_AUTO, PX4_SUB_AUTO_LOITER)
P_RTL = px4_custom_mode(PX4_MAIN_AUTO, PX4_SUB_AUTO_RTL)
P_TAKEOFF = px4_custom_mode(PX4_MAIN_AUTO, 2)  # PX4_CUSTOM_SUB_MODE_AUTO_TAKEOFF
P_POSCTL, P_ALTCTL = px4_custom_mode(PX4_MAIN_POSCTL), px4_custom_mode(PX4_MAIN_ALTCTL)
P_MANUAL = px4_custom_mode(PX4_MAIN_MANUAL)
#: The mission modes (:mod:`groundstation.vehicle.mission_exec`): ArduCopter AUTO
#: (Mode::Number::AUTO 3), PX4 AUTO.MISSION (PX4_CUSTOM_SUB_MODE_AUTO_MISSION 4).
AP_AUTO = 3
P_MISSION = px4_custom_mode(PX4_MAIN_AUTO, 4)
PX4_KNOWN = {P_MANUAL, P_ALTCTL, P_POSCTL, P_OFFBOARD, px4_custom_mode(PX4_MAIN_STABILIZED),
             P_LAND, P_LOITER, P_RTL, P_TAKEOFF, P_MISSION}
#: Behaviour of each mode: guided (SET_ATTITUDE_TARGET), hold (position), alt (level, hold
#: altitude), land, rtl, takeoff (PX4 AUTO.TAKEOFF), auto (the stored mission), idle (manual
#: modes without RC).
KIND = {APM["GUIDED"]: "guided", APM["GUIDED_NOGPS"]: "guided", APM["LOITER"]: "hold",
        APM["BRAKE"]: "hold", APM["ALT_HOLD"]: "alt", APM["LAND"]: "land", APM["RTL"]: "rtl",
        AP_AUTO: "auto"}
PX4_KIND = {P_OFFBOARD: "guided", P_POSCTL: "hold", P_LOITER: "hold", P_ALTCTL: "alt",
            P_LAND: "land", P_RTL: "rtl", P_TAKEOFF: "takeoff", P_MISSION: "auto"}
AP_NEEDS_POSITION = {APM["GUIDED"], APM["LOITER"], APM["RTL"], APM["BRAKE"], AP_AUTO}
PX4_NEEDS_POSITION = {P_POSCTL, P_LOITER, P_RTL, P_TAKEOFF, P_MISSION}
#: ArduCopter modes with a user takeoff (``has_user_takeoff``); ALT_HOLD only if param3 != 0.
AP_USER_TAKEOFF = {APM["GUIDED"], APM["GUIDED_NOGPS"], APM["LOITER"]}
#: Arm checks and the fence this simulator reports (module docstring).
AC_FENCE_TYPE_PRESENT = 0b1011  # max altitude, circle, min altitude
VISION_HEALTHY_S = 0.3


class ModeRules:
    """Mode changes, arming checks, NAV_TAKEOFF and SYS_STATUS bits (mixin of
    :class:`groundstation.vehicle.autopilot.Autopilot`)."""

    px4: bool
    armed: bool
    mode: int
    home: Any
    hold_p: Any
    params_table: Any
    sp_recent: Any
    last_vision_t: float
    takeoff_z: float | None  #: takeoff altitude [m; NED], None: PX4's MIS_TAKEOFF_ALT
    origin: tuple[float, float, float]  #: EKF origin: lat, lon [deg], alt [m AMSL]
    truth: Callable[[], Any]
    landed: bool
    i: int
    hold_z: float
    mission: Any  #: groundstation.vehicle.mission_exec.MissionExec

    def position_ok(self, t: float) -> bool:
        """The simulated EKF has a position (overridden by the autopilot)."""
        raise NotImplementedError

    def enter_mode(self, new: int, t: float) -> None:
        """Switch mode without checks (overridden by the autopilot)."""
        raise NotImplementedError

    def event(self, t: float, name: str) -> None:
        """Record an event (overridden by the autopilot)."""
        raise NotImplementedError

    # -- modes --------------------------------------------------------------------------
    def _set_mode(self, base: int, custom: int, t: float, sub: int = 0) -> int:
        """MAV_CMD_DO_SET_MODE / SET_MODE for this flavour; returns the MAV_RESULT."""
        if base & mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED == 0:
            return int(mav.MAV_RESULT_DENIED)
        if self.px4:
            # COMMAND_LONG carries main and sub mode; SET_MODE the packed custom_mode.
            new = custom if custom > 0xFFFF else px4_custom_mode(
                custom, sub if custom == PX4_MAIN_AUTO else 0)
            if new not in PX4_KNOWN:
                return int(mav.MAV_RESULT_TEMPORARILY_REJECTED)
        else:
            new = custom
        return self._switch(new, t)

    def _switch_to(self, kind: str, t: float) -> int:
        """MAV_CMD_NAV_LAND (``land``) / MAV_CMD_NAV_RETURN_TO_LAUNCH (``rtl``)."""
        if kind == "land":
            return self._switch(P_LAND if self.px4 else APM["LAND"], t)
        return self._switch(P_RTL if self.px4 else APM["RTL"], t)

    @property
    def _refused(self) -> int:
        return int(mav.MAV_RESULT_TEMPORARILY_REJECTED if self.px4 else mav.MAV_RESULT_FAILED)

    def _switch(self, new: int, t: float) -> int:
        """Enter mode ``new`` if this flavour allows it now (module docstring)."""
        if not self.px4 and new not in APM.values() and new != AP_AUTO:
            return self._refused
        needs = PX4_NEEDS_POSITION if self.px4 else AP_NEEDS_POSITION
        if self.armed and new in needs and not self.position_ok(t):
            self.event(t, "mode_refused_no_position")
            return self._refused
        fresh = bool(self.sp_recent) and \
            t - self.sp_recent[-1] < self.params_table.get("COM_OF_LOSS_T", 0.0)
        if self.px4 and new == P_OFFBOARD and not fresh:
            self.event(t, "offboard_refused")
            return self._refused
        if new in (AP_AUTO, P_MISSION) and new != self.mode and self.mission.refuse_entry(t):
            return self._refused
        if new != self.mode:
            self.enter_mode(new, t)
        return int(mav.MAV_RESULT_ACCEPTED)

    def arming_check(self, t: float) -> bool:
        """The pre-arm checks of the current mode pass: it needs no position, or the EKF has
        one (ArduCopter "Need Position Estimate"; PX4 the mode's requirements)."""
        needs = PX4_NEEDS_POSITION if self.px4 else AP_NEEDS_POSITION
        return self.mode not in needs or self.position_ok(t)

    # -- takeoff ------------------------------------------------------------------------
    def _cmd_takeoff(self, p: list[float], t: float, frame: int | None) -> int:
        """MAV_CMD_NAV_TAKEOFF (module docstring); p holds param1..param7."""
        if self.px4:
            alt_amsl = p[6]  # NaN: MIS_TAKEOFF_ALT above home
            self.takeoff_z = self.origin[2] - alt_amsl if math.isfinite(alt_amsl) else None
            return self._switch(P_TAKEOFF, t)
        if frame is not None and frame != mav.MAV_FRAME_GLOBAL_RELATIVE_ALT:
            return int(mav.MAV_RESULT_DENIED)
        alt = p[6]
        if not math.isfinite(alt):
            return int(mav.MAV_RESULT_DENIED)
        must_navigate = p[2] == 0.0  # C's is_zero(param3): a NaN (MAVSDK's unused) is not zero
        allowed = self.mode in AP_USER_TAKEOFF or (self.mode == APM["ALT_HOLD"]
                                                   and not must_navigate)
        height = float(self.home[2]) - float(self.truth().p[self.i, 2])
        if not (self.armed and self.landed and allowed and alt > height):
            return int(mav.MAV_RESULT_FAILED)
        self.takeoff_z = float(self.home[2]) - alt
        if self.mode != APM["GUIDED_NOGPS"]:  # its angle controller ignores the takeoff
            st = self.truth()
            self.hold_p = np.array([st.p[self.i, 0], st.p[self.i, 1], self.takeoff_z])
            self.hold_z = self.takeoff_z
        self.event(t, "takeoff")
        return int(mav.MAV_RESULT_ACCEPTED)

    def px4_takeoff_target(self) -> float:
        """AUTO.TAKEOFF's altitude [m; NED]: param7 if higher, else home + MIS_TAKEOFF_ALT."""
        floor = float(self.home[2]) - float(self.params_table["MIS_TAKEOFF_ALT"])
        return floor if self.takeoff_z is None else min(self.takeoff_z, floor)

    def on_takeoff_done(self, t: float) -> None:
        """PX4 at its takeoff altitude: the commander switches to AUTO.LOITER."""
        self.takeoff_z = None
        self.event(t, "takeoff_complete")
        self.enter_mode(P_LOITER, t)

    # -- SYS_STATUS ---------------------------------------------------------------------
    def sensor_bits(self, t: float, base: int) -> tuple[int, int, int]:
        """SYS_STATUS (present, enabled, health) from the simulated sensors ``base`` plus the
        pre-arm, geofence and vision bits as this flavour reports them (module docstring)."""
        present = enabled = health = base
        armable = self.armed or self.arming_check(t)
        if self.px4:
            kind_ok = self.mode not in (P_LAND, P_RTL)  # mode_req_prevent_arming
            if self.mode == P_MISSION:
                kind_ok = self.mission.present()  # mode_req_mission
            if self.mode == P_OFFBOARD:
                kind_ok = bool(self.sp_recent) and \
                    t - self.sp_recent[-1] < float(self.params_table["COM_OF_LOSS_T"])
            if self.armed or (armable and kind_ok):
                health |= mav.MAV_SYS_STATUS_PREARM_CHECK
            return present, enabled, health
        pt = self.params_table
        present |= mav.MAV_SYS_STATUS_PREARM_CHECK
        if int(pt["ARMING_CHECK"]) != 0:
            enabled |= mav.MAV_SYS_STATUS_PREARM_CHECK
            if armable:
                health |= mav.MAV_SYS_STATUS_PREARM_CHECK
        fence = mav.MAV_SYS_STATUS_GEOFENCE
        store = getattr(self, "fence", None)  # groundstation.vehicle.fence.Fence
        polygons = store is not None and bool(store.stored.get(mav.MAV_MISSION_TYPE_FENCE))
        if int(pt["FENCE_TYPE"]) & AC_FENCE_TYPE_PRESENT or (int(pt["FENCE_TYPE"]) & 4
                                                             and polygons):
            present |= fence
            on = store.enabled if store is not None else int(pt["FENCE_ENABLE"]) == 1
            if on and int(pt["FENCE_ACTION"]) != 0:
                enabled |= fence
        if store is None or not store.breaches:
            health |= fence  # healthy unless breached
        if pt["VISO_TYPE"] > 0:
            vision = mav.MAV_SYS_STATUS_SENSOR_VISION_POSITION
            present, enabled = present | vision, enabled | vision
            if t - self.last_vision_t <= VISION_HEALTHY_S:
                health |= vision
        return present, enabled, health

