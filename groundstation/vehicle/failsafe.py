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

from agent.wire.mavlink import mavlink as mav

ACTIONS = ("warn", "hold", "brake", "land", "rtl", "terminate")


def statustext(ap: Any, severity: int, text: str) -> None:
    """STATUSTEXT from the autopilot (at most 50 characters, as the field holds)."""
    ap.mav.statustext_send(severity, text.encode()[:50])


def act(ap: Any, action: str, t: float, reason: str) -> None:
    """Take failsafe ``action`` for ``reason``: as the vehicle's flavour does it
    (:func:`at_once` for ArduCopter, :func:`after_hold` for PX4)."""
    if action not in ACTIONS:
        raise ValueError(f"unknown failsafe action {action!r}")
    ap.event(t, f"failsafe_{reason}_{action}")
    if action == "warn" or not ap.armed:
        return
    ap.flavour.failsafe(ap, action, t)


def at_once(ap: Any, action: str, t: float) -> None:
    """ArduCopter's action: disarm on the ground or to terminate, else the mode at once
    (Hold and Brake: BRAKE), Land when that is refused."""
    fl = ap.flavour
    if ap.landed or action == "terminate":
        _disarm(ap, t)
        return
    switch_or_land(ap, {"hold": fl.hold_mode, "brake": fl.hold_mode, "rtl": fl.rtl_mode,
                        "land": fl.land_mode}[action], t)


def after_hold(ap: Any, action: str, t: float) -> None:
    """PX4's action: Hold for COM_FAIL_ACT_T first unless it is Hold, Brake or Terminate
    (:func:`due` then runs it)."""
    delay = float(ap.params_table.get("COM_FAIL_ACT_T", 0.0))
    if action in ("hold", "brake", "terminate") or delay <= 0:
        run(ap, action, t)
        return
    switch_or_land(ap, ap.flavour.hold_mode, t)
    ap.failsafe_pending = (t + delay, action)


def run(ap: Any, action: str, t: float) -> None:
    """A delayed failsafe action itself: hold, land, rtl, terminate."""
    ap.failsafe_pending = None
    fl = ap.flavour
    if action == "terminate":
        _disarm(ap, t)
    elif action in ("hold", "brake"):
        switch_or_land(ap, fl.hold_mode, t)
    elif action == "rtl":
        switch_or_land(ap, fl.rtl_mode, t)
    else:
        switch_or_land(ap, fl.land_mode, t)


def due(ap: Any, t: float) -> None:
    """Run a delayed failsafe action whose hold is over; a mode change away from the Hold
    during the delay (the user's, COM_FAIL_ACT_T's purpose) or a disarm cancels it."""
    pending = getattr(ap, "failsafe_pending", None)
    if pending is None:
        return
    if ap.mode != ap.flavour.hold_mode or not ap.armed:
        ap.failsafe_pending = None
        ap.event(t, "failsafe_cancelled")
    elif t >= pending[0]:
        run(ap, pending[1], t)


def switch_or_land(ap: Any, mode: int, t: float) -> None:
    """Switch to ``mode`` unless in it already; Land when it is refused (it needs a position)."""
    if ap.mode == mode:
        return
    land = ap.flavour.land_mode
    if ap._switch(mode, t) != mav.MAV_RESULT_ACCEPTED and mode != land:
        ap._switch(land, t)


def _disarm(ap: Any, t: float) -> None:
    if ap.armed:
        ap.armed = False
        ap.event(t, "disarmed")
