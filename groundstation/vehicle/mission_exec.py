"""Missions flown in AUTO by the simulated autopilot: the stored MAV_MISSION_TYPE_MISSION items
(:mod:`.fence` stores every mission type), item by item as ArduCopter and PX4 fly them.
:class:`MissionExec` is what both do; each flavour's subclass (``mission_class`` of
:mod:`groundstation.vehicle.flavours`: ``ardupilot_mission``, ``px4_mission``) what it does its
own way, in the order of this docstring.

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
from abc import ABC, abstractmethod
from typing import Any, ClassVar

import numpy as np

from agent.wire.mavlink import mavlink as mav
from groundstation.vehicle import failsafe, mission_do
from groundstation.vehicle import telemetry as tm
from groundstation.vehicle.conventions import local_ne
from groundstation.vehicle.mission_fly import Flight

M = mav
STOPPED, RUNNING, COMPLETE = "stopped", "running", "complete"
TAKEOFF, LAND, RTL = M.MAV_CMD_NAV_TAKEOFF, M.MAV_CMD_NAV_LAND, M.MAV_CMD_NAV_RETURN_TO_LAUNCH
FLY_TO = {M.MAV_CMD_NAV_WAYPOINT, M.MAV_CMD_NAV_LOITER_UNLIM, M.MAV_CMD_NAV_LOITER_TIME}
RELATIVE_FRAMES = {M.MAV_FRAME_GLOBAL_RELATIVE_ALT, M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT}


class MissionExec(ABC):
    """One autopilot's mission in AUTO (module docstring); ``reached`` lists the seq of every
    MISSION_ITEM_REACHED sent. A flavour's subclass sets the class attributes and implements
    the abstract methods."""

    #: The :class:`~.mission_fly.Flight` subclass that flies its NAV items.
    flight: ClassVar[type[Flight]]
    #: The first item flown (ArduPilot AP_MISSION_FIRST_REAL_COMMAND 1: item 0 is home).
    first: ClassVar[int]
    #: NAV_RETURN_TO_LAUNCH is a command: reached at once, then the RTL mode (PX4).
    rtl_item_is_command: ClassVar[bool]
    #: MISSION_CURRENT names each DO item while it runs (PX4's ``current_seq``).
    current_do_items: ClassVar[bool]
    #: A NAV item it cannot fly is skipped with STATUSTEXT "Skipping invalid cmd #N".
    skips_aloud: ClassVar[bool]
    #: A mission's DO_MOUNT_CONTROL first takes the gimbal's control (PX4).
    mount_takes_gimbal: ClassVar[bool]
    #: MISSION_CURRENT says PAUSED for a stopped mission past its first item.
    pauses: ClassVar[bool]

    def __init__(self, ap: Any) -> None:
        self.ap = ap
        self.state = STOPPED
        self.cur: int | None = None
        self.auto_armed = False
        self.reached: list[int] = []
        self.fly = self.flight(self)
        self._armed = False
        self._version = 0
        self._sent: tuple[int, int, int, int] | None = None

    # -- the stored mission -------------------------------------------------------------
    @property
    def items(self) -> list[Any]:
        """The stored mission items (ArduCopter's item 0 is home)."""
        return list(self.ap.fence.stored.get(M.MAV_MISSION_TYPE_MISSION, []))

    def present(self) -> bool:
        """A mission is stored (ArduCopter: more than home)."""
        return len(self.items) > self.first

    @abstractmethod
    def is_nav(self, cmd: int) -> bool:
        """A NAV item: flown, not run (module docstring)."""

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
        return self.refuse_armed_entry(t)

    @abstractmethod
    def refuse_armed_entry(self, t: float) -> bool:
        """Armed, with a mission: whether the mission mode is refused still."""

    @abstractmethod
    def refuses_arming(self) -> bool:
        """Arming is refused in the mission mode now."""

    def on_enter(self, t: float) -> None:
        """The mission mode was entered: start or resume the mission."""
        self.fly.reset(t)
        self.begin(t)

    @abstractmethod
    def begin(self, t: float) -> None:
        """Start or resume the mission (the mission mode was entered, the flight reset)."""

    def on_exit(self, t: float) -> None:
        """The mission mode was left: the mission stops where it is."""
        self.state = STOPPED if self.state == RUNNING else self.state
        self.fly.reset(t)
        self.send_current(t)

    @abstractmethod
    def mission_start(self, p: list[float], t: float) -> int:
        """MAV_CMD_MISSION_START (param1..7): the MAV_RESULT."""

    # -- sequencing ---------------------------------------------------------------------
    def run_from(self, k: int, t: float) -> None:
        """Run the DO items from index ``k`` up to the next NAV item and start that; the
        mission completes when none is left."""
        items = self.items
        while k < len(items):
            it = items[k]
            if self.rtl_item_is_command and it.command == RTL:
                self.cur = k
                self.reach(k, t)
                self.cur = min(k + 1, len(items) - 1)
                self.state = COMPLETE
                self.ap._switch_to("rtl", t)
                return
            if self.is_nav(it.command):
                self.start_nav(k, t)
                return
            if self.current_do_items:
                self.cur = k
                self.send_current(t)
            reported, speed = mission_do.run(self, it, t)
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
            if self.skips_aloud:
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
        self.state = COMPLETE
        self.ap.event(t, "mission_complete")
        self.end(t)
        self.send_current(t)

    @abstractmethod
    def end(self, t: float) -> None:
        """What the vehicle does once the mission is complete."""

    # -- DO items (:mod:`.mission_do`) ----------------------------------------------------
    @abstractmethod
    def do_known(self, cmd: int) -> bool:
        """A DO item it carries out or accepts (others are skipped aloud)."""

    @abstractmethod
    def do_reported(self, cmd: int) -> bool:
        """A completed DO item is reported with MISSION_ITEM_REACHED."""

    @abstractmethod
    def camera_item(self, cmd: int, p: list[float], t: float) -> None:
        """A camera item (param1..7)."""

    @abstractmethod
    def speed_item(self, p: list[float]) -> float | None:
        """DO_CHANGE_SPEED's horizontal speed [m/s]: None unchanged, NaN the default."""

    # -- every tick ---------------------------------------------------------------------
    def update(self, t: float) -> None:
        """Disarms, new uploads, MISSION_CURRENT on change."""
        ap = self.ap
        disarmed = self._armed and not ap.armed
        if disarmed:
            self.auto_armed = False
        self.watch_disarm(t, disarmed)
        self._armed = bool(ap.armed)
        version = int(ap.fence.versions.get(M.MAV_MISSION_TYPE_MISSION, 0))
        if version != self._version:
            self._version = version
            self.on_upload(t)
        self.send_current(t)

    @abstractmethod
    def watch_disarm(self, t: float, disarmed: bool) -> None:
        """Every tick, before uploads: ``disarmed`` says the vehicle just disarmed."""

    @abstractmethod
    def on_upload(self, t: float) -> None:
        """A new mission was stored (or the mission cleared)."""

    @abstractmethod
    def on_set_current(self, msg: Any, t: float) -> None:
        """MISSION_SET_CURRENT (module docstring)."""

    # -- MISSION_CURRENT ----------------------------------------------------------------
    @abstractmethod
    def total(self, n: int) -> int:
        """MISSION_CURRENT.total of ``n`` stored items."""

    def current_fields(self) -> tuple[int, int, int, int]:
        """MISSION_CURRENT (seq, total, mission_state, mission_mode)."""
        n = len(self.items)
        seq = self.cur if self.cur is not None else 0
        total = self.total(n)
        if not self.present():
            state = M.MISSION_STATE_NO_MISSION
        elif self.state == COMPLETE:
            state = M.MISSION_STATE_COMPLETE
        elif self.state == RUNNING:
            state = M.MISSION_STATE_ACTIVE
        elif self.pauses and seq > 0:
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
