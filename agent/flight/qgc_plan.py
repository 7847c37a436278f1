"""A :class:`~agent.flight.refly.Route` as a QGroundControl ``.plan`` document (pure: builds the
JSON object, writes nothing).

Format (QGroundControl dev guide, "Plan File Format", and QGC's own writer, ``MissionItem::save``
and ``SimpleMissionItem``): ``{"fileType": "Plan", "version": 1, "groundStation", "mission",
"geoFence", "rallyPoints"}``; mission ``version`` 2 with ``firmwareType`` (MAV_AUTOPILOT),
``vehicleType`` (MAV_TYPE), ``cruiseSpeed``, ``hoverSpeed``, ``globalPlanAltitudeMode``,
``plannedHomePosition`` [lat, lon, AMSL alt] and ``items``; each item a ``SimpleItem`` with
``command``, ``frame``, ``params`` (7 numbers, ``null`` for NaN, as QGC writes them),
``autoContinue`` and ``doJumpId`` (numbered from 1); items with a position also carry
``AMSLAltAboveTerrain`` (null), ``Altitude`` and ``AltitudeMode`` (1: relative to home).
``geoFence`` version 2: polygons ``{"inclusion", "polygon": [[lat, lon], ...], "version": 1}``,
no circles; ``rallyPoints`` version 2, none. MAVSDK's ``mission_raw.import_qgroundcontrol_
mission`` needs all three top-level sections and these item fields.

Items, per drone: ``MAV_CMD_NAV_TAKEOFF`` above the launch point; per viewpoint
``MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW`` (pitch from the horizon, yaw absolute to north: flags
ROLL_LOCK | PITCH_LOCK | YAW_LOCK, the spec's "LOCK mode"; rates NaN = unset; all gimbals), then
``MAV_CMD_NAV_WAYPOINT`` at the camera position (hold time, acceptance radius, yaw = the
camera's compass heading), then ``MAV_CMD_IMAGE_START_CAPTURE`` for one image (QGC's "take
photo" item: camera 0 = all, interval 0, 1 image), then ``MAV_CMD_NAV_DELAY`` of
:data:`CAPTURE_WAIT` [s], or the camera's ``trigger_s`` if longer (the run's ``[camera]``:
the next image cannot come sooner): both autopilots go on with the next items as soon as the camera
command is out (PX4 re-emits it to the camera component, which exposes after a latency), so
without the delay the next gimbal item turns the camera and the vehicle leaves during the
exposure. A PX4 plan has ``MAV_CMD_DO_GIMBAL_MANAGER_CONFIGURE`` (−2, −2: the autopilot takes
primary control) right after the take-off: PX4's gimbal takes a mission's gimbal items, which
come from the autopilot itself, only from the primary control
(src/modules/gimbal/input_mavlink.cpp); ArduPilot's mission has no such item and needs none.
A PX4 plan then sets every camera to image mode (``MAV_CMD_SET_CAMERA_MODE``, 0, mode 0, as
QGroundControl's camera section writes it).
The gimbal item comes before its waypoint because mission DO items run when the preceding NAV
item completes: so the gimbal turns during the leg, and the image is taken when the hold at
the viewpoint is over. Transit waypoints
(climbs over the structure, the return) have yaw NaN (the autopilot's heading mode). Last,
``MAV_CMD_NAV_LAND`` at the launch point.

Altitudes: frame ``MAV_FRAME_GLOBAL_RELATIVE_ALT`` (3), metres above home, home being the
launch point on the ground (world z = 0) at the origin's altitude: fly from flat ground at the
origin's level, armed at the launch point. ArduCopter ignores a waypoint's yaw (its
WP_YAW_BEHAVIOR decides); the gimbal's earth-frame yaw then points the camera if it has a yaw
axis.
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Mapping, Sequence
from typing import Any, Final

import numpy as np

from agent.flight.flavours import FLAVOURS, flavour
from agent.flight.geodetic import Origin, enu_to_geodetic
from agent.flight.refly import Fence, Route

MAV_FRAME_GLOBAL: Final = 0
MAV_FRAME_MISSION: Final = 2
MAV_FRAME_GLOBAL_RELATIVE_ALT: Final = 3
MAV_CMD_NAV_WAYPOINT: Final = 16
MAV_CMD_NAV_LAND: Final = 21
MAV_CMD_NAV_TAKEOFF: Final = 22
MAV_CMD_NAV_DELAY: Final = 93
#: How long the vehicle stays after each image command [s] (MAV_CMD_NAV_DELAY): the camera
#: exposes after a latency, and the next viewpoint's gimbal item must not turn it before.
CAPTURE_WAIT: Final = 1.0
MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW: Final = 1000
MAV_CMD_DO_GIMBAL_MANAGER_CONFIGURE: Final = 1001
MAV_CMD_IMAGE_START_CAPTURE: Final = 2000
MAV_CMD_SET_CAMERA_MODE: Final = 530
CAMERA_MODE_IMAGE: Final = 0
GIMBAL_MANAGER_FLAGS_ROLL_LOCK: Final = 4
GIMBAL_MANAGER_FLAGS_PITCH_LOCK: Final = 8
GIMBAL_MANAGER_FLAGS_YAW_LOCK: Final = 16
#: Horizon-stabilised roll and pitch, yaw absolute to north.
GIMBAL_FLAGS: Final = (GIMBAL_MANAGER_FLAGS_ROLL_LOCK | GIMBAL_MANAGER_FLAGS_PITCH_LOCK
                       | GIMBAL_MANAGER_FLAGS_YAW_LOCK)


class _FirmwareTypes(Mapping[str, int]):
    """Flavour name → the plan's ``firmwareType`` (its MAV_AUTOPILOT), read from the registered
    flavours (:mod:`agent.flight.flavours`) whenever asked."""

    def __getitem__(self, name: str) -> int:
        return FLAVOURS[name].mav_autopilot

    def __iter__(self) -> Iterator[str]:
        return iter(FLAVOURS)

    def __len__(self) -> int:
        return len(FLAVOURS)


#: MAV_AUTOPILOT of the plan's ``firmwareType``, per flavour.
AUTOPILOTS: Final[Mapping[str, int]] = _FirmwareTypes()
MAV_TYPE_QUADROTOR: Final = 2
#: QGroundControl's AltMode: 1 = relative to home (MAV_FRAME_GLOBAL_RELATIVE_ALT).
ALTITUDE_MODE_RELATIVE: Final = 1
NAN: Final = math.nan


def _param(x: float) -> float | None:
    return None if math.isnan(x) else float(x)


def simple_item(command: int, frame: int, params: Sequence[float], jump_id: int,
                altitude: float | None = None) -> dict[str, Any]:
    """One ``SimpleItem``: 7 params (NaN written as null); ``altitude`` [m above home] adds
    QGC's altitude fields (items with a position)."""
    if len(params) != 7:
        raise ValueError(f"a mission item has 7 params, got {len(params)}")
    item: dict[str, Any] = {"type": "SimpleItem", "command": command, "frame": frame,
                            "params": [_param(p) for p in params], "autoContinue": True,
                            "doJumpId": jump_id}
    if altitude is not None:
        item.update(AMSLAltAboveTerrain=None, Altitude=float(altitude),
                    AltitudeMode=ALTITUDE_MODE_RELATIVE)
    return item


def to_geodetic(points: np.ndarray, origin: Origin) -> list[tuple[float, float, float]]:
    """(lat, lon [degrees], altitude above the origin's [m]) of points (n, 3) [m; world ENU]."""
    lat, lon, alt = enu_to_geodetic(np.asarray(points, dtype=np.float64), origin)
    return [(float(a), float(b), float(c) - origin.alt)
            for a, b, c in zip(np.atleast_1d(lat), np.atleast_1d(lon), np.atleast_1d(alt),
                               strict=True)]


def _polygon(corners: np.ndarray | None, inclusion: bool, origin: Origin
             ) -> list[dict[str, Any]]:
    if corners is None:
        return []
    pts = np.column_stack([corners, np.zeros(len(corners))])
    return [{"inclusion": inclusion, "version": 1,
             "polygon": [[lat, lon] for lat, lon, _ in to_geodetic(pts, origin)]}]


def signed_yaw(heading: float) -> float:
    """A compass heading [degrees, [0, 360)] as the gimbal's yaw in (−180, 180] (NaN stays)."""
    return heading - 360.0 if heading > 180.0 else heading


def viewpoint_holds(route: Route, hold: float, gimbal_rate: float | None) -> list[float]:
    """The hold [s] at each viewpoint of ``route``: ``hold``, or longer where the gimbal,
    turning at ``gimbal_rate`` [degrees/s] on both axes at once, needs longer to go from the
    previous viewpoint's pitch and yaw to this one's (None: ``hold`` everywhere). Before the
    first viewpoint the gimbal is level and its yaw unknown (the drone faces where it was put
    down): up to 180 degrees. A NaN heading leaves the yaw where it is. The leg flown while
    the gimbal turns is not counted (a bound, not an estimate)."""
    views = [w.viewpoint for w in route.waypoints if w.viewpoint is not None]
    if gimbal_rate is None:
        return [hold] * len(views)
    out, pitch, yaw = [], 0.0, math.nan
    for v in views:  # a loop over one drone's viewpoints, each depending on the previous
        d_pitch = abs(v.pitch - pitch)
        if math.isnan(v.heading):
            d_yaw = 0.0
        elif math.isnan(yaw):
            d_yaw = 180.0
        else:
            d_yaw = abs((v.heading - yaw + 180.0) % 360.0 - 180.0)
        out.append(max(hold, max(d_pitch, d_yaw) / gimbal_rate))
        pitch, yaw = v.pitch, yaw if math.isnan(v.heading) else v.heading
    return out


def mission_items(route: Route, origin: Origin, *, hold: float = 1.0,
                  accept_radius: float = 0.5, gimbal_control: bool = False,
                  gimbal_rate: float | None = None, capture_wait: float = CAPTURE_WAIT,
                  camera_mode: bool = False) -> list[dict[str, Any]]:
    """The mission's items (see the module docstring): at each viewpoint ``hold`` [s], or
    the gimbal's turn at ``gimbal_rate`` [degrees/s] if longer (:func:`viewpoint_holds`),
    ``accept_radius`` [m] for every waypoint, ``capture_wait`` [s] after each image;
    ``gimbal_control``: the autopilot takes the gimbal's primary control after the take-off
    (PX4); ``camera_mode``: MAV_CMD_SET_CAMERA_MODE (image) after the take-off."""
    items: list[dict[str, Any]] = []
    holds = iter(viewpoint_holds(route, hold, gimbal_rate))

    def add(command: int, frame: int, params: Sequence[float],
            altitude: float | None = None) -> None:
        items.append(simple_item(command, frame, params, len(items) + 1, altitude))

    top = route.launch + np.array([0.0, 0.0, route.takeoff_height])
    pts = np.array([top, *(w.position for w in route.waypoints), route.launch])
    geo = to_geodetic(pts, origin)
    lat, lon, alt = geo[0]
    add(MAV_CMD_NAV_TAKEOFF, MAV_FRAME_GLOBAL_RELATIVE_ALT, [0, 0, 0, NAN, lat, lon, alt], alt)
    if gimbal_control:  # -2, -2: "set itself in control"; secondary control unchanged
        add(MAV_CMD_DO_GIMBAL_MANAGER_CONFIGURE, MAV_FRAME_MISSION, [-2, -2, -1, -1, 0, 0, 0])
    if camera_mode:  # all cameras (0) to image mode, as QGroundControl's camera section does
        add(MAV_CMD_SET_CAMERA_MODE, MAV_FRAME_MISSION, [0, CAMERA_MODE_IMAGE, NAN, NAN, NAN,
                                                         NAN, NAN])
    for w, (lat, lon, alt) in zip(route.waypoints, geo[1:-1], strict=True):
        v = w.viewpoint
        if v is None:
            add(MAV_CMD_NAV_WAYPOINT, MAV_FRAME_GLOBAL_RELATIVE_ALT,
                [0, accept_radius, 0, NAN, lat, lon, alt], alt)
            continue
        add(MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW, MAV_FRAME_MISSION,
            [v.pitch, signed_yaw(v.heading), NAN, NAN, GIMBAL_FLAGS, 0, 0])
        add(MAV_CMD_NAV_WAYPOINT, MAV_FRAME_GLOBAL_RELATIVE_ALT,
            [next(holds), accept_radius, 0, v.heading, lat, lon, alt], alt)
        add(MAV_CMD_IMAGE_START_CAPTURE, MAV_FRAME_MISSION, [0, 0, 1, 0, NAN, NAN, NAN])
        add(MAV_CMD_NAV_DELAY, MAV_FRAME_MISSION, [capture_wait, -1, -1, -1, 0, 0, 0])
    lat, lon, alt = geo[-1]
    add(MAV_CMD_NAV_LAND, MAV_FRAME_GLOBAL_RELATIVE_ALT, [0, 0, 0, NAN, lat, lon, alt], alt)
    return items


def plan_document(route: Route, fence: Fence, origin: Origin, *, autopilot: str = "px4",
                  hold: float = 1.0, accept_radius: float = 0.5,
                  gimbal_rate: float | None = None, trigger_s: float = 0.0) -> dict[str, Any]:
    """The whole ``.plan`` JSON object of one drone's route and the shared fences
    (``gimbal_rate`` [degrees/s]: see :func:`viewpoint_holds`; ``trigger_s`` [s]: the
    camera's shortest interval between two images, the least wait after each image)."""
    fl = flavour(autopilot)  # ValueError (one line) for an unknown autopilot
    (lat, lon, alt), = to_geodetic(route.launch[None, :], origin)
    return {
        "fileType": "Plan",
        "version": 1,
        "groundStation": "viscover",
        "mission": {
            "version": 2,
            "firmwareType": fl.mav_autopilot,
            "vehicleType": MAV_TYPE_QUADROTOR,
            "cruiseSpeed": 15,
            "hoverSpeed": 5,
            "globalPlanAltitudeMode": ALTITUDE_MODE_RELATIVE,
            "plannedHomePosition": [lat, lon, origin.alt + alt],
            "items": mission_items(route, origin, hold=hold, accept_radius=accept_radius,
                                   gimbal_control=fl.mission_gimbal_configure,
                                   gimbal_rate=gimbal_rate,
                                   capture_wait=max(CAPTURE_WAIT, trigger_s),
                                   camera_mode=fl.mission_camera_mode),
        },
        "geoFence": {
            "version": 2,
            "polygons": (_polygon(fence.inclusion, True, origin)
                         + _polygon(fence.exclusion, False, origin)),
            "circles": [],
        },
        "rallyPoints": {"version": 2, "points": []},
    }
