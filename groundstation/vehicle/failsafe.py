"""Failsafe actions of the simulated autopilot, shared by the fence and the battery monitors.

ArduCopter (ArduCopter/events.cpp ``do_failsafe_action``, ArduCopter/fence.cpp
``fence_check``): a failsafe on the ground disarms (``should_disarm_on_failsafe``:
land_complete); in the air the action switches mode at once, falling back as the source
does: RTL → LAND when RTL is refused (it needs a position), BRAKE → LAND, SmartRTL (not
simulated) → RTL → LAND or → LAND; "terminate" disarms (motors stop).

PX4 (commander failsafe framework, src/modules/commander/failsafe): the action follows a
hold of COM_FAIL_ACT_T [s] in AUTO.LOITER ("Hold") unless the action is itself Hold, a
warning or a termination (a mode change during the hold cancels it: "the user can switch
modes", commander_params.c); Return or Hold without a position estimate fall back to Land.
Actions are the flavour-neutral words ``warn``, ``hold``, ``brake``, ``land``, ``rtl``,
``terminate``; each is recorded as an event ``failsafe_<reason>_<action>``.
"""

from __future__ import annotations

from typing import Any

from agent.wire.mavlink import ARDUPILOT_MODES as APM
from agent.wire.mavlink import mavlink as mav
from groundstation.vehicle.modes import P_LAND, P_LOITER, P_RTL

ACTIONS = ("warn", "hold", "brake", "land", "rtl", "terminate")


def statustext(ap: Any, severity: int, text: str) -> None:
    """STATUSTEXT from the autopilot (at most 50 characters, as the field holds)."""
    ap.mav.statustext_send(severity, text.encode()[:50])


def act(ap: Any, action: str, t: float, reason: str) -> None:
    """Take failsafe ``action`` for ``reason`` now (ArduPilot) or after the PX4 hold delay."""
    if action not in ACTIONS:
        raise ValueError(f"unknown failsafe action {action!r}")
    ap.event(t, f"failsafe_{reason}_{action}")
    if action == "warn" or not ap.armed:
        return
    if not ap.px4:
        if ap.landed:
            _disarm(ap, t)
        elif action == "terminate":
            _disarm(ap, t)
        else:
            _ardupilot_mode(ap, action, t)
        return
    delay = float(ap.params_table.get("COM_FAIL_ACT_T", 0.0))
    if action in ("hold", "brake", "terminate") or delay <= 0:
        run_px4(ap, action, t)
        return
    _px4_switch(ap, P_LOITER, t)
    ap.failsafe_pending = (t + delay, action)


def run_px4(ap: Any, action: str, t: float) -> None:
    """PX4's failsafe action (after its hold delay): hold, land, rtl, terminate."""
    ap.failsafe_pending = None
    if action == "terminate":
        _disarm(ap, t)
    elif action in ("hold", "brake"):
        _px4_switch(ap, P_LOITER, t)
    elif action == "rtl":
        _px4_switch(ap, P_RTL, t)
    else:
        _px4_switch(ap, P_LAND, t)


def due(ap: Any, t: float) -> None:
    """Run a PX4 failsafe action whose hold delay is over; a mode change away from the Hold
    during the delay (the user's, COM_FAIL_ACT_T's purpose) or a disarm cancels it."""
    pending = getattr(ap, "failsafe_pending", None)
    if pending is None:
        return
    if ap.mode != P_LOITER or not ap.armed:
        ap.failsafe_pending = None
        ap.event(t, "failsafe_cancelled")
    elif t >= pending[0]:
        run_px4(ap, pending[1], t)


def _ardupilot_mode(ap: Any, action: str, t: float) -> None:
    first = {"hold": APM["BRAKE"], "brake": APM["BRAKE"], "rtl": APM["RTL"],
             "land": APM["LAND"]}[action]
    if ap.mode == first or ap._switch(first, t) == mav.MAV_RESULT_ACCEPTED:
        return
    ap._switch(APM["LAND"], t)


def _px4_switch(ap: Any, mode: int, t: float) -> None:
    if ap.mode == mode:
        return
    if ap._switch(mode, t) != mav.MAV_RESULT_ACCEPTED and mode != P_LAND:
        ap._switch(P_LAND, t)


def _disarm(ap: Any, t: float) -> None:
    if ap.armed:
        ap.armed = False
        ap.event(t, "disarmed")
