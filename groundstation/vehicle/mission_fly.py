"""The NAV item being flown in AUTO: when it is reached or done, and the commands that fly it
(:mod:`groundstation.vehicle.mission_exec` says what each item does per flavour and why;
legs and tracking: :mod:`groundstation.vehicle.mission_nav`).

Phases: ``takeoff`` (a vertical leg), ``climb`` (PX4's climb before a first NAV item that is
no takeoff), ``wp`` (a leg to the item's position, then its hold), ``land_move`` (to the
landing point at the present altitude), ``land`` / ``landed`` (the autopilot's landing
controller), ``rtl`` (ArduCopter's RTL inside AUTO), ``delay`` (NAV_DELAY: stay), ``hold``
(loiter at a point), ``idle``.
Positions [m; local NED], headings [rad; NED], times [s sim].
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from agent.flight.frames import wrap_pi
from agent.wire.mavlink import mavlink as mav
from groundstation.vehicle.mission_nav import (
    YAW_MIN_TRACK,
    YAW_SLEW,
    Leg,
    Speeds,
    bearing,
    leg_speeds,
    slew_yaw,
    track,
)

if TYPE_CHECKING:
    from groundstation.vehicle.control import Controls

M = mav
Array = NDArray[np.float64]
Targets = tuple[float, float, float, float]
TAKEOFF, LAND, RTL = M.MAV_CMD_NAV_TAKEOFF, M.MAV_CMD_NAV_LAND, M.MAV_CMD_NAV_RETURN_TO_LAUNCH
FLY_TO = {M.MAV_CMD_NAV_WAYPOINT, M.MAV_CMD_NAV_LOITER_UNLIM, M.MAV_CMD_NAV_LOITER_TIME}
#: ArduCopter's takeoff is complete within this of its altitude [m] (at rest: AC_AutoTakeoff's
#: "within the stopping distance of the target").
AP_TAKEOFF_DONE = 0.1


class Flight:
    """The current NAV item of a :class:`~.mission_exec.MissionExec` (module docstring)."""

    def __init__(self, ex: Any) -> None:
        self.ex = ex
        self.ap = ex.ap
        self.px4 = bool(ex.px4)
        self.phase = "idle"
        self.item: Any = None
        self.leg: Leg | None = None
        self.dest: Array | None = None
        self.hold_point: Array | None = None
        self.hold_from: float | None = None
        self.fast = False
        self.yaw_cmd: float | None = None
        self.yaw_hold = 0.0
        self.last_t: float | None = None
        self.speed: float | None = None  #: DO_CHANGE_SPEED's horizontal speed [m/s]

    def _pose(self) -> tuple[Array, Array, float]:
        st = self.ap.truth()
        i = self.ap.i
        return st.p[i].copy(), st.v[i].copy(), float(st.att[i, 2])

    def reset(self, t: float) -> None:
        """A mode change: nothing flown, speeds back to the defaults."""
        self.phase, self.item, self.leg, self.hold_from = "idle", None, None, None
        self.yaw_cmd, self.last_t, self.speed = None, t, None

    def hold_here(self) -> None:
        """Loiter where the vehicle is."""
        p, _, yaw = self._pose()
        self.phase, self.hold_point, self.yaw_cmd = "hold", p, yaw

    def last_setpoint(self) -> Array:
        """The last destination flown to (the present position if none)."""
        return self.dest.copy() if self.dest is not None else self._pose()[0]

    # -- starting an item ---------------------------------------------------------------
    def start(self, k: int, t: float) -> bool:
        """Start NAV item ``k``; False if this simulator does not fly that command."""
        ex, ap = self.ex, self.ap
        items = ex.items
        it = items[k]
        p, _, yaw = self._pose()
        self.item, self.leg, self.hold_from = it, None, None
        self.yaw_hold = yaw if self.yaw_cmd is None else self.yaw_cmd
        pt = ap.params_table
        cmd = it.command
        default = self.dest if self.dest is not None else p
        if self.px4 and ap.landed and cmd in FLY_TO:  # PX4's CLIMB work item
            self.phase = "climb"
            self.dest = np.array([p[0], p[1], p[2] - float(pt["MIS_TAKEOFF_ALT"])])
        elif cmd == TAKEOFF:
            z = float(ex.position(it, p)[2])
            if self.px4:
                floor = (p[2] if ap.landed else float(ap.home_ned()[2])) \
                    - float(pt["MIS_TAKEOFF_ALT"])
                z = min(z, floor)
            else:
                z = min(z, float(p[2]) - (1.0 if ap.landed else 0.0))
            self.phase, self.dest = "takeoff", np.array([p[0], p[1], z])
        elif cmd in FLY_TO:
            self.phase, self.dest = "wp", ex.position(it, default)
            nxt = next((j for j in items[k + 1:] if ex.is_nav(j.command)), None)
            self.fast = (not self.px4 and int(max(it.params[0], 0.0)) == 0
                         and nxt is not None and nxt.command in FLY_TO)
        elif cmd == LAND:
            here = it.x == 0 and it.y == 0
            target = p if here else ex.position(it, p)
            far = float(np.hypot(*(target[:2] - p[:2])))
            if not here and (not self.px4 or far > float(pt["NAV_ACC_RAD"])):
                self.phase = "land_move"
                self.dest = np.array([target[0], target[1], p[2]])
            else:
                self._begin_land(target)
        elif cmd == M.MAV_CMD_NAV_DELAY:
            self.phase, self.hold_from = "delay", t
            self.hold_point = self.dest.copy() if self.dest is not None else p
        elif cmd == RTL and not self.px4:
            self.phase = "rtl"
            ap.rtl_landing, ap.hold_p, ap.hold_yaw = False, p.copy(), yaw
        else:
            return False
        return True

    def _begin_land(self, target: Array) -> None:
        p, _, yaw = self._pose()
        self.phase = "land"
        self.dest = np.array([target[0], target[1], p[2]])
        self.ap.hold_p = self.dest.copy()
        self.ap.hold_yaw = yaw if self.yaw_cmd is None else self.yaw_cmd

    # -- every step ---------------------------------------------------------------------
    def step(self, t: float) -> Targets | None:
        """Check the item, then the commands for this step (None: the mission left the
        mission mode, the caller asks the new mode)."""
        dt = 0.0 if self.last_t is None else max(t - self.last_t, 0.0)
        self.last_t = t
        self._verify(t)
        if not self.ex.active:
            return None
        return self._control(t, dt)

    def _verify(self, t: float) -> None:
        ex, ap = self.ex, self.ap
        ph = self.phase
        p, _, yaw = self._pose()
        pt = ap.params_table
        if ph == "takeoff" and self.dest is not None:
            if not self.px4 and not ex.auto_armed:
                if int(pt["AUTO_OPTIONS"]) & 2 or not ap.landed:
                    ex.auto_armed = True
                else:
                    return
            if self.px4:
                height = float(ap.home_ned()[2]) - float(self.dest[2])
                rad = float(pt["NAV_MC_ALT_RAD"])
                rad = height / 2.0 if 0.0 < height < rad else rad
                done = p[2] < self.dest[2] + rad
            else:
                done = self.leg is not None and self.leg.done(t) and \
                    abs(p[2] - self.dest[2]) < AP_TAKEOFF_DONE
            if done:
                ex.item_done(t)
        elif ph == "climb" and self.dest is not None:
            if p[2] < self.dest[2] + float(pt["NAV_MC_ALT_RAD"]) and ex.cur is not None:
                ex.start_nav(ex.cur, t)
        elif ph == "wp":
            if self.hold_from is None and self._wp_reached(t, p, yaw):
                self.hold_from = t
            if self.hold_from is not None and self.item.command != M.MAV_CMD_NAV_LOITER_UNLIM:
                hold = max(float(self.item.params[0]), 0.0)
                if not self.px4:
                    hold = float(int(hold))  # AP_Mission keeps whole seconds (uint16 p1)
                if t - self.hold_from >= hold:
                    ex.item_done(t)
        elif ph == "land_move" and self.dest is not None:
            if self.px4:
                done = float(np.hypot(*(p[:2] - self.dest[:2]))) <= float(pt["NAV_ACC_RAD"])
            else:
                done = self.leg is not None and self.leg.done(t) and \
                    float(np.linalg.norm(p - self.dest)) <= float(pt["WPNAV_RADIUS"]) / 100.0
            if done:
                self._begin_land(self.dest)
        elif ph == "delay" and self.hold_from is not None:
            if t - self.hold_from >= max(float(self.item.params[0]), 0.0):
                ex.item_done(t)
        elif ph == "land" and self.px4 and ap.landed:
            ex.item_done(t)  # ArduCopter disarms on touchdown instead (verify_land)
        elif ph == "rtl" and ap.rtl_landing and ap.landed:
            ex.item_done(t)

    def _wp_reached(self, t: float, p: Array, yaw: float) -> bool:
        """The waypoint's position (and PX4: its yaw) is reached (mission_exec docstring)."""
        assert self.dest is not None
        pt = self.ap.params_table
        d = p - self.dest
        if not self.px4:
            if self.leg is None or not self.leg.done(t):
                return False
            return self.fast or float(np.linalg.norm(d)) <= float(pt["WPNAV_RADIUS"]) / 100.0
        radius = float(self.item.params[1])
        if not (math.isfinite(radius) and radius > 1e-6):
            radius = float(pt["NAV_ACC_RAD"])
        if float(np.hypot(d[0], d[1])) > radius or abs(float(d[2])) > float(pt["NAV_MC_ALT_RAD"]):
            return False
        want = float(self.item.params[3])
        if math.isfinite(want):
            return abs(wrap_pi(math.radians(want) - yaw)) < math.radians(float(pt["MIS_YAW_ERR"]))
        return True

    def _yaw_want(self) -> float:
        leg = self.leg
        if self.phase == "wp" and self.px4 and math.isfinite(float(self.item.params[3])):
            return wrap_pi(math.radians(float(self.item.params[3])))
        if self.phase in ("wp", "land_move") and leg is not None:
            still = not self.px4 and int(self.ap.params_table["WP_YAW_BEHAVIOR"]) == 0
            if not still and leg.horizontal >= YAW_MIN_TRACK:
                return bearing(leg.start, leg.end)
        return self.yaw_hold

    def _speeds(self) -> Speeds:
        s = leg_speeds(self.ap, self.speed)
        if self.px4 and self.phase in ("takeoff", "climb"):
            s = replace(s, up=float(self.ap.params_table["MPC_TKO_SPEED"]))
        return s

    def _control(self, t: float, dt: float) -> Targets:
        ap: Controls = self.ap
        ph = self.phase
        p, v, yaw_now = self._pose()
        if self.yaw_cmd is None:
            self.yaw_cmd = yaw_now
        if ph in ("takeoff", "climb", "wp", "land_move") and self.dest is not None:
            if ph == "takeoff" and not self.px4 and not self.ex.auto_armed:
                return 0.0, 0.0, yaw_now, 0.0  # waits for the throttle (mission_exec)
            speeds = self._speeds()
            if self.leg is None:
                self.leg = Leg(p, self.dest, speeds, t)
            rate = YAW_SLEW["px4" if self.px4 else "ardupilot"]
            self.yaw_cmd = slew_yaw(self.yaw_cmd, self._yaw_want(), rate, dt)
            p_t, v_t, a_t = self.leg.at(t)
            return track(ap, p_t, v_t, a_t, self.yaw_cmd, speeds)
        if ph in ("land", "landed"):
            return ap._land(t, float(v[2]))
        if ph == "rtl":
            return ap._rtl(t)
        if ph in ("hold", "delay") and self.hold_point is not None:
            return ap._hold(self.hold_point, self.yaw_cmd)
        if ap.landed:
            return 0.0, 0.0, yaw_now, 0.0
        return ap._hold(ap.hold_p, ap.hold_yaw)
