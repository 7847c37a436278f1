"""Missions as ArduCopter flies them in AUTO: what :mod:`groundstation.vehicle.mission_exec`
(its docstring gives the sources: ArduCopter/mode_auto.cpp, libraries/AP_Mission) says of
ArduCopter, on top of what both autopilots do.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from agent.wire.mavlink import mavlink as mav
from groundstation.vehicle import failsafe, mission_do
from groundstation.vehicle.mission_exec import RUNNING, STOPPED, TAKEOFF, MissionExec
from groundstation.vehicle.mission_fly import FLY_TO, Array, Flight
from groundstation.vehicle.mission_nav import Speeds

M = mav
#: ArduCopter's takeoff is complete within this of its altitude [m] (at rest: AC_AutoTakeoff's
#: "within the stopping distance of the target").
AP_TAKEOFF_DONE = 0.1


class ArduPilotFlight(Flight):
    """A NAV item as ArduCopter flies it (AC_WPNav, ModeAuto ``verify_*``)."""

    yaw_slew = math.radians(60.0)  # ATC_SLEW_YAW 6000 cdeg/s (libraries/AC_AttitudeControl)
    waits_for_throttle = True
    whole_second_holds = True
    flies_rtl = True
    land_completes = False  # it disarms on touchdown instead (verify_land)
    follows_item_yaw = False  # WP_YAW_BEHAVIOR decides

    def climbs_first(self, cmd: int) -> bool:
        return False

    def takeoff_altitude(self, z: float, p: Array) -> float:
        return min(z, float(p[2]) - (1.0 if self.ap.landed else 0.0))  # at least 1 m up

    def fast_waypoint(self, it: Any, nxt: Any) -> bool:
        return (int(max(it.params[0], 0.0)) == 0 and nxt is not None
                and nxt.command in FLY_TO)

    def moves_before_landing(self, far: float) -> bool:
        return True  # do_land: to the point at its altitude first

    def takeoff_done(self, t: float, p: Array) -> bool:
        assert self.dest is not None
        return self.leg is not None and self.leg.done(t) and \
            abs(p[2] - self.dest[2]) < AP_TAKEOFF_DONE

    def land_move_done(self, t: float, p: Array) -> bool:
        assert self.dest is not None
        radius = float(self.ap.params_table["WPNAV_RADIUS"]) / 100.0
        return self.leg is not None and self.leg.done(t) and \
            float(np.linalg.norm(p - self.dest)) <= radius

    def wp_reached(self, t: float, p: Array, yaw: float) -> bool:
        assert self.dest is not None
        if self.leg is None or not self.leg.done(t):
            return False
        radius = float(self.ap.params_table["WPNAV_RADIUS"]) / 100.0
        return self.fast or float(np.linalg.norm(p - self.dest)) <= radius

    def keeps_heading(self) -> bool:
        return int(self.ap.params_table["WP_YAW_BEHAVIOR"]) == 0

    def base_speeds(self) -> Speeds:
        pt = self.ap.params_table  # WPNAV_* in cm/s and cm/s²
        return Speeds(float(pt["WPNAV_SPEED"]) / 100.0, float(pt["WPNAV_SPEED_UP"]) / 100.0,
                      float(pt["WPNAV_SPEED_DN"]) / 100.0, float(pt["WPNAV_ACCEL"]) / 100.0)


class ArduPilotMission(MissionExec):
    """ArduCopter AUTO (mode_auto.cpp, AP_Mission): item 0 is home, every NAV item up to
    MAV_CMD_NAV_LAST, missions resumed unless MIS_RESTART."""

    flight = ArduPilotFlight
    first = 1
    rtl_item_is_command = False
    current_do_items = False
    skips_aloud = True
    mount_takes_gimbal = False
    pauses = False

    def is_nav(self, cmd: int) -> bool:
        return bool(cmd <= M.MAV_CMD_NAV_LAST)

    def refuse_armed_entry(self, t: float) -> bool:
        ap = self.ap
        if ap.landed and not self._starts_with_takeoff():
            failsafe.statustext(ap, M.MAV_SEVERITY_CRITICAL, "Auto: Missing Takeoff Cmd")
            ap.event(t, "mission_refused_no_takeoff")
            return True
        return False

    def refuses_arming(self) -> bool:
        """Without AUTO_OPTIONS bit 0."""
        if not self.active:
            return False
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

    def begin(self, t: float) -> None:
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

    def mission_start(self, p: list[float], t: float) -> int:
        ap = self.ap
        if not ap.armed or ap._switch(ap.flavour.mission_mode, t) != M.MAV_RESULT_ACCEPTED:
            return int(M.MAV_RESULT_FAILED)
        self.auto_armed = True
        if self.state != RUNNING and self.present():
            self.on_enter(t)
        return int(M.MAV_RESULT_ACCEPTED)

    def end(self, t: float) -> None:
        """exit_mission: disarm if landed, else loiter where it is, still in AUTO."""
        ap = self.ap
        if ap.landed:
            if ap.armed:
                ap.armed = False
                ap.event(t, "disarmed")
        else:
            self.fly.hold_here()

    def do_known(self, cmd: int) -> bool:
        return mission_do.ardupilot_known(cmd)

    def do_reported(self, cmd: int) -> bool:
        return mission_do.ardupilot_reported(cmd)

    def camera_item(self, cmd: int, p: list[float], t: float) -> None:
        self.ap.camera.autopilot_command(cmd, p, t)  # AP_Mission → AP_Camera

    def speed_item(self, p: list[float]) -> float | None:
        return mission_do.ardupilot_speed(p)

    def watch_disarm(self, t: float, disarmed: bool) -> None:
        """A disarm resets the mission to its start (AP_Arming_Copter::disarm)."""
        if not disarmed:
            return
        self.cur = None
        if self.state == RUNNING and self.active and self.present():
            self.run_from(self.first, t)

    def on_upload(self, t: float) -> None:
        n = len(self.items)
        self.cur = None if self.cur is not None and self.cur >= n else self.cur
        if self.state == RUNNING and self.active and self.cur is not None \
                and self.fly.phase == "wp":
            self.start_nav(self.cur, t)  # mission changed: restart the current waypoint

    def on_set_current(self, msg: Any, t: float) -> None:
        """``set_current_cmd``: 0 means 1, out of range ignored; answered with the seq."""
        seq, n = int(msg.seq), len(self.items)
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

    def total(self, n: int) -> int:
        return max(n - 1, 0)  # less home
