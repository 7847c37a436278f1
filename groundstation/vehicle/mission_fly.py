"""The NAV item being flown in AUTO: when it is reached or done, and the commands that fly it
(:mod:`groundstation.vehicle.mission_exec` says what each item does per flavour and why;
legs and tracking: :mod:`groundstation.vehicle.mission_nav`).

Phases: ``takeoff`` (a vertical leg), ``climb`` (PX4's climb before a first NAV item that is
no takeoff), ``wp`` (a leg to the item's position, then its hold), ``land_move`` (to the
landing point at the present altitude), ``land`` / ``landed`` (the autopilot's landing
controller), ``rtl`` (ArduCopter's RTL inside AUTO), ``delay`` (NAV_DELAY: stay), ``hold``
(loiter at a point), ``idle``.
Positions [m; local NED], headings [rad; NED], times [s sim]. :class:`Flight` is what both
autopilots do; a flavour's subclass (``MissionExec.flight``) what it does its own way.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np
from numpy.typing import NDArray

from agent.flight.frames import wrap_pi
from agent.wire.mavlink import mavlink as mav
from groundstation.vehicle.mission_nav import (
    YAW_MIN_TRACK,
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


class Flight(ABC):
    """The current NAV item of a :class:`~.mission_exec.MissionExec` (module docstring). A
    flavour's subclass sets the class attributes and implements the abstract methods."""

    #: Heading slew rate [rad/s] (:mod:`.mission_nav`).
    yaw_slew: ClassVar[float]
    #: A takeoff on the ground waits for the pilot's throttle (ArduCopter's ``auto_armed``).
    waits_for_throttle: ClassVar[bool]
    #: A waypoint's hold counts whole seconds only.
    whole_second_holds: ClassVar[bool]
    #: NAV_RETURN_TO_LAUNCH is flown inside the mission.
    flies_rtl: ClassVar[bool]
    #: NAV_LAND completes (MISSION_ITEM_REACHED) once landed.
    land_completes: ClassVar[bool]
    #: A waypoint's yaw (param4, when given) is the heading flown.
    follows_item_yaw: ClassVar[bool]

    def __init__(self, ex: Any) -> None:
        self.ex = ex
        self.ap = ex.ap
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

    # -- the flavour's rules ----------------------------------------------------------------
    @abstractmethod
    def climbs_first(self, cmd: int) -> bool:
        """NAV item ``cmd`` starts with a climb to the takeoff altitude (PX4's CLIMB)."""

    @abstractmethod
    def takeoff_altitude(self, z: float, p: Array) -> float:
        """A NAV_TAKEOFF's target altitude [m; NED] from the item's ``z``, started at ``p``."""

    @abstractmethod
    def fast_waypoint(self, it: Any, nxt: Any) -> bool:
        """Waypoint ``it`` passes as soon as its target arrives (``nxt``: the next NAV item)."""

    @abstractmethod
    def moves_before_landing(self, far: float) -> bool:
        """A NAV_LAND ``far`` [m] away flies there before it descends."""

    @abstractmethod
    def takeoff_done(self, t: float, p: Array) -> bool:
        """The takeoff leg to ``self.dest`` is complete at position ``p``."""

    @abstractmethod
    def land_move_done(self, t: float, p: Array) -> bool:
        """The move to the landing point ``self.dest`` is complete at ``p``."""

    @abstractmethod
    def wp_reached(self, t: float, p: Array, yaw: float) -> bool:
        """The waypoint is reached (mission_exec docstring)."""

    @abstractmethod
    def keeps_heading(self) -> bool:
        """Legs are flown without turning towards them."""

    @abstractmethod
    def base_speeds(self) -> Speeds:
        """The mission speeds of its parameters (:func:`.mission_nav.leg_speeds`)."""

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
        if self.climbs_first(cmd):
            self.phase = "climb"
            self.dest = np.array([p[0], p[1], p[2] - float(pt["MIS_TAKEOFF_ALT"])])
        elif cmd == TAKEOFF:
            z = self.takeoff_altitude(float(ex.position(it, p)[2]), p)
            self.phase, self.dest = "takeoff", np.array([p[0], p[1], z])
        elif cmd in FLY_TO:
            self.phase, self.dest = "wp", ex.position(it, default)
            nxt = next((j for j in items[k + 1:] if ex.is_nav(j.command)), None)
            self.fast = self.fast_waypoint(it, nxt)
        elif cmd == LAND:
            here = it.x == 0 and it.y == 0
            target = p if here else ex.position(it, p)
            far = float(np.hypot(*(target[:2] - p[:2])))
            if not here and self.moves_before_landing(far):
                self.phase = "land_move"
                self.dest = np.array([target[0], target[1], p[2]])
            else:
                self._begin_land(target)
        elif cmd == M.MAV_CMD_NAV_DELAY:
            self.phase, self.hold_from = "delay", t
            self.hold_point = self.dest.copy() if self.dest is not None else p
        elif cmd == RTL and self.flies_rtl:
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

    def _waiting_for_throttle(self) -> bool:
        """A takeoff on the ground still waits for the throttle (mission_exec docstring)."""
        return self.waits_for_throttle and not self.ex.auto_armed

    def _verify(self, t: float) -> None:
        ex, ap = self.ex, self.ap
        ph = self.phase
        p, _, yaw = self._pose()
        pt = ap.params_table
        if ph == "takeoff" and self.dest is not None:
            if self._waiting_for_throttle():
                if int(pt["AUTO_OPTIONS"]) & 2 or not ap.landed:
                    ex.auto_armed = True
                else:
                    return
            if self.takeoff_done(t, p):
                ex.item_done(t)
        elif ph == "climb" and self.dest is not None:
            if p[2] < self.dest[2] + float(pt["NAV_MC_ALT_RAD"]) and ex.cur is not None:
                ex.start_nav(ex.cur, t)
        elif ph == "wp":
            if self.hold_from is None and self.wp_reached(t, p, yaw):
                self.hold_from = t
            if self.hold_from is not None and self.item.command != M.MAV_CMD_NAV_LOITER_UNLIM:
                hold = max(float(self.item.params[0]), 0.0)
                if self.whole_second_holds:
                    hold = float(int(hold))  # AP_Mission keeps whole seconds (uint16 p1)
                if t - self.hold_from >= hold:
                    ex.item_done(t)
        elif ph == "land_move" and self.dest is not None:
            if self.land_move_done(t, p):
                self._begin_land(self.dest)
        elif ph == "delay" and self.hold_from is not None:
            if t - self.hold_from >= max(float(self.item.params[0]), 0.0):
                ex.item_done(t)
        elif ph == "land" and self.land_completes and ap.landed:
            ex.item_done(t)  # ArduCopter disarms on touchdown instead (verify_land)
        elif ph == "rtl" and ap.rtl_landing and ap.landed:
            ex.item_done(t)

    def _yaw_want(self) -> float:
        leg = self.leg
        if self.phase == "wp" and self.follows_item_yaw \
                and math.isfinite(float(self.item.params[3])):
            return wrap_pi(math.radians(float(self.item.params[3])))
        if self.phase in ("wp", "land_move") and leg is not None:
            if not self.keeps_heading() and leg.horizontal >= YAW_MIN_TRACK:
                return bearing(leg.start, leg.end)
        return self.yaw_hold

    def speeds(self) -> Speeds:
        """The speeds of the leg flown now: :meth:`base_speeds`, DO_CHANGE_SPEED's override."""
        return leg_speeds(self.base_speeds(), self.speed)

    def _control(self, t: float, dt: float) -> Targets:
        ap: Controls = self.ap
        ph = self.phase
        p, v, yaw_now = self._pose()
        if self.yaw_cmd is None:
            self.yaw_cmd = yaw_now
        if ph in ("takeoff", "climb", "wp", "land_move") and self.dest is not None:
            if ph == "takeoff" and self._waiting_for_throttle():
                return 0.0, 0.0, yaw_now, 0.0  # waits for the throttle (mission_exec)
            speeds = self.speeds()
            if self.leg is None:
                self.leg = Leg(p, self.dest, speeds, t)
            self.yaw_cmd = slew_yaw(self.yaw_cmd, self._yaw_want(), self.yaw_slew, dt)
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
