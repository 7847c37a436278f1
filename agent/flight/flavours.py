"""Autopilot flavours, as the flight code sees them: one object per autopilot behind one
:class:`Autopilot` protocol, so the rest of the flight side never branches on the autopilot's
name.

A flavour knows its flight modes (HEARTBEAT ``custom_mode`` numbers and names), how to put
the vehicle under our control (``engage``: the steps before arming), how to land it, how its
parameters travel (PARAM_VALUE encoding), which parameters the pre-flight rules and the fence
need, and how it reports a fence breach.

The flavours and their registry live one layer down, in :mod:`agent.wire.mavlink` (the
flight settings name the known flavours too, and :mod:`agent.config` may not import
:mod:`agent.flight`); this module is their name on the flight side. The contract, where each
flavour lives and how to add one: ``docs/autopilots.md``.
"""

from __future__ import annotations

from agent.wire.mavlink import (
    ARDUCOPTER_MODES,
    FLAVOURS,
    PX4,
    PX4_AUTO_SUB_MODES,
    PX4_MAIN_AUTO,
    PX4_MAIN_MODES,
    ArduPilot,
    Autopilot,
    EngageSteps,
    Modes,
    flavour,
    flavour_names,
    flavour_of_heartbeat,
    px4_custom_mode,
    register,
    unregister,
)

__all__ = ["ARDUCOPTER_MODES", "FLAVOURS", "PX4", "PX4_AUTO_SUB_MODES", "PX4_MAIN_AUTO",
           "PX4_MAIN_MODES", "ArduPilot", "Autopilot", "EngageSteps", "Modes", "flavour",
           "flavour_names", "flavour_of_heartbeat", "px4_custom_mode", "register",
           "unregister"]
