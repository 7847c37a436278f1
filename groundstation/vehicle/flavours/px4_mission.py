"""Missions as PX4 flies them in AUTO.MISSION: what :mod:`groundstation.vehicle.mission_exec`
(its docstring gives the sources: navigator mission_base.cpp, mission_block.cpp, Commander.cpp)
says of PX4, on top of what both autopilots do.
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Any

import numpy as np

from agent.flight.frames import wrap_pi
from agent.wire.mavlink import mavlink as mav
from groundstation.vehicle import failsafe, mission_do
from groundstation.vehicle.mission_exec import (
    COMPLETE,
    LAND,
    RUNNING,
    STOPPED,
    TAKEOFF,
    MissionExec,
)
from groundstation.vehicle.mission_fly import FLY_TO, Array, Flight
from groundstation.vehicle.mission_nav import Speeds

M = mav
#: PX4's items with a position (navigator ``item_contains_position``); its RTL is a command.
PX4_POSITION = {*FLY_TO, M.MAV_CMD_NAV_LOITER_TURNS, LAND, TAKEOFF,
                M.MAV_CMD_NAV_LOITER_TO_ALT}


class PX4Flight(Flight):
    """A NAV item as PX4's navigator flies it (mission_block.cpp)."""

    yaw_slew = math.radians(45.0)  # MPC_YAWRAUTO_MAX 45 °/s (src/modules/mc_pos_control)
    waits_for_throttle = False
    whole_second_holds = False
    flies_rtl = False  # a command (PX4Mission.rtl_item_is_command)
    land_completes = True
    follows_item_yaw = True

    def climbs_first(self, cmd: int) -> bool:
        return bool(self.ap.landed and cmd in FLY_TO)  # its CLIMB work item

    def takeoff_altitude(self, z: float, p: Array) -> float:
        ap = self.ap
        floor = (p[2] if ap.landed else float(ap.home_ned()[2])) \
            - float(ap.params_table["MIS_TAKEOFF_ALT"])
        return min(z, floor)

    def fast_waypoint(self, it: Any, nxt: Any) -> bool:
        return False

    def moves_before_landing(self, far: float) -> bool:
        return far > float(self.ap.params_table["NAV_ACC_RAD"])  # else it slides there

    def takeoff_done(self, t: float, p: Array) -> bool:
        assert self.dest is not None
        ap = self.ap
        height = float(ap.home_ned()[2]) - float(self.dest[2])
        rad = float(ap.params_table["NAV_MC_ALT_RAD"])
        rad = height / 2.0 if 0.0 < height < rad else rad
        return bool(p[2] < self.dest[2] + rad)

    def land_move_done(self, t: float, p: Array) -> bool:
        assert self.dest is not None
        far = float(np.hypot(*(p[:2] - self.dest[:2])))
        return far <= float(self.ap.params_table["NAV_ACC_RAD"])

    def wp_reached(self, t: float, p: Array, yaw: float) -> bool:
        """Within the acceptance radius (param2, else NAV_ACC_RAD), NAV_MC_ALT_RAD and
        MIS_YAW_ERR of the item's yaw when it gives one."""
        assert self.dest is not None
        pt = self.ap.params_table
        d = p - self.dest
        radius = float(self.item.params[1])
        if not (math.isfinite(radius) and radius > 1e-6):
            radius = float(pt["NAV_ACC_RAD"])
        if float(np.hypot(d[0], d[1])) > radius or abs(float(d[2])) > float(pt["NAV_MC_ALT_RAD"]):
            return False
        want = float(self.item.params[3])
        if math.isfinite(want):
            return abs(wrap_pi(math.radians(want) - yaw)) < math.radians(float(pt["MIS_YAW_ERR"]))
        return True

    def keeps_heading(self) -> bool:
        return False

    def base_speeds(self) -> Speeds:
        pt = self.ap.params_table
        return Speeds(float(pt["MPC_XY_CRUISE"]), float(pt["MPC_Z_V_AUTO_UP"]),
                      float(pt["MPC_Z_V_AUTO_DN"]), float(pt["MPC_ACC_HOR"]))

    def speeds(self) -> Speeds:
        """Takeoff and climb at MPC_TKO_SPEED."""
        s = super().speeds()
        if self.phase in ("takeoff", "climb"):
            s = replace(s, up=float(self.ap.params_table["MPC_TKO_SPEED"]))
        return s


class PX4Mission(MissionExec):
    """PX4 AUTO.MISSION: every item from 0, DO items reported and current in turn, RTL as a
    command, restarted from 0 after a disarm once finished."""

    flight = PX4Flight
    first = 0
    rtl_item_is_command = True
    current_do_items = True
    skips_aloud = False
    mount_takes_gimbal = True  # mission_block.cpp acquires the gimbal first
    pauses = True

    def __init__(self, ap: Any) -> None:
        super().__init__(ap)
        self._disarmed_inactive = False

    def is_nav(self, cmd: int) -> bool:
        """Its items with a position, and NAV_DELAY, which takes its time too."""
        return cmd in PX4_POSITION or cmd == M.MAV_CMD_NAV_DELAY

    def refuse_armed_entry(self, t: float) -> bool:
        return False

    def refuses_arming(self) -> bool:
        """Without a mission."""
        if not self.active:
            return False
        return not self.present()

    def begin(self, t: float) -> None:
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

    def mission_start(self, p: list[float], t: float) -> int:
        """AUTO.MISSION from param1's item (when it is one)."""
        first = p[0]
        if self.present() and math.isfinite(first) and 0 <= first < len(self.items):
            self.cur = int(first)
        return int(self.ap._switch(self.ap.flavour.mission_mode, t))

    def end(self, t: float) -> None:
        """"Mission finished": AUTO.LOITER over the last set-point, or stay landed."""
        ap = self.ap
        landed = ap.landed or self.fly.phase in ("land", "landed")
        failsafe.statustext(ap, M.MAV_SEVERITY_INFO, "Mission finished, landed" if landed
                            else "Mission finished, loitering")
        if landed:
            self.fly.phase = "landed"
        else:
            point = self.fly.last_setpoint()
            if ap._switch(ap.flavour.loiter_mode, t) == M.MAV_RESULT_ACCEPTED:
                ap.hold_p = point  # loiter over the last set-point

    def do_known(self, cmd: int) -> bool:
        return True  # unknown DO items are passed over silently

    def do_reported(self, cmd: int) -> bool:
        return True

    def camera_item(self, cmd: int, p: list[float], t: float) -> None:
        mission_do.component_camera(self.ap, cmd, p, t)

    def speed_item(self, p: list[float]) -> float | None:
        return mission_do.px4_speed(p)

    def watch_disarm(self, t: float, disarmed: bool) -> None:
        if not self.ap.armed and not self.active:
            self._disarmed_inactive = True  # checkMissionRestart

    def on_upload(self, t: float) -> None:
        self.cur = 0
        self.state = STOPPED
        if self.active:
            if not self.items:
                self.finish(t)
            elif self.ap.armed:
                self.state = RUNNING
                self.run_from(0, t)

    def on_set_current(self, msg: Any, t: float) -> None:
        seq = int(msg.seq)
        if seq >= len(self.items):
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
        return None

    def total(self, n: int) -> int:
        return n if n > 0 else 0xFFFF
