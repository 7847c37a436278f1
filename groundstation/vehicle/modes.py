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

The rules that differ (mode numbers and kinds, takeoff, SYS_STATUS bits, refusals) are the
flavour's (:mod:`groundstation.vehicle.flavours`); :class:`ModeRules` applies them.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from agent.wire.mavlink import mavlink as mav

if TYPE_CHECKING:
    from groundstation.vehicle.flavours.base import SimFlavour

#: What a mode does (a flavour's ``kinds``): guided (SET_ATTITUDE_TARGET), hold (position),
#: alt (level, hold altitude), land, rtl, takeoff (PX4 AUTO.TAKEOFF), auto (the stored
#: mission), idle (manual modes without RC).
KINDS = ("guided", "hold", "alt", "land", "rtl", "takeoff", "auto", "idle")


class ModeRules:
    """Mode changes, arming checks, NAV_TAKEOFF and SYS_STATUS bits (mixin of
    :class:`groundstation.vehicle.autopilot.Autopilot`), by the vehicle's flavour."""

    flavour: SimFlavour
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
    #: a set-point within the set-point timeout before t [s] (the controls')
    fresh_setpoint: Callable[[float], bool]

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
        return self._switch(self.flavour.requested_mode(custom, sub), t)

    def _switch_to(self, kind: str, t: float) -> int:
        """MAV_CMD_NAV_LAND (``land``) / MAV_CMD_NAV_RETURN_TO_LAUNCH (``rtl``)."""
        fl = self.flavour
        return self._switch(fl.land_mode if kind == "land" else fl.rtl_mode, t)

    @property
    def _refused(self) -> int:
        return int(self.flavour.refused)

    def _switch(self, new: int, t: float) -> int:
        """Enter mode ``new`` if this flavour allows it now (module docstring)."""
        fl = self.flavour
        if new not in fl.known_modes:
            return self._refused
        if self.armed and new in fl.needs_position and not self.position_ok(t):
            self.event(t, "mode_refused_no_position")
            return self._refused
        if new in fl.stream_gated_modes and not self.fresh_setpoint(t):
            self.event(t, "offboard_refused")
            return self._refused
        if new == fl.mission_mode and new != self.mode and self.mission.refuse_entry(t):
            return self._refused
        if new != self.mode:
            self.enter_mode(new, t)
        return int(mav.MAV_RESULT_ACCEPTED)

    def arming_check(self, t: float) -> bool:
        """The pre-arm checks of the current mode pass: it needs no position, or the EKF has
        one (ArduCopter "Need Position Estimate"; PX4 the mode's requirements)."""
        return self.mode not in self.flavour.needs_position or self.position_ok(t)

    # -- takeoff ------------------------------------------------------------------------
    def _cmd_takeoff(self, p: list[float], t: float, frame: int | None) -> int:
        """MAV_CMD_NAV_TAKEOFF (module docstring); p holds param1..param7."""
        return int(self.flavour.takeoff(self, p, t, frame))

    def takeoff_target(self) -> float:
        """AUTO.TAKEOFF's altitude [m; NED]: param7 if higher, else home + MIS_TAKEOFF_ALT."""
        floor = float(self.home[2]) - float(self.params_table["MIS_TAKEOFF_ALT"])
        return floor if self.takeoff_z is None else min(self.takeoff_z, floor)

    def on_takeoff_done(self, t: float) -> None:
        """At the takeoff mode's altitude: the commander switches to its loiter mode."""
        self.takeoff_z = None
        self.event(t, "takeoff_complete")
        self.enter_mode(self.flavour.loiter_mode, t)

    # -- SYS_STATUS ---------------------------------------------------------------------
    def sensor_bits(self, t: float, base: int) -> tuple[int, int, int]:
        """SYS_STATUS (present, enabled, health) from the simulated sensors ``base`` plus the
        pre-arm, geofence and vision bits as this flavour reports them (module docstring)."""
        return self.flavour.sensor_bits(self, t, base)
