"""Where the simulated vehicle is on the Earth, and how its attitude is reported.

The vehicle's local frame (NED, metres, the motion-capture frame turned to NED) has its origin
at the EKF origin, a fixed geodetic point per vehicle: ``VehicleParams.origin`` or, by
default, the flavour's SITL start location (:data:`ORIGIN`). Both autopilots report global
positions as that origin offset by the local position, the way ArduPilot's
``Location::offset`` does it (flat earth, radius 6378100 m, libraries/AP_Common/Location.cpp):
GLOBAL_POSITION_INT and HOME_POSITION therefore agree with LOCAL_POSITION_NED to the
centimetre at the scales of a flight arena.

Units on the wire (common.xml; ArduPilot ``GCS_MAVLINK::send_global_position_int``, PX4
``MavlinkStreamGlobalPositionInt``): lat/lon degE7, alt mm AMSL, relative_alt mm above home,
vx/vy/vz cm/s NED, hdg cdeg 0..35999.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

Array = NDArray[np.float64]

#: The SITL default start locations: ArduPilot's CMAC (Tools/autotest/locations.txt) and PX4's
#: PX4_HOME_LAT / _LON / _ALT (Zurich): latitude, longitude [deg], altitude [m AMSL].
ORIGIN: dict[str, tuple[float, float, float]] = {
    "ardupilot": (-35.363261, 149.165230, 584.0),
    "px4": (47.397742, 8.545594, 488.0),
}
#: ArduPilot's RADIUS_OF_EARTH [m] (libraries/AP_Math/definitions.h).
EARTH_RADIUS = 6378100.0
_DEG_PER_M = 180.0 / (math.pi * EARTH_RADIUS)


def geodetic(origin: tuple[float, float, float], p_ned: Array) -> tuple[int, int, int]:
    """(lat degE7, lon degE7, alt mm AMSL) of the local NED point ``p_ned`` [m]."""
    lat0, lon0, alt0 = origin
    lat = lat0 + float(p_ned[0]) * _DEG_PER_M
    lon = lon0 + float(p_ned[1]) * _DEG_PER_M / math.cos(math.radians(lat0))
    return round(lat * 1e7), round(lon * 1e7), round((alt0 - float(p_ned[2])) * 1000.0)


def heading_cdeg(yaw: float) -> int:
    """GLOBAL_POSITION_INT.hdg: yaw [rad; NED] as centidegrees 0..35999."""
    return round(math.degrees(yaw % (2.0 * math.pi)) * 100.0) % 36000


def body_rates(att: Array, euler_rates: Array) -> tuple[float, float, float]:
    """Body angular rates (p, q, r) [rad/s; FRD] from roll, pitch [rad] and the Euler angle
    rates [rad/s] (what ATTITUDE_QUATERNION's roll/pitch/yawspeed carry: the gyro)."""
    roll, pitch = float(att[0]), float(att[1])
    dr, dp, dy = (float(a) for a in euler_rates)
    sr, cr, sp, cp = math.sin(roll), math.cos(roll), math.sin(pitch), math.cos(pitch)
    return dr - dy * sp, dp * cr + dy * sr * cp, -dp * sr + dy * cr * cp


def local_ne(origin: tuple[float, float, float], lat_e7: int, lon_e7: int) -> Array:
    """The local (north, east) [m] of a point lat/lon [degE7]: :func:`geodetic`'s inverse
    (flat earth from ``origin``, ArduPilot's ``Location::get_distance_NE``)."""
    lat0, lon0, _ = origin
    north = (lat_e7 * 1e-7 - lat0) / _DEG_PER_M
    east = (lon_e7 * 1e-7 - lon0) * math.cos(math.radians(lat0)) / _DEG_PER_M
    return np.array([north, east])


def utc_us(t: float) -> int:
    """UTC [µs] at simulation time t [s]: SIM_EPOCH_UTC + t (deterministic, no wall clock)."""
    return round((SIM_EPOCH_UTC + max(t, 0.0)) * 1e6)


#: UTC [s] of simulation time 0 (2026-01-01T00:00:00Z): what the simulated GNSS reports.
SIM_EPOCH_UTC = 1767225600.0
