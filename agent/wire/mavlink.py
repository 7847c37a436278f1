"""The MAVLink side of the wire contract: pymavlink loaded for MAVLink 2, and the autopilot
constants both our driver and our simulated vehicle speak.

``MAVLINK20=1`` must be set before pymavlink loads its dialect: import ``mavutil`` and
``mavlink`` from here, never from pymavlink directly.

Mode numbers are the autopilots' own: ArduCopter's ``custom_mode`` values
(ArduCopter/mode.h), PX4's main/sub modes packed into ``custom_mode``
(px4_custom_mode.h: main mode in bits 16-23, sub mode in bits 24-31).
"""

from __future__ import annotations

import os
from typing import Final

os.environ["MAVLINK20"] = "1"

from pymavlink import mavutil

if mavutil.mavlink.WIRE_PROTOCOL_VERSION != "2.0":  # imported earlier without MAVLINK20
    mavutil.set_dialect("ardupilotmega")

mavlink = mavutil.mavlink

#: ArduCopter flight modes (``custom_mode``).
ARDUPILOT_MODES: Final = {"STABILIZE": 0, "ALT_HOLD": 2, "GUIDED": 4, "LOITER": 5, "RTL": 6,
                          "LAND": 9, "BRAKE": 17, "GUIDED_NOGPS": 20}
ARDUPILOT_GUIDED_NOGPS: Final = 20
ARDUPILOT_LAND: Final = 9

#: PX4 main modes and sub modes (``px4_custom_mode.h``).
PX4_MAIN_MANUAL: Final = 1
PX4_MAIN_ALTCTL: Final = 2
PX4_MAIN_POSCTL: Final = 3
PX4_MAIN_AUTO: Final = 4
PX4_MAIN_OFFBOARD: Final = 6
PX4_MAIN_STABILIZED: Final = 7
PX4_SUB_AUTO_TAKEOFF: Final = 2
PX4_SUB_AUTO_LOITER: Final = 3
PX4_SUB_AUTO_RTL: Final = 5
PX4_SUB_AUTO_LAND: Final = 6
PX4_OFFBOARD: Final = (PX4_MAIN_OFFBOARD, 0)
PX4_AUTO_LAND: Final = (PX4_MAIN_AUTO, PX4_SUB_AUTO_LAND)

#: ArduCopter GUID_OPTIONS bit 3: SET_ATTITUDE_TARGET thrust is thrust, not a climb rate.
GUID_OPTIONS_REAL_THRUST: Final = 8

#: MAV_CMD_COMPONENT_ARM_DISARM param2 that forces a disarm in flight.
FORCE_DISARM_MAGIC: Final = 21196


def px4_custom_mode(main: int, sub: int = 0) -> int:
    """PX4 HEARTBEAT ``custom_mode`` of (main, sub): main in bits 16-23, sub in bits 24-31."""
    return (main << 16) | (sub << 24)


__all__ = [
    "ARDUPILOT_GUIDED_NOGPS",
    "ARDUPILOT_LAND",
    "ARDUPILOT_MODES",
    "FORCE_DISARM_MAGIC",
    "GUID_OPTIONS_REAL_THRUST",
    "PX4_AUTO_LAND",
    "PX4_MAIN_ALTCTL",
    "PX4_MAIN_AUTO",
    "PX4_MAIN_MANUAL",
    "PX4_MAIN_OFFBOARD",
    "PX4_MAIN_POSCTL",
    "PX4_MAIN_STABILIZED",
    "PX4_OFFBOARD",
    "PX4_SUB_AUTO_LAND",
    "PX4_SUB_AUTO_LOITER",
    "PX4_SUB_AUTO_RTL",
    "PX4_SUB_AUTO_TAKEOFF",
    "mavlink",
    "mavutil",
    "px4_custom_mode",
]
