"""pymavlink, loaded for MAVLink 2 (``MAVLINK20=1`` must be set before the dialect loads).

Import ``mavutil`` and ``mavlink`` from here rather than from pymavlink directly.
"""

from __future__ import annotations

import os

os.environ["MAVLINK20"] = "1"

from pymavlink import mavutil

if mavutil.mavlink.WIRE_PROTOCOL_VERSION != "2.0":  # imported earlier without MAVLINK20
    mavutil.set_dialect("ardupilotmega")

mavlink = mavutil.mavlink

__all__ = ["mavlink", "mavutil"]
