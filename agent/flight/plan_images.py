"""QGroundControl ``.plan`` documents read back (pure: parsed JSON in, images out; the
writer is :mod:`agent.flight.qgc_plan`): the images a plan's items take, each a camera
position [m; world ENU] and optical axis, for ``viscover import-plan``.

Reading a plan (QGroundControl's "Plan File Format" and its ``MissionItem::load``: a
``SimpleItem`` is ``command``, ``frame`` and 7 ``params``, ``null`` meaning NaN), the items
are walked in order as the autopilot flies them:

* a navigation item with a position (``MAV_CMD_NAV_WAYPOINT`` 16, ``NAV_LOITER_*`` 17-19, 31,
  ``NAV_LAND`` 21, ``NAV_TAKEOFF`` 22) moves the vehicle to params 5-7 (latitude, longitude
  [degrees], altitude [m]) in its frame: ``MAV_FRAME_GLOBAL`` (0, 5) AMSL, or
  ``MAV_FRAME_GLOBAL_RELATIVE_ALT`` (3, 6) above home (the plan's ``plannedHomePosition``);
  a NaN latitude or longitude keeps the vehicle's; a waypoint's param 4 is the vehicle's
  heading [compass degrees] (NaN: the autopilot's, unknown here);
* ``MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW`` (1000) sets the camera's pitch (param 1 [degrees, up
  +], from the horizon) and yaw (param 2 [degrees]), absolute to north with the YAW_LOCK flag
  (param 5 & 16, what export-plan writes), else relative to the vehicle's heading; NaN leaves
  an angle as it was; ``MAV_CMD_DO_MOUNT_CONTROL`` (205, QGroundControl's older camera
  section) sets pitch (param 1) and yaw relative to the vehicle (param 3);
* ``MAV_CMD_IMAGE_START_CAPTURE`` (2000) and ``MAV_CMD_DO_DIGICAM_CONTROL`` (203 with param
  5 "shot" set) take one image where the vehicle is, along the camera's direction.

The camera starts level, its yaw unknown until set; an image of unknown direction is left
out with a warning. Complex items (surveys, structure scans) are refused.

Malformed documents raise ValueError with one line naming the item.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from agent.flight.geodetic import Origin, geodetic_to_enu

Array = NDArray[np.float64]

#: Navigation commands whose params 5-7 are the vehicle's position.
NAV_POSITION = frozenset({16, 17, 18, 19, 21, 22, 31})
MAV_CMD_NAV_WAYPOINT = 16
MAV_CMD_DO_DIGICAM_CONTROL = 203
MAV_CMD_DO_MOUNT_CONTROL = 205
MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW = 1000
MAV_CMD_IMAGE_START_CAPTURE = 2000
GIMBAL_MANAGER_FLAGS_YAW_LOCK = 16
#: Frames of params 5-7: AMSL altitude, altitude above home.
FRAMES_AMSL = frozenset({0, 5})
FRAMES_RELATIVE = frozenset({3, 6})


@dataclass(frozen=True)
class PlanImage:
    """One image a plan takes: the plan's ``name``, the image's number in it (from 1) and its
    item's index (from 1, as QGroundControl numbers them), the camera ``position`` (3,)
    [m; world ENU] and unit optical axis ``direction`` (3,) [world ENU]."""

    name: str
    number: int
    item: int
    position: Array
    direction: Array

    @property
    def label(self) -> str:
        """``A.plan#3`` (the plan's third image)."""
        return f"{self.name}#{self.number}"


@dataclass
class PlanImages:
    """What one plan file's items take (:func:`plan_images`) and what could not be counted."""

    name: str
    images: list[PlanImage] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)


def camera_direction(heading: float, pitch: float) -> Array:
    """Unit optical axis [world ENU] of a camera at compass ``heading`` [degrees, clockwise
    from north] and ``pitch`` [degrees, + up from the horizon]."""
    h, p = math.radians(heading), math.radians(pitch)
    return np.array([math.cos(p) * math.sin(h), math.cos(p) * math.cos(h), math.sin(p)])


def _params(item: Any, k: int) -> list[float]:
    """The 7 params of item ``k`` (null: NaN); ValueError naming the item otherwise."""
    raw = item.get("params")
    if not isinstance(raw, list) or len(raw) != 7:
        raise ValueError(f"item {k}: params must be a list of 7 numbers (null for none)")
    out = []
    for x in raw:
        if x is None:
            out.append(math.nan)
        elif isinstance(x, bool) or not isinstance(x, int | float):
            raise ValueError(f"item {k}: params must be numbers or null, got {x!r}")
        else:
            out.append(float(x))
    return out


def _int_field(item: Any, name: str, k: int) -> int:
    x = item.get(name)
    if isinstance(x, bool) or not isinstance(x, int | float) or x != int(x):
        raise ValueError(f"item {k}: {name} must be an integer, got {x!r}")
    return int(x)


def _home(mission: Any) -> tuple[float, float, float]:
    home = mission.get("plannedHomePosition")
    if not (isinstance(home, list) and len(home) == 3 and all(
            isinstance(x, int | float) and not isinstance(x, bool) and math.isfinite(x)
            for x in home)):
        raise ValueError("mission.plannedHomePosition must be [latitude, longitude, altitude]")
    return float(home[0]), float(home[1]), float(home[2])


def plan_images(doc: Any, origin: Origin, name: str) -> PlanImages:
    """The images a ``.plan`` document (parsed JSON) takes, walked as the module docstring
    says, with the world frame's origin at ``origin``; ValueError (one line) for a document
    that is not a plan or an item that cannot be read."""
    if not isinstance(doc, dict) or doc.get("fileType") != "Plan":
        raise ValueError('not a QGroundControl plan (no "fileType": "Plan")')
    mission = doc.get("mission")
    if not isinstance(mission, dict) or not isinstance(mission.get("items"), list):
        raise ValueError("mission.items: missing (a plan holds a mission with a list of items)")
    home = _home(mission)
    out = PlanImages(name)
    lat = lon = alt = math.nan  # AMSL [m]; unknown before the first positioned item
    heading = math.nan  # the vehicle's [compass degrees]
    pitch, yaw, yaw_absolute = 0.0, math.nan, True  # the camera's
    shots = 0
    for k, item in enumerate(mission["items"], start=1):  # a loop over items, in flight order
        if not isinstance(item, dict):
            raise ValueError(f"item {k}: not an object")
        if item.get("type") != "SimpleItem":
            raise ValueError(f"item {k}: type {item.get('type')!r} is not supported (only "
                             "SimpleItem: complex items such as surveys are not read)")
        command, frame = _int_field(item, "command", k), _int_field(item, "frame", k)
        p = _params(item, k)
        if command in NAV_POSITION:
            if frame not in FRAMES_AMSL | FRAMES_RELATIVE:
                raise ValueError(f"item {k}: frame {frame} is not supported (0 or 5: AMSL, 3 "
                                 "or 6: relative to home)")
            if math.isfinite(p[4]) and math.isfinite(p[5]):
                lat, lon = p[4], p[5]
            if math.isfinite(p[6]):
                alt = p[6] + (home[2] if frame in FRAMES_RELATIVE else 0.0)
            if command == MAV_CMD_NAV_WAYPOINT:
                heading = p[3] % 360.0 if math.isfinite(p[3]) else math.nan
        elif command == MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW:
            pitch = p[0] if math.isfinite(p[0]) else pitch
            if math.isfinite(p[1]):
                flags = int(p[4]) if math.isfinite(p[4]) else 0
                yaw, yaw_absolute = p[1], bool(flags & GIMBAL_MANAGER_FLAGS_YAW_LOCK)
        elif command == MAV_CMD_DO_MOUNT_CONTROL:
            pitch = p[0] if math.isfinite(p[0]) else pitch
            yaw, yaw_absolute = (p[2], False) if math.isfinite(p[2]) else (yaw, yaw_absolute)
        elif command in (MAV_CMD_IMAGE_START_CAPTURE, MAV_CMD_DO_DIGICAM_CONTROL):
            if command == MAV_CMD_DO_DIGICAM_CONTROL and not (math.isfinite(p[4]) and p[4]):
                continue  # no shot
            shots += 1
            number = shots
            where = f"{name}: image {number} (item {k})"
            if math.isnan(lat) or math.isnan(alt):
                out.warnings.append(f"{where}: taken before any position: not counted")
                continue
            compass = yaw if yaw_absolute else heading + yaw
            if math.isnan(compass):
                out.warnings.append(f"{where}: the camera's heading is unknown (gimbal yaw "
                                    "relative to a vehicle heading the plan leaves to the "
                                    "autopilot): not counted")
                continue
            pos = geodetic_to_enu(lat, lon, alt, origin)
            out.images.append(PlanImage(name, number, k, np.asarray(pos, dtype=np.float64),
                                        camera_direction(compass, pitch)))
    return out
