"""Missions flown in AUTO by the simulated autopilot: the stored MAV_MISSION_TYPE_MISSION items
(:mod:`.fence` stores every mission type), item by item as ArduCopter and PX4 fly them.

Modes and refusals. ArduCopter AUTO is custom_mode 3 (ArduCopter/mode_auto.cpp
``ModeAuto::init``): while disarmed any mode is taken; armed, it needs a mission (more than
the home item 0), a position, and on the ground a mission whose first NAV item is a takeoff
("Auto: Missing Takeoff Cmd"), else MAV_RESULT_FAILED. Arming in AUTO is refused unless
AUTO_OPTIONS bit 0. On the ground the takeoff waits for the pilot's throttle, which a
simulator without RC never raises, unless AUTO_OPTIONS bit 1 or MAV_CMD_MISSION_START (armed:
AUTO, then ``set_auto_armed``; GCS_MAVLINK_Copter); a vehicle already flying goes on at once.
Entering AUTO starts the mission, or resumes it at its current NAV item (MIS_RESTART 0;
AP_Mission ``start_or_resume``); leaving stops it; a disarm resets it to its start
(AP_Arming_Copter::disarm). PX4 AUTO.MISSION is main mode 4, sub mode 4 (also MAVSDK's
``mission_raw.start_mission`` and MAV_CMD_MISSION_START, whose param1 sets the first item):
armed, TEMPORARILY_REJECTED without a mission; it can arm in it; it resumes at its
``current_seq`` and restarts from 0 when the finished mission is entered again after a
disarm (navigator mission_base.cpp ``checkMissionRestart``).

Items. NAV items are flown one at a time; the DO items after one run when it completes, in
order, before the next NAV item starts (AP_Mission ``advance_current_nav_cmd``; PX4 issues
them one per navigator cycle). Flown as legs of :mod:`.mission_nav`:

* NAV_TAKEOFF climbs straight up over where it starts (ArduCopter ``takeoff_start``: at least
  1 m up when landed, WPNAV_SPEED_UP; complete at the altitude (AC_AutoTakeoff). PX4
  MPC_TKO_SPEED to max(item, MIS_TAKEOFF_ALT above the ground), reached within
  NAV_MC_ALT_RAD, or half the height when lower: mission_block.cpp). Altitudes: frames 3, 6
  (relative to home) and 0, 5 (AMSL). PX4 landed at a NAV item that is no takeoff first
  climbs to MIS_TAKEOFF_ALT (its CLIMB work item, no MISSION_ITEM_REACHED).
* NAV_WAYPOINT (and LOITER_TIME, LOITER_UNLIM: never completes). ArduCopter: reached when its
  leg's target has arrived and the vehicle is within WPNAV_RADIUS (a waypoint with no hold
  followed by another waypoint passes as soon as the target arrives: a "fast waypoint"); the
  item's acceptance radius is not used; then it holds param1 whole seconds
  (``verify_nav_wp``); heading along the leg when longer than 2 m (WP_YAW_BEHAVIOR ≠ 0). PX4:
  reached within the item's acceptance radius (param2 > 0, else NAV_ACC_RAD) horizontally and
  NAV_MC_ALT_RAD vertically, and within MIS_YAW_ERR of the item's yaw (param4, when given:
  the heading it flies, else along the leg); then it holds param1 [s].
* NAV_LAND at a location flies there at its altitude first (ArduCopter ``do_land``: target
  arrived and within WPNAV_RADIUS; PX4 only from beyond NAV_ACC_RAD, else it slides there
  descending), then lands (:meth:`.control.Controls._land`). ArduCopter disarms on touchdown
  and the item never completes (``verify_land``); PX4 reports it reached when landed, the
  mission ends, and COM_DISARM_LAND disarms.
* NAV_DELAY waits param1 [s] where the vehicle is (ArduCopter ``do_nav_delay``; PX4 reaches it
  when the delay is over, mission_block.cpp).
* NAV_RETURN_TO_LAUNCH: ArduCopter flies RTL inside AUTO and completes landed; PX4 treats it
  as a command: reached at once, then the mode AUTO.RTL.

End of the mission: ArduCopter stays in AUTO loitering where it is, or disarms if landed
(``exit_mission``); PX4 says "Mission finished, loitering" and the commander switches to
AUTO.LOITER over the last set-point, or stays landed (mission_base.cpp
``setEndOfMissionItems``; Commander.cpp: mission finished in AUTO_MISSION → AUTO_LOITER).

Messages. MISSION_ITEM_REACHED (seq) once per item completed: every item on PX4
(mission_result.seq_reached), on ArduCopter every NAV item and the DO items the copter
verifies (DO items of AP_Mission itself, camera and gimbal, send none: :mod:`.mission_do`).
MISSION_CURRENT (seq: ArduCopter the current NAV item, PX4 ``current_seq``; total: the count
less home on ArduCopter, the count on PX4; mission_state; mission_mode 1 in the mission mode)
on every change and at 1 Hz. MISSION_SET_CURRENT: ArduCopter ``set_current_cmd`` (0 means 1;
out of range ignored) answered by MISSION_CURRENT of the asked seq; PX4 answers an
out-of-range seq with STATUSTEXT "WPM: WP CURR CMD: Not in list".
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from agent.wire.mavlink import mavlink as mav
from groundstation.vehicle import failsafe, mission_do
from groundstation.vehicle import telemetry as tm
from groundstation.vehicle.conventions import local_ne
from groundstation.vehicle.mission_fly import Flight
from groundstation.vehicle.modes import AP_AUTO, P_LOITER, P_MISSION

M = mav
STOPPED, RUNNING, COMPLETE = "stopped", "running", "complete"
TAKEOFF, LAND, RTL = M.MAV_CMD_NAV_TAKEOFF, M.MAV_CMD_NAV_LAND, M.MAV_CMD_NAV_RETURN_TO_LAUNCH
FLY_TO = {M.MAV_CMD_NAV_WAYPOINT, M.MAV_CMD_NAV_LOITER_UNLIM, M.MAV_CMD_NAV_LOITER_TIME}
#: PX4's items with a position (navigator ``item_contains_position``); its RTL is a command.
PX4_POSITION = {*FLY_TO, M.MAV_CMD_NAV_LOITER_TURNS, LAND, TAKEOFF,
                M.MAV_CMD_NAV_LOITER_TO_ALT}
RELATIVE_FRAMES = {M.MAV_FRAME_GLOBAL_RELATIVE_ALT, M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT}


class MissionExec:
    """One autopilot's mission in AUTO (module docstring); ``reached`` lists the seq of every
    MISSION_ITEM_REACHED sent."""

    def __init__(self, ap: Any) -> None:
        self.ap = ap
        self.px4 = bool(ap.px4)
        self.state = STOPPED
        self.cur: int | None = None
        self.auto_armed = False
        self.reached: list[int] = []
        self.fly = Flight(self)
        self._armed = False
        self._version = 0
        self._sent: tuple[int, int, int, int] | None = None
        self._disarmed_inactive = False

    # -- the stored mission -------------------------------------------------------------
    @property
    def items(self) -> list[Any]:
        """The stored mission items (ArduCopter's item 0 is home)."""
        return list(self.ap.fence.stored.get(M.MAV_MISSION_TYPE_MISSION, []))

    @property
    def first(self) -> int:
        """The first item flown (ArduPilot AP_MISSION_FIRST_REAL_COMMAND 1; PX4 0)."""
        return 0 if self.px4 else 1

    def present(self) -> bool:
        """A mission is stored (ArduCopter: more than home)."""
        return len(self.items) > self.first

    def is_nav(self, cmd: int) -> bool:
        """A NAV item (ArduPilot ``is_nav_cmd``: ids up to MAV_CMD_NAV_LAST; PX4 its items
        with a position, and NAV_DELAY, which takes its time too)."""
        if self.px4:
            return cmd in PX4_POSITION or cmd == M.MAV_CMD_NAV_DELAY
        return bool(cmd <= M.MAV_CMD_NAV_LAST)

    @property
    def active(self) -> bool:
        """The autopilot is in its mission mode."""
        return bool(self.ap.kind == "auto")

    def position(self, it: Any, default: np.ndarray) -> np.ndarray:
        """Item ``it``'s position [m; local NED]: lat/lon (degE7) from the EKF origin and its
        altitude (relative to home, or AMSL); lat = lon = 0 takes ``default``'s."""
        ap = self.ap
        ne = default[:2] if it.x == 0 and it.y == 0 else local_ne(ap.origin, it.x, it.y)
        if it.frame in RELATIVE_FRAMES:
            z = float(ap.home_ned()[2]) - it.z
        else:
            z = float(ap.origin[2]) - it.z
        return np.array([float(ne[0]), float(ne[1]), z])

    # -- modes --------------------------------------------------------------------------
    def refuse_entry(self, t: float) -> bool:
        """Whether the switch to the mission mode is refused now (module docstring)."""
        ap = self.ap
        if not ap.armed:
            return False
        if not self.present():
            ap.event(t, "mission_refused_empty")
            return True
        if not self.px4 and ap.landed and not self._starts_with_takeoff():
            failsafe.statustext(ap, M.MAV_SEVERITY_CRITICAL, "Auto: Missing Takeoff Cmd")
            ap.event(t, "mission_refused_no_takeoff")
            return True
        return False

    def refuses_arming(self) -> bool:
        """Arming is refused in the mission mode: ArduCopter without AUTO_OPTIONS bit 0, PX4
        without a mission."""
        if not self.active:
            return False
        if self.px4:
            return not self.present()
        return int(self.ap.params_table["AUTO_OPTIONS"]) & 1 == 0

    def _starts_with_takeoff(self) -> bool:
        """AP_Mission ``starts_with_takeoff_cmd``: the next NAV item (skipping NAV_DELAY) is a
        takeoff."""
        restart = int(self.ap.params_table["MIS_RESTART"]) != 0
        k = self.first if restart or self.cur is None else self.cur
        for it in self.items[k:]:
            if not self.is_nav(it.command) or it.command == M.MAV_CMD_NAV_DELAY:
                continue
            return bool(it.command == TAKEOFF)
        return False

    def on_enter(self, t: float) -> None:
        """The mission mode was entered: start or resume the mission."""
        self.fly.reset(t)
        if self.px4:
            finished = self.state == COMPLETE or (
                self.cur is not None and self.cur + 1 >= len(self.items))
            if self._disarmed_inactive and finished:
                self.cur = 0
            self._disarmed_inactive = False
            if not self.present():
                self.state = COMPLETE
                self.fly.hold_here()
                return
            self.state = RUNNING
            self.run_from(self.cur or 0, t)
            return
        if not self.ap.landed:
            self.auto_armed = True  # already flying
        if not self.present():
            self.fly.hold_here()  # AP_Mission::update does nothing without commands
            return
        restart = int(self.ap.params_table["MIS_RESTART"]) != 0
        resume = self.cur if self.state == STOPPED and not restart else None
        self.state = RUNNING
        if resume is None:
            self.run_from(self.first, t)
        else:
            self.start_nav(resume, t)

    def on_exit(self, t: float) -> None:
        """The mission mode was left: the mission stops where it is."""
        self.state = STOPPED if self.state == RUNNING else self.state
        self.fly.reset(t)
        self.send_current(t)

    def mission_start(self, p: list[float], t: float) -> int:
        """MAV_CMD_MISSION_START (module docstring)."""
        ap = self.ap
        if self.px4:
            first = p[0]
            if self.present() and math.isfinite(first) and 0 <= first < len(self.items):
                self.cur = int(first)
            return int(ap._switch(P_MISSION, t))
        if not ap.armed or ap._switch(AP_AUTO, t) != M.MAV_RESULT_ACCEPTED:
            return int(M.MAV_RESULT_FAILED)
        self.auto_armed = True
        if self.state != RUNNING and self.present():
            self.on_enter(t)
        return int(M.MAV_RESULT_ACCEPTED)

    # -- sequencing ---------------------------------------------------------------------
    def run_from(self, k: int, t: float) -> None:
        """Run the DO items from index ``k`` up to the next NAV item and start that; the
        mission completes when none is left."""
        items = self.items
        while k < len(items):
            it = items[k]
            if self.px4 and it.command == RTL:
                self.cur = k
                self.reach(k, t)
                self.cur = min(k + 1, len(items) - 1)
                self.state = COMPLETE
                self.ap._switch_to("rtl", t)
                return
            if self.is_nav(it.command):
                self.start_nav(k, t)
                return
            if self.px4:
                self.cur = k
                self.send_current(t)
            reported, speed = mission_do.run(self.ap, it, t)
            if speed is not None:
                self.fly.speed = None if math.isnan(speed) else speed
            if reported:
                self.reach(k, t)
            k += 1
        self.finish(t)

    def start_nav(self, k: int, t: float) -> None:
        """Start NAV item ``k``."""
        self.cur = k
        self.ap.event(t, f"mission_item_{k}")
        if not self.fly.start(k, t):
            if not self.px4:
                failsafe.statustext(self.ap, M.MAV_SEVERITY_WARNING,
                                    f"Skipping invalid cmd #{self.items[k].command}")
            self.reach(k, t)
            self.run_from(k + 1, t)
            return
        self.send_current(t)

    def item_done(self, t: float) -> None:
        """The current NAV item completed: report it and go on."""
        k = self.cur if self.cur is not None else self.first
        self.reach(k, t)
        self.run_from(k + 1, t)

    def reach(self, k: int, t: float) -> None:
        """MISSION_ITEM_REACHED of item ``k``."""
        self.reached.append(k)
        self.ap.event(t, f"mission_reached_{k}")
        self.ap.mav.mission_item_reached_send(k)

    def finish(self, t: float) -> None:
        """The mission is complete (module docstring)."""
        ap = self.ap
        self.state = COMPLETE
        ap.event(t, "mission_complete")
        if self.px4:
            landed = ap.landed or self.fly.phase in ("land", "landed")
            failsafe.statustext(ap, M.MAV_SEVERITY_INFO, "Mission finished, landed" if landed
                                else "Mission finished, loitering")
            if landed:
                self.fly.phase = "landed"
            else:
                point = self.fly.last_setpoint()
                if ap._switch(P_LOITER, t) == M.MAV_RESULT_ACCEPTED:
                    ap.hold_p = point  # loiter over the last set-point
        elif ap.landed:
            if ap.armed:
                ap.armed = False
                ap.event(t, "disarmed")
        else:
            self.fly.hold_here()
        self.send_current(t)

    # -- every tick ---------------------------------------------------------------------
    def update(self, t: float) -> None:
        """Disarms (ArduCopter resets its mission), new uploads, MISSION_CURRENT on change."""
        ap = self.ap
        if self._armed and not ap.armed:
            self.auto_armed = False
            if not self.px4:
                self.cur = None
                if self.state == RUNNING and self.active and self.present():
                    self.run_from(self.first, t)
        if self.px4 and not ap.armed and not self.active:
            self._disarmed_inactive = True
        self._armed = bool(ap.armed)
        version = int(ap.fence.versions.get(M.MAV_MISSION_TYPE_MISSION, 0))
        if version != self._version:
            self._version = version
            self._on_upload(t)
        self.send_current(t)

    def _on_upload(self, t: float) -> None:
        """A new mission was stored (or the mission cleared)."""
        n = len(self.items)
        if self.px4:
            self.cur = 0
            self.state = STOPPED
            if self.active:
                if n == 0:
                    self.finish(t)
                elif self.ap.armed:
                    self.state = RUNNING
                    self.run_from(0, t)
            return
        self.cur = None if self.cur is not None and self.cur >= n else self.cur
        if self.state == RUNNING and self.active and self.cur is not None \
                and self.fly.phase == "wp":
            self.start_nav(self.cur, t)  # mission changed: restart the current waypoint

    def on_set_current(self, msg: Any, t: float) -> None:
        """MISSION_SET_CURRENT (module docstring)."""
        seq, n = int(msg.seq), len(self.items)
        if self.px4:
            if seq >= n:
                return failsafe.statustext(self.ap, M.MAV_SEVERITY_CRITICAL,
                                           "WPM: WP CURR CMD: Not in list")
            self.cur = seq
            if self.active and self.ap.armed:
                self.state = RUNNING
                self.fly.reset(t)
                self.run_from(seq, t)
            elif self.state == COMPLETE:
                self.state = STOPPED
            self.send_current(t)
            return
        if seq >= n or n == 1:
            return
        k = max(seq, 1)
        if self.state == RUNNING and self.active:
            self.fly.reset(t)
            self.run_from(k, t)
        else:
            self.state = STOPPED
            self.cur = next((j for j in range(k, n) if self.is_nav(self.items[j].command)), None)
        self.send_current(t, seq)

    # -- MISSION_CURRENT ----------------------------------------------------------------
    def current_fields(self) -> tuple[int, int, int, int]:
        """MISSION_CURRENT (seq, total, mission_state, mission_mode)."""
        n = len(self.items)
        seq = self.cur if self.cur is not None else 0
        if self.px4:
            total = n if n > 0 else 0xFFFF
        else:
            total = max(n - 1, 0)
        if not self.present():
            state = M.MISSION_STATE_NO_MISSION
        elif self.state == COMPLETE:
            state = M.MISSION_STATE_COMPLETE
        elif self.state == RUNNING:
            state = M.MISSION_STATE_ACTIVE
        elif self.px4 and seq > 0:
            state = M.MISSION_STATE_PAUSED
        else:
            state = M.MISSION_STATE_NOT_STARTED
        return seq, total, state, int(self.active)

    def send_current(self, t: float, seq: int | None = None, force: bool = False) -> None:
        """MISSION_CURRENT when it changed (or ``seq`` given: that seq, as an answer)."""
        fields = self.current_fields()
        if seq is not None:
            fields = (seq, *fields[1:])
        elif fields == self._sent and not force:
            return
        self._sent = fields
        self.ap.mav.mission_current_send(*fields)


tm.register(M.MAVLINK_MSG_ID_MISSION_CURRENT,
            lambda v, t: v.mission.send_current(t, force=True), None, 1.0)
