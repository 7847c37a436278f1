"""WGS-84 geodesy: the mission's world frame (ENU [m], origin at a geodetic point) to and from
latitude, longitude and ellipsoidal height, through Earth-centred Earth-fixed coordinates (pure
numpy; no I/O).

Conventions: latitude and longitude in degrees (north and east positive), heights in metres
above the WGS-84 ellipsoid. Altitudes that an autopilot calls AMSL differ from ellipsoidal
heights by the geoid undulation (tens of metres), but that offset is the same for every point of
a mission site (it varies over kilometres), so a plan whose altitudes are all taken relative to
the origin's altitude is unaffected: give the origin's altitude in whichever datum the vehicles
use and every derived altitude is in that datum.

The world frame is the local tangent plane at the origin: x east, y north, z up along the
ellipsoid normal. Its "north" is true north at the origin only; 100 m east of it the meridians
have turned by 100 / R · sin(lat) rad (under 0.001° at 45°).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

Array = NDArray[np.float64]

#: WGS-84 semi-major axis [m] and flattening (NIMA TR8350.2).
WGS84_A = 6378137.0
WGS84_F = 1.0 / 298.257223563
#: First eccentricity squared e² = f (2 − f).
WGS84_E2 = WGS84_F * (2.0 - WGS84_F)


@dataclass(frozen=True)
class Origin:
    """The geodetic point of the world frame's origin: latitude, longitude [degrees], altitude
    [m] (ellipsoidal, or AMSL: see the module docstring)."""

    lat: float
    lon: float
    alt: float

    def __post_init__(self) -> None:
        if not all(math.isfinite(v) for v in (self.lat, self.lon, self.alt)):
            raise ValueError("origin: latitude, longitude and altitude must be finite numbers")
        if not -90.0 <= self.lat <= 90.0:
            raise ValueError(f"origin: latitude {self.lat} is not in [-90, 90] degrees")
        if not -180.0 <= self.lon <= 180.0:
            raise ValueError(f"origin: longitude {self.lon} is not in [-180, 180] degrees")


def geodetic_to_ecef(lat: ArrayLike, lon: ArrayLike, h: ArrayLike) -> Array:
    """ECEF position(s) (..., 3) [m] of latitude, longitude [degrees] and height [m]:
    (N + h) cos φ cos λ, (N + h) cos φ sin λ, (N (1 − e²) + h) sin φ, N = a / √(1 − e² sin² φ)."""
    phi = np.radians(np.asarray(lat, dtype=np.float64))
    lam = np.radians(np.asarray(lon, dtype=np.float64))
    hh = np.asarray(h, dtype=np.float64)
    sp, cp = np.sin(phi), np.cos(phi)
    n = WGS84_A / np.sqrt(1.0 - WGS84_E2 * sp * sp)
    return np.stack([(n + hh) * cp * np.cos(lam), (n + hh) * cp * np.sin(lam),
                     (n * (1.0 - WGS84_E2) + hh) * sp], axis=-1)


def ecef_to_geodetic(xyz: ArrayLike, iterations: int = 8) -> tuple[Array, Array, Array]:
    """Latitude, longitude [degrees] and height [m] of ECEF position(s) (..., 3) [m].

    Fixed-point iteration on the latitude, φ ← atan2(z + e² N(φ) sin φ, p) with p = √(x² + y²),
    started from the spherical guess; the height is p cos φ + z sin φ − a √(1 − e² sin² φ),
    which holds at the poles too. Each step gains about three decimal digits near the
    surface, so a few steps reach float64 (the default 8 are more than enough below 10⁴ km)."""
    a = np.asarray(xyz, dtype=np.float64)
    x, y, z = a[..., 0], a[..., 1], a[..., 2]
    p = np.hypot(x, y)
    lam = np.arctan2(y, x)
    phi = np.arctan2(z, p * (1.0 - WGS84_E2))
    for _ in range(iterations):
        sp = np.sin(phi)
        n = WGS84_A / np.sqrt(1.0 - WGS84_E2 * sp * sp)
        phi = np.arctan2(z + WGS84_E2 * n * sp, p)
    sp, cp = np.sin(phi), np.cos(phi)
    h = p * cp + z * sp - WGS84_A * np.sqrt(1.0 - WGS84_E2 * sp * sp)
    return np.degrees(phi), np.degrees(lam), h


def enu_rotation(origin: Origin) -> Array:
    """R (3, 3) whose columns are the origin's east, north and up unit vectors in ECEF, so that
    an ENU offset e maps to the ECEF offset R e (and back with Rᵀ)."""
    phi, lam = math.radians(origin.lat), math.radians(origin.lon)
    sp, cp, sl, cl = math.sin(phi), math.cos(phi), math.sin(lam), math.cos(lam)
    return np.array([[-sl, -sp * cl, cp * cl],
                     [cl, -sp * sl, cp * sl],
                     [0.0, cp, sp]])


def enu_to_geodetic(enu: ArrayLike, origin: Origin) -> tuple[Array, Array, Array]:
    """Latitude, longitude [degrees] and altitude [m] of world point(s) (..., 3) [m; world ENU],
    the world frame's origin being at ``origin`` (its altitude the datum of the result)."""
    e = np.asarray(enu, dtype=np.float64)
    o = geodetic_to_ecef(origin.lat, origin.lon, origin.alt)
    return ecef_to_geodetic(o + e @ enu_rotation(origin).T)


def geodetic_to_enu(lat: ArrayLike, lon: ArrayLike, alt: ArrayLike, origin: Origin) -> Array:
    """World point(s) (..., 3) [m; world ENU] of latitude, longitude [degrees] and altitude [m]
    (the inverse of :func:`enu_to_geodetic`)."""
    d = geodetic_to_ecef(lat, lon, alt) - geodetic_to_ecef(origin.lat, origin.lon, origin.alt)
    return np.asarray(d @ enu_rotation(origin), dtype=np.float64)


def compass_heading(east: float, north: float) -> float:
    """Compass heading [degrees in [0, 360): from north, clockwise] of a horizontal direction
    given by its east and north components (ENU); NaN for the zero vector."""
    if math.hypot(east, north) < 1e-9:
        return math.nan
    heading = math.degrees(math.atan2(east, north)) % 360.0
    return 0.0 if heading >= 360.0 else heading  # −1e-17 % 360 rounds up to 360


@dataclass(frozen=True)
class LocalToWorld:
    """The exact map from a local ENU frame anchored at geodetic point ``local`` (e.g. the
    autopilot's EKF origin, GPS_GLOBAL_ORIGIN) to the mission's world ENU frame anchored at
    ``world`` (the scenario's origin, shared by all drones): p_world = R p_local + t [m],
    with R = R_worldᵀ R_local (both ENU rotations into ECEF) and t the local origin's world
    position. Both frames are tangent planes, so the map is a rigid motion (exact, no small-
    distance approximation); R differs from the identity by the meridians' convergence
    (about 1.6e-4 rad per km east at 45°)."""

    local: Origin
    world: Origin
    rotation: Array
    offset: Array

    @classmethod
    def between(cls, local: Origin, world: Origin | None) -> LocalToWorld:
        """The map from ``local`` to ``world`` (``world`` None: the identity, the world
        frame is the local one)."""
        if world is None:
            return cls(local, local, np.eye(3), np.zeros(3))
        rot = enu_rotation(world).T @ enu_rotation(local)
        off = geodetic_to_enu(local.lat, local.lon, local.alt, world)
        return cls(local, world, rot, np.asarray(off, dtype=np.float64))

    @property
    def distance_m(self) -> float:
        """How far the local origin is from the world origin [m]."""
        return float(np.linalg.norm(self.offset))

    def point(self, p_local: ArrayLike) -> Array:
        """World position(s) (..., 3) [m; world ENU] of local ENU position(s) [m]."""
        return np.asarray(np.asarray(p_local, dtype=np.float64) @ self.rotation.T + self.offset,
                          dtype=np.float64)

    def vector(self, v_local: ArrayLike) -> Array:
        """World vector(s) (..., 3) [world ENU] of local ENU vector(s) (velocities)."""
        return np.asarray(np.asarray(v_local, dtype=np.float64) @ self.rotation.T,
                          dtype=np.float64)
