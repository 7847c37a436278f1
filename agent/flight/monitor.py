"""Vehicle monitor: are we still the ones flying this vehicle? A pure state machine.

Feed it the decoded fields of the vehicle's messages with the mission time t [s]; ask
:meth:`VehicleMonitor.check` for a :class:`Verdict`. After :meth:`VehicleMonitor.engage`
(the arm and mode handshake confirmed) the verdict is *in control* until the first of:

* ``link_lost``: no HEARTBEAT from the vehicle for ``heartbeat_timeout_s``;
* ``mode_changed``: its custom_mode left the expected set (a pilot's switch or a failsafe;
  the mode is named from the tables below);
* ``disarmed``: HEARTBEAT base_mode without MAV_MODE_FLAG_SAFETY_ARMED (128);
* ``battery_critical``: SYS_STATUS / BATTERY_STATUS remaining at or below the bound, or a
  BATTERY_STATUS charge_state CRITICAL/EMERGENCY/FAILED/UNHEALTHY;
* ``autopilot_failsafe``: HEARTBEAT system_status CRITICAL (5), EMERGENCY (6) or
  FLIGHT_TERMINATION (8) (ArduCopter reports CRITICAL while any failsafe is triggered:
  ArduCopter/GCS_Mavlink.cpp, vehicle_system_status());
* ``landed``: EXTENDED_SYS_STATE landed_state ON_GROUND (1) after IN_AIR (2) was seen.

The first cause is latched until the next :meth:`engage`. Messages from other systems or
components (a ground station, a camera, another drone) are ignored; MAVLink HEARTBEATs of
non-autopilots carry MAV_AUTOPILOT_INVALID (8) and are ignored too.

:class:`MocapAge` is the other rule the driver applies: how old its latest mocap pose is,
judged on the ground station's own time stamps (the stale-mocap failsafe).

Mode numbers and names (HEARTBEAT.custom_mode) are the flavour's
(:mod:`agent.flight.flavours`: ArduCopter's ``Mode::Number``, PX4's main and sub mode bits).
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass

from agent.flight.flavours import (
    ARDUCOPTER_MODES,
    PX4_AUTO_SUB_MODES,
    PX4_MAIN_AUTO,
    PX4_MAIN_MODES,
    Autopilot,
    flavour,
    px4_custom_mode,
)

# MAVLink common.xml values (checked against pymavlink in tests/test_flight_monitor.py).
MAV_AUTOPILOT_ARDUPILOTMEGA = 3
MAV_AUTOPILOT_INVALID = 8
MAV_AUTOPILOT_PX4 = 12
MAV_MODE_FLAG_SAFETY_ARMED = 128
MAV_STATE_CRITICAL = 5
MAV_STATE_EMERGENCY = 6
MAV_STATE_FLIGHT_TERMINATION = 8
MAV_LANDED_STATE_ON_GROUND = 1
MAV_LANDED_STATE_IN_AIR = 2
MAV_BATTERY_CHARGE_STATE_CRITICAL = 3
MAV_BATTERY_CHARGE_STATE_EMERGENCY = 4
MAV_BATTERY_CHARGE_STATE_FAILED = 5
MAV_BATTERY_CHARGE_STATE_UNHEALTHY = 6

__all__ = [
    "ARDUCOPTER_MODES",
    "PX4_AUTO_SUB_MODES",
    "PX4_MAIN_AUTO",
    "PX4_MAIN_MODES",
    "REASONS",
    "MocapAge",
    "MonitorConfig",
    "VehicleMonitor",
    "Verdict",
    "mode_name",
    "px4_custom_mode",
]

#: Causes of leaving control, as reported in :attr:`Verdict.code`.
REASONS = ("link_lost", "mode_changed", "disarmed", "battery_critical", "autopilot_failsafe",
           "landed")


def mode_name(autopilot: str | Autopilot, custom_mode: int) -> str:
    """Human name of a HEARTBEAT custom_mode for ``autopilot`` (a flavour or its name,
    'ardupilot' or 'px4'), e.g. 'GUIDED_NOGPS', 'AUTO.LAND'; unknown numbers are spelled out."""
    return _flavour(autopilot).mode_name(custom_mode)


def _flavour(autopilot: str | Autopilot) -> Autopilot:
    """The flavour object of ``autopilot`` (ValueError, one line, for an unknown name)."""
    return flavour(autopilot) if isinstance(autopilot, str) else autopilot


@dataclass(frozen=True)
class MonitorConfig:
    """Bounds: HEARTBEAT timeout [s] (vehicles send about 1 Hz), battery remaining at or below
    which the battery is critical [%], optional critical pack voltage [V]."""

    heartbeat_timeout_s: float = 3.0
    battery_critical_pct: float = 15.0
    battery_critical_v: float | None = None

    def __post_init__(self) -> None:
        if not self.heartbeat_timeout_s > 0 or not 0 <= self.battery_critical_pct <= 100:
            raise ValueError("heartbeat_timeout_s must be > 0 and battery_critical_pct 0..100")


@dataclass(frozen=True)
class Verdict:
    """In control, or not: ``code`` one of :data:`REASONS` ('' while in control, 'idle'
    before engage), ``reason`` one human line, ``t`` [s] when it was detected."""

    in_control: bool
    code: str
    reason: str
    t: float


class VehicleMonitor:
    """Watches one vehicle (``target_system``/``target_component``) flown by us (``own_system``
    /``own_component``) in one of ``expected_modes`` (custom_mode numbers)."""

    def __init__(self, autopilot: str | Autopilot, expected_modes: Iterable[int],
                 target_system: int, target_component: int = 1, own_system: int = 1,
                 own_component: int = 191, config: MonitorConfig | None = None) -> None:
        self.flavour = _flavour(autopilot)
        if not 1 <= target_system <= 255:
            raise ValueError("target_system must be 1..255")
        self.autopilot = self.flavour.name
        self.expected = {self.flavour.mode_key(m) for m in expected_modes}
        if not self.expected:
            raise ValueError("expected_modes must not be empty")
        self.target = (target_system, target_component)
        self.own = (own_system, own_component)
        self.cfg = config or MonitorConfig()
        self.engaged_at: float | None = None
        self.last_heartbeat: float | None = None
        self.mode: int | None = None
        self.armed = False
        self.battery_pct: float | None = None
        self._airborne = False
        self._left: Verdict | None = None
        self._acks: dict[int, tuple[float, int]] = {}

    # -- lifecycle ------------------------------------------------------------------------
    def engage(self, t: float) -> None:
        """We are in control from time t [s] (armed and in an expected mode, confirmed)."""
        self.engaged_at, self._left, self._airborne = t, None, False

    def _is_ours(self, sysid: int | None, compid: int | None) -> bool:
        """A message from our vehicle (None: the caller already filtered)."""
        return (sysid is None or sysid == self.target[0]) and (
            compid is None or compid == self.target[1])

    def _leave(self, t: float, code: str, reason: str) -> None:
        """Latch the first cause while engaged."""
        if self.engaged_at is not None and self._left is None:
            self._left = Verdict(False, code, reason, t)

    # -- inputs -----------------------------------------------------------------------------
    def on_heartbeat(self, t: float, sysid: int, compid: int, base_mode: int, custom_mode: int,
                     system_status: int, autopilot: int) -> bool:
        """HEARTBEAT fields; returns whether it was our vehicle's (others are ignored)."""
        if not self._is_ours(sysid, compid) or autopilot == MAV_AUTOPILOT_INVALID:
            return False
        self.last_heartbeat, self.mode = t, custom_mode
        self.armed = bool(base_mode & MAV_MODE_FLAG_SAFETY_ARMED)
        if system_status in (MAV_STATE_CRITICAL, MAV_STATE_EMERGENCY,
                             MAV_STATE_FLIGHT_TERMINATION):
            self._leave(t, "autopilot_failsafe",
                        f"autopilot reports system_status {system_status} (failsafe) in "
                        f"{self.flavour.mode_name(custom_mode)}")
        if self.flavour.mode_key(custom_mode) not in self.expected:
            self._leave(t, "mode_changed",
                        f"mode changed to {self.flavour.mode_name(custom_mode)} "
                        f"({custom_mode}) by the pilot or a failsafe")
        if not self.armed:
            self._leave(t, "disarmed", "vehicle disarmed")
        return True

    def on_sys_status(self, t: float, battery_remaining_pct: float, voltage: float,
                      sysid: int | None = None, compid: int | None = None) -> None:
        """SYS_STATUS: battery remaining [%] (−1 unknown) and pack voltage [V] (≤ 0 unknown)."""
        if self._is_ours(sysid, compid):
            self._battery(t, battery_remaining_pct, voltage, "SYS_STATUS")

    def on_battery_status(self, t: float, battery_remaining_pct: float, charge_state: int = 0,
                          voltage: float = -1.0, sysid: int | None = None,
                          compid: int | None = None) -> None:
        """BATTERY_STATUS: remaining [%] (−1 unknown), MAV_BATTERY_CHARGE_STATE, voltage [V]."""
        if not self._is_ours(sysid, compid):
            return
        if charge_state in (MAV_BATTERY_CHARGE_STATE_CRITICAL, MAV_BATTERY_CHARGE_STATE_EMERGENCY,
                            MAV_BATTERY_CHARGE_STATE_FAILED, MAV_BATTERY_CHARGE_STATE_UNHEALTHY):
            self._leave(t, "battery_critical",
                        f"battery charge_state {charge_state} (critical or worse)")
        self._battery(t, battery_remaining_pct, voltage, "BATTERY_STATUS")

    def _battery(self, t: float, pct: float, voltage: float, source: str) -> None:
        if pct >= 0:
            self.battery_pct = pct
            if pct <= self.cfg.battery_critical_pct:
                self._leave(t, "battery_critical", f"battery at {pct:.0f} % ({source}), "
                            f"critical at {self.cfg.battery_critical_pct:.0f} %")
        v_min = self.cfg.battery_critical_v
        if v_min is not None and 0 < voltage <= v_min:
            self._leave(t, "battery_critical",
                        f"battery at {voltage:.2f} V ({source}), critical at {v_min:.2f} V")

    def on_extended_sys_state(self, t: float, landed_state: int, sysid: int | None = None,
                              compid: int | None = None) -> None:
        """EXTENDED_SYS_STATE landed_state (MAV_LANDED_STATE)."""
        if not self._is_ours(sysid, compid) or self.engaged_at is None:
            return
        if landed_state == MAV_LANDED_STATE_IN_AIR:
            self._airborne = True
        elif landed_state == MAV_LANDED_STATE_ON_GROUND and self._airborne:
            self._leave(t, "landed", "vehicle reports it has landed")

    def ack_matches(self, command: int, target_system: int, target_component: int,
                    expected_command: int | None = None) -> bool:
        """Is this COMMAND_ACK addressed to us (target 0 = unset, as in MAVLink 1 ACKs) and,
        if given, for ``expected_command``? ACKs to another system or component are not."""
        to_us = target_system in (0, self.own[0]) and target_component in (0, self.own[1])
        return to_us and (expected_command is None or command == expected_command)

    def on_command_ack(self, t: float, command: int, result: int, target_system: int,
                       target_component: int, sysid: int | None = None,
                       compid: int | None = None) -> bool:
        """COMMAND_ACK; kept (see :meth:`last_ack`) only if from our vehicle and to us."""
        if not self._is_ours(sysid, compid) or not self.ack_matches(
                command, target_system, target_component):
            return False
        self._acks[command] = (t, result)
        return True

    def last_ack(self, command: int, since: float = -float("inf")) -> int | None:
        """MAV_RESULT of the latest ACK for ``command`` received at or after ``since`` [s]."""
        got = self._acks.get(command)
        return got[1] if got is not None and got[0] >= since else None

    # -- verdict ------------------------------------------------------------------------------
    def check(self, t: float) -> Verdict:
        """The verdict at time t [s] (heartbeat timeout counted from the last HEARTBEAT, or
        from engage if none came since)."""
        if self.engaged_at is None:
            return Verdict(False, "idle", "not engaged yet", t)
        if self._left is None:
            ref = max(self.engaged_at, self.last_heartbeat or self.engaged_at)
            if t - ref > self.cfg.heartbeat_timeout_s:
                self._leave(t, "link_lost", f"no HEARTBEAT from system {self.target[0]} for "
                            f"{t - ref:.1f} s (limit {self.cfg.heartbeat_timeout_s:.1f} s)")
        return self._left or Verdict(True, "", "in control", t)


class MocapAge:
    """How old the latest mocap pose is, judged on the ground station's own time stamps.

    The ground station (the master) stamps each pose with its capture time and announces its
    mission clock on ``viscover/<m>/clock``: both are readings of one clock. The age of a pose
    stamped t is ``T − t`` [s mission], T the newest mission time heard from the master (a
    clock message's t, or a pose's stamp). The receiver's side enters nowhere: neither when the
    pose arrived nor the receiver's extrapolated clock. So a busy machine that delays delivery
    (late poses come with equally late clock messages) or a starved simulator whose physics
    time stood still (time dilation) does not age a pose, while a real gap does: the master's
    clock runs on and no newer pose of this drone comes (occluded, lost by the tracker, not
    published). The driver compares the age with ``mocap_stale_s`` (0.2 s mission by default).

    One gap has no stamp: the master falls silent altogether (its process, the router or the
    link is gone). After ``silence_s`` wall seconds [local monotonic, 0.5 s] without any
    message of the master, every pose counts as infinitely old.

    Thread-safe: :meth:`heard` is called from the transport's receive thread, :meth:`age` from
    the driver's stream thread. ``wall`` is the local monotonic clock [s] (a test passes a
    manual clock's ``now``).
    """

    def __init__(self, silence_s: float = 0.5, wall: Callable[[], float] = time.monotonic
                 ) -> None:
        if not silence_s > 0:
            raise ValueError("silence_s must be > 0")
        self.silence_s = silence_s
        self._wall = wall
        self._lock = threading.Lock()
        self.master_t = -math.inf  #: newest mission time heard from the master [s]
        self._heard_wall = -math.inf  #: when the master was last heard [s local monotonic]

    def heard(self, t: float) -> None:
        """A message of the master arrived, stamped t [s mission] (its clock or a pose)."""
        with self._lock:
            self.master_t = max(self.master_t, t)
            self._heard_wall = self._wall()

    def silent_for(self) -> float:
        """Wall seconds since the master was last heard (inf before the first message)."""
        with self._lock:
            return self._wall() - self._heard_wall

    def age(self, t_pose: float | None) -> float:
        """Age [s mission] of the pose stamped ``t_pose``: newest master time − stamp; inf
        without a pose or after ``silence_s`` wall seconds of silence of the master."""
        with self._lock:
            if t_pose is None or self._wall() - self._heard_wall > self.silence_s:
                return math.inf
            return max(0.0, self.master_t - t_pose)
