"""viscover's view of a mission as ROS 2 messages (pure functions; rosbags' message classes).

Every message is stamped with a wall time [ns since the Unix epoch]: when the bridge received
what it converts (ROS tools compare stamps with their own clock: rviz keeps transforms by
stamp). Positions are [m; world ENU], orientations (x, y, z, w) R_parent←child
(:mod:`groundstation.ros2.frames`), colours RGBA in [0, 1].

* :func:`pose_stamped`: a pose in the world frame.
* :func:`tf_message`: a list of (parent, child, translation, rotation) transforms.
* :func:`landmark_marker`: landmarks as one SPHERE_LIST, a colour per point.
* :func:`frustum_markers`: per drone a LINE_LIST (the camera pyramid) and a TEXT_VIEW_FACING
  label, in the drone's colour (``ns`` ``frustum`` and ``label``, ``id`` the drone's row).
* :func:`diagnostics`: ``viscover status`` as a DiagnosticArray.
* :func:`log_of`: a mission event as an ``rcl_interfaces/Log`` line (``name`` viscover.<source>,
  ``function`` the event's kind).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any, Final, cast

import numpy as np
from numpy.typing import NDArray
from rosbags.typesys.stores.ros2_jazzy import (
    builtin_interfaces__msg__Duration as Duration,
)
from rosbags.typesys.stores.ros2_jazzy import (
    builtin_interfaces__msg__Time as Time,
)
from rosbags.typesys.stores.ros2_jazzy import (
    diagnostic_msgs__msg__DiagnosticArray as DiagnosticArray,
)
from rosbags.typesys.stores.ros2_jazzy import (
    diagnostic_msgs__msg__DiagnosticStatus as DiagnosticStatus,
)
from rosbags.typesys.stores.ros2_jazzy import (
    diagnostic_msgs__msg__KeyValue as KeyValue,
)
from rosbags.typesys.stores.ros2_jazzy import geometry_msgs__msg__Point as Point
from rosbags.typesys.stores.ros2_jazzy import geometry_msgs__msg__Pose as Pose
from rosbags.typesys.stores.ros2_jazzy import geometry_msgs__msg__PoseStamped as PoseStamped
from rosbags.typesys.stores.ros2_jazzy import geometry_msgs__msg__Quaternion as Quaternion
from rosbags.typesys.stores.ros2_jazzy import geometry_msgs__msg__Transform as Transform
from rosbags.typesys.stores.ros2_jazzy import (
    geometry_msgs__msg__TransformStamped as TransformStamped,
)
from rosbags.typesys.stores.ros2_jazzy import geometry_msgs__msg__Vector3 as Vector3
from rosbags.typesys.stores.ros2_jazzy import rcl_interfaces__msg__Log as Log
from rosbags.typesys.stores.ros2_jazzy import (
    sensor_msgs__msg__CompressedImage as CompressedImage,
)
from rosbags.typesys.stores.ros2_jazzy import std_msgs__msg__ColorRGBA as ColorRGBA
from rosbags.typesys.stores.ros2_jazzy import std_msgs__msg__Header as Header
from rosbags.typesys.stores.ros2_jazzy import tf2_msgs__msg__TFMessage as TFMessage
from rosbags.typesys.stores.ros2_jazzy import visualization_msgs__msg__Marker as Marker
from rosbags.typesys.stores.ros2_jazzy import (
    visualization_msgs__msg__MarkerArray as MarkerArray,
)
from rosbags.typesys.stores.ros2_jazzy import visualization_msgs__msg__MeshFile as MeshFile

from agent.mission.watch import DroneRow, MissionView
from agent.storage.events import MissionEvent
from agent.storage.recording import PALETTE
from groundstation.ros2 import frames
from groundstation.ros2.frames import Quat
from groundstation.ros2.names import drone_token

RGBA = tuple[float, float, float, float]
#: colours of an inspection's capture states: pending (orange), captured (green)
PENDING_RGBA: Final = (1.0, 0.498, 0.055, 1.0)
CAPTURED_RGBA: Final = (0.173, 0.627, 0.173, 1.0)
#: a landmark nobody owns (grey, as in the recording)
UNOWNED_RGBA: Final = (0.75, 0.75, 0.75, 1.0)
#: rcl_interfaces/Log levels of the events' levels
LOG_LEVELS: Final = {"info": Log.INFO, "warning": Log.WARN, "error": Log.ERROR}
_EMPTY_U8: Final = np.zeros(0, dtype=np.uint8)


def time_of(ns: int) -> Time:
    """``builtin_interfaces/Time`` of a wall time [ns since the epoch]."""
    sec, nanosec = frames.stamp(ns)
    return Time(sec=sec, nanosec=nanosec)


def header(ns: int, frame_id: str) -> Header:
    """A header stamped ``ns`` [ns since the epoch] in ``frame_id``."""
    return Header(stamp=time_of(ns), frame_id=frame_id)


def drone_rgba(row: int, alpha: float = 1.0) -> RGBA:
    """Drone row ``row``'s colour (matplotlib's C{row}, as in the recording and the report)."""
    r, g, b = (float(c) for c in PALETTE[row % len(PALETTE)])
    return (r, g, b, alpha)


def _pose(p: Sequence[float], q: Quat) -> Pose:
    return Pose(position=Point(x=float(p[0]), y=float(p[1]), z=float(p[2])),
                orientation=Quaternion(x=q[0], y=q[1], z=q[2], w=q[3]))


def pose_stamped(p: Sequence[float], q: Quat, ns: int, frame_id: str) -> PoseStamped:
    """A pose at p [m] with attitude q (x, y, z, w) in ``frame_id``, stamped ``ns``."""
    return PoseStamped(header=header(ns, frame_id), pose=_pose(p, q))


def tf_message(transforms: Sequence[tuple[str, str, Sequence[float], Quat]],
               ns: int) -> TFMessage:
    """Transforms (parent, child, translation [m] in parent, rotation R_parent←child), all
    stamped ``ns``."""
    stamp = time_of(ns)
    return TFMessage(transforms=[TransformStamped(
        header=Header(stamp=stamp, frame_id=parent), child_frame_id=child,
        transform=Transform(translation=Vector3(x=float(t[0]), y=float(t[1]), z=float(t[2])),
                            rotation=Quaternion(x=q[0], y=q[1], z=q[2], w=q[3])))
        for parent, child, t, q in transforms])


def _marker(ns: int, frame_id: str, namespace: str, ident: int, kind: int,
            scale: tuple[float, float, float], rgba: RGBA, *,
            points: list[Point] | None = None, colors: list[ColorRGBA] | None = None,
            text: str = "", pose: Pose | None = None) -> Marker:
    """One ADD marker with everything rviz does not use left empty."""
    return Marker(
        header=header(ns, frame_id), ns=namespace, id=ident, type=kind, action=Marker.ADD,
        pose=pose or _pose((0.0, 0.0, 0.0), frames.IDENTITY),
        scale=Vector3(x=scale[0], y=scale[1], z=scale[2]),
        color=ColorRGBA(r=rgba[0], g=rgba[1], b=rgba[2], a=rgba[3]),
        lifetime=Duration(sec=0, nanosec=0), frame_locked=False,
        points=points or [], colors=colors or [], texture_resource="",
        texture=CompressedImage(header=header(0, ""), format="", data=_EMPTY_U8),
        uv_coordinates=[], text=text, mesh_resource="",
        mesh_file=MeshFile(filename="", data=_EMPTY_U8), mesh_use_embedded_materials=False)


def marker_array(markers: list[Marker]) -> MarkerArray:
    """A MarkerArray of Jazzy markers (rosbags types the array's field with the older Marker
    class, whose definition lacks the texture and mesh fields; the CDR is Jazzy's)."""
    return MarkerArray(markers=cast(Any, markers))


def owner_colours(owner: NDArray[np.intp]) -> list[RGBA]:
    """Each landmark's colour: its owner's row colour, grey without an owner (-1)."""
    return [drone_rgba(int(i)) if i >= 0 else UNOWNED_RGBA for i in owner.tolist()]


def capture_colours(captured: NDArray[np.bool_]) -> list[RGBA]:
    """Each landmark's colour by capture state: captured green, pending orange."""
    return [CAPTURED_RGBA if c else PENDING_RGBA for c in captured.tolist()]


def landmark_marker(q: NDArray[np.float64], colours: list[RGBA], ns: int, namespace: str,
                    diameter: float, frame_id: str) -> MarkerArray:
    """Landmarks q (m, 3) [m; world ENU] as one SPHERE_LIST marker (``namespace``, id 0) of
    spheres ``diameter`` [m] wide, one colour per landmark."""
    pts = [Point(x=x, y=y, z=z) for x, y, z in np.asarray(q, dtype=np.float64).tolist()]
    cols = [ColorRGBA(r=r, g=g, b=b, a=a) for r, g, b, a in colours]
    return marker_array([_marker(ns, frame_id, namespace, 0, Marker.SPHERE_LIST,
                                 (diameter, diameter, diameter), (1.0, 1.0, 1.0, 1.0),
                                 points=pts, colors=cols)])


def frustum_markers(rows: Sequence[int], p: Sequence[Sequence[float]],
                    v: Sequence[Sequence[float]], labels: Sequence[str], ns: int,
                    depth: float, half_h: float, half_v: float,
                    frame_id: str) -> MarkerArray:
    """Per drone k (colour row ``rows[k]``, camera at p[k] [m] looking along unit v[k]): its
    frustum ``depth`` [m] deep with half-angles ``half_h``, ``half_v`` [rad], and its label
    ``labels[k]`` above it."""
    out: list[Marker] = []
    for row, pk, vk, text in zip(rows, p, v, labels, strict=True):  # a loop over drones
        rgba = drone_rgba(row)
        pts = [Point(x=a, y=b, z=c) for a, b, c in
               frames.frustum_points(pk, vk, depth, half_h, half_v)]
        out.append(_marker(ns, frame_id, "frustum", row, Marker.LINE_LIST, (0.02, 0.0, 0.0),
                           rgba, points=pts))
        above = (float(pk[0]), float(pk[1]), float(pk[2]) + 0.3)
        out.append(_marker(ns, frame_id, "label", row, Marker.TEXT_VIEW_FACING,
                           (0.0, 0.0, 0.15), rgba, text=text,
                           pose=_pose(above, frames.IDENTITY)))
    return marker_array(out)


def _level(row: DroneRow) -> int:
    """A drone's diagnostic level: STALE when its link is stale or never heard, WARN when it
    left before being done or has a fault, OK otherwise."""
    if row.link in ("stale", "not heard yet", "never heard", "token, no state"):
        return DiagnosticStatus.STALE
    if (row.link == "left" and not row.done) or row.fault != "-":
        return DiagnosticStatus.WARN
    return DiagnosticStatus.OK


def _values(items: dict[str, Any]) -> list[KeyValue]:
    return [KeyValue(key=k, value=str(v)) for k, v in items.items()]


def diagnostics(view: MissionView, tokens: dict[str, str], ns: int) -> DiagnosticArray:
    """``viscover status`` as diagnostics: one status per drone (``viscover/<token>``,
    hardware_id its viscover id) and one for the mission (``viscover/mission``: ERROR on an
    invariant violation, WARN while the mesh is gone or landmarks have no owner, else OK)."""
    out = []
    for row in view.rows:  # a loop over drones
        aid = row.id.removesuffix(" (joined)")
        out.append(DiagnosticStatus(
            level=_level(row), name=f"viscover/{tokens.get(aid, aid)}",
            message=f"{row.phase}, {row.owned} landmarks, vision {row.vision:.3f}",
            hardware_id=aid, values=_values({
                "phase": row.phase, "owned": row.owned, "vision": f"{row.vision:.6g}",
                "trades (ok / failed)": row.trades, "link": row.link, "heard": row.heard,
                "mocap": row.mocap, "fault": row.fault, "done": row.done})))
    level = DiagnosticStatus.ERROR if view.violations else \
        DiagnosticStatus.WARN if view.mesh_gone_s is not None or view.unowned else \
        DiagnosticStatus.OK
    word = "complete" if view.complete else "running"
    values: dict[str, Any] = {
        "mission": view.mission, "complete": view.complete, "coverage": f"{view.coverage:.6g}",
        "seen": view.seen, "not_seen": view.not_seen, "unowned": view.unowned,
        "elapsed_s": f"{view.elapsed_s:.1f}", "mission_t": f"{view.mission_t:.2f}",
        "violations": len(view.violations), "rejected": view.rejected,
        "fenced": ",".join(view.fenced), "orphaned": view.orphaned, "mesh": view.mesh}
    if view.captured is not None:
        values["captured"] = view.captured
    out.append(DiagnosticStatus(
        level=level, name="viscover/mission", hardware_id=view.mission,
        message=f"{word}, coverage {view.coverage:.4g}" + (
            f", {len(view.violations)} violation(s)" if view.violations else ""),
        values=_values(values)))
    return DiagnosticArray(header=header(ns, ""), status=out)


def log_of(event: MissionEvent) -> Log:
    """A mission event as a log line stamped with its ``time`` [s since the epoch]; the
    source is the logger's name (``viscover.<source>``), the kind its function."""
    t = event.time
    ns = int(t * 1e9) if math.isfinite(t) else 0
    return Log(stamp=time_of(ns), level=LOG_LEVELS.get(event.level, Log.INFO),
               name=f"viscover.{event.source}", msg=event.text, file="",
               function=event.kind, line=0)


def parse_targets(text: str, known: Sequence[str]) -> tuple[list[str] | None, list[str]]:
    """The drones a land / stop String names: ``""`` or ``all`` → None (every live drone);
    else comma- or space-separated ids, each a viscover id or its ROS token. Returns
    (targets, unknown words)."""
    words = [w for w in text.replace(",", " ").split() if w]
    if not words or words == ["all"]:
        return None, []
    by_token = {drone_token(d): d for d in known}
    targets, unknown = [], []
    for w in words:
        d = w if w in known else by_token.get(w)
        if d is None:
            unknown.append(w)
        elif d not in targets:
            targets.append(d)
    return targets, unknown
