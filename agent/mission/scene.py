"""Foxglove messages of a mission (foxglove-sdk's well-known schemas), built from numpy arrays:
drones (bodies, safety spheres, camera arrows and frusta, labels), landmarks coloured by owner
(one point cloud, packed bytes), the mission space, poses, frame transforms and event logs.
World frame :data:`~agent.storage.recording.WORLD` (ENU, metres); a PoseInFrame's camera looks
along its +x axis; the camera *frame* of :func:`frame_transforms` is an optical frame."""

from __future__ import annotations

import numpy as np
from foxglove.messages import (
    ArrowPrimitive,
    Color,
    FrameTransform,
    LinePrimitive,
    LinePrimitiveLineType,
    Log,
    LogLevel,
    PackedElementField,
    PackedElementFieldNumericType,
    Point3,
    PointCloud,
    Pose,
    PoseInFrame,
    Quaternion,
    SceneEntity,
    SceneUpdate,
    SpherePrimitive,
    TextPrimitive,
    Timestamp,
    Vector3,
)
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from agent.core.inspection import camera_axes
from agent.storage.events import MissionEvent
from agent.storage.recording import PALETTE, WORLD, camera_frame, drone_frame, landmark_colours

Array = NDArray[np.float64]
#: half-angle [rad] of the drawn camera frustum (the vision model has no field of view)
FRUSTUM_HALF_ANGLE = np.deg2rad(30.0)
_LEVELS = {"info": LogLevel.Info, "warning": LogLevel.Warning, "error": LogLevel.Error}
#: point layout of the landmark cloud: x, y, z float32, red..alpha uint8, id uint32, owner int32
_CLOUD = np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("red", "u1"), ("green", "u1"),
                   ("blue", "u1"), ("alpha", "u1"), ("id", "<u4"), ("owner", "<i4")])
_F = PackedElementFieldNumericType
_FIELDS = [("x", 0, _F.Float32), ("y", 4, _F.Float32), ("z", 8, _F.Float32),
           ("red", 12, _F.Uint8), ("green", 13, _F.Uint8), ("blue", 14, _F.Uint8),
           ("alpha", 15, _F.Uint8), ("id", 16, _F.Uint32), ("owner", 20, _F.Int32)]


def stamp(wall: float) -> Timestamp:
    """A Foxglove timestamp of a wall time [s since the epoch]."""
    return Timestamp.from_epoch_secs(wall)


def camera_quaternions(v: Array) -> Array:
    """Quaternions (n, 4) (x, y, z, w) turning +x onto unit v (n, 3): yaw about z, pitch about y."""
    v = np.asarray(v, dtype=np.float64).reshape(-1, 3)
    yaw = np.arctan2(v[:, 1], v[:, 0])
    pitch = -np.arcsin(np.clip(v[:, 2], -1.0, 1.0))
    cz, sz = np.cos(yaw / 2), np.sin(yaw / 2)
    cy, sy = np.cos(pitch / 2), np.sin(pitch / 2)
    return np.stack([-sz * sy, cz * sy, cy * sz, cz * cy], axis=1)


def frame_rotations(v: Array) -> tuple[Array, Array]:
    """Rotations (n, 3, 3) of the drone frames and, in them, of the camera frames of cameras
    looking along unit v (n, 3) [world ENU] (see :func:`frame_transforms`)."""
    v = np.asarray(v, dtype=np.float64).reshape(-1, 3)
    yaw = np.arctan2(v[:, 1], v[:, 0])
    c, s, z, o = np.cos(yaw), np.sin(yaw), np.zeros(v.shape[0]), np.ones(v.shape[0])
    body = np.stack([np.stack([c, -s, z], 1), np.stack([s, c, z], 1), np.stack([z, z, o], 1)],
                    axis=1)
    right, up = camera_axes(v)
    optical = np.stack([right, -up, v], axis=2)  # columns: x right, y down, z optical axis
    return body, np.einsum("nji,njk->nik", body, optical)


def frame_transforms(aid: str, p: Array, v: Array, wall: float
                     ) -> tuple[FrameTransform, FrameTransform]:
    """The two FrameTransforms of drone ``aid`` at position p (3,) [m; world ENU] with its
    camera along unit v (3,), stamped ``wall`` [s since the epoch].

    * ``world`` → ``drone/<id>`` (:func:`~agent.storage.recording.drone_frame`): translation
      p [m]; rotation the yaw of v about z (x forward along the camera's heading, y left, z
      up: a level frame, so a viewer following it keeps the horizon).
    * ``drone/<id>`` → ``drone/<id>/camera`` (:func:`~agent.storage.recording.camera_frame`):
      no translation (the model's camera sits at the drone's position); rotation from the
      drone frame to the camera's *optical* frame, Foxglove's camera convention: +z along the
      optical axis v, +x the image's right (v × ẑ, horizontal: the camera has no roll, as in
      :func:`agent.core.inspection.camera_axes`), +y down the image.

    Foxglove's FrameTransform maps a point of the child frame into the parent frame: rotate
    by the quaternion (x, y, z, w), then add the translation.
    """
    body, cam = frame_rotations(np.asarray(v, dtype=np.float64)[None])
    qb, qc = Rotation.from_matrix(np.concatenate([body, cam])).as_quat()  # (x, y, z, w)
    ts = stamp(wall)

    def quat(q: Array) -> Quaternion:
        return Quaternion(x=float(q[0]), y=float(q[1]), z=float(q[2]), w=float(q[3]))

    return (FrameTransform(timestamp=ts, parent_frame_id=WORLD, child_frame_id=drone_frame(aid),
                           translation=Vector3(x=float(p[0]), y=float(p[1]), z=float(p[2])),
                           rotation=quat(qb)),
            FrameTransform(timestamp=ts, parent_frame_id=drone_frame(aid),
                           child_frame_id=camera_frame(aid),
                           translation=Vector3(x=0.0, y=0.0, z=0.0), rotation=quat(qc)))


def frustum_segments(p: Array, v: Array, depth: float,
                     half_angle: float = FRUSTUM_HALF_ANGLE) -> Array:
    """Line-list points (n, 16, 3) [m] of square camera pyramids at p along v, depth [m] deep."""
    p, v = np.asarray(p, dtype=np.float64), np.asarray(v, dtype=np.float64)
    e1 = np.cross(v, [0.0, 0.0, 1.0])
    flat = np.linalg.norm(e1, axis=1) < 1e-6
    e1[flat] = np.cross(v[flat], [1.0, 0.0, 0.0])
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    e2 = np.cross(e1, v)
    s = np.tan(half_angle)
    signs = np.array([[1, 1], [1, -1], [-1, -1], [-1, 1]], dtype=np.float64)
    corners = p[:, None] + depth * (v[:, None] + s * (signs[None, :, :1] * e1[:, None]
                                                      + signs[None, :, 1:] * e2[:, None]))
    apex = np.repeat(p[:, None], 4, axis=1)
    spokes = np.stack([apex, corners], axis=2).reshape(-1, 8, 3)
    rim = np.stack([corners, np.roll(corners, -1, axis=1)], axis=2).reshape(-1, 8, 3)
    return np.concatenate([spokes, rim], axis=1)


def _colour(i: int, alpha: float = 1.0) -> Color:
    """Agent row ``i``'s colour (matplotlib's C{i})."""
    r, g, b = PALETTE[i % len(PALETTE)]
    return Color(r=float(r), g=float(g), b=float(b), a=alpha)


def _pose(p: Array, quat: Array | None = None) -> Pose:
    """A pose at p (3,) [m] with quaternion (x, y, z, w) (identity without one)."""
    x, y, z, w = (0.0, 0.0, 0.0, 1.0) if quat is None else (float(c) for c in quat)
    return Pose(position=Vector3(x=float(p[0]), y=float(p[1]), z=float(p[2])),
                orientation=Quaternion(x=x, y=y, z=z, w=w))


def pose_in_frame(p: Array, quat: Array, wall: float) -> PoseInFrame:
    """A pose in the world frame: position p (3,) [m], quaternion (x, y, z, w)."""
    return PoseInFrame(timestamp=stamp(wall), frame_id=WORLD, pose=_pose(p, quat))


def drone_update(rows: list[int], ids: list[str], p: Array, v: Array, labels: list[str],
                 wall: float, d_opt: float, r_s: float) -> SceneUpdate:
    """Per drone k: body, safety sphere (R_s [m]), camera arrow, frustum (d_opt [m]), label."""
    quats = camera_quaternions(v)
    seg = frustum_segments(p, v, d_opt)
    ents = []
    for k, (i, aid) in enumerate(zip(rows, ids, strict=True)):  # a loop over drones
        c, pose = _colour(i), _pose(p[k], quats[k])
        ents.append(SceneEntity(
            timestamp=stamp(wall), frame_id=WORLD, id=f"drone/{aid}",
            spheres=[SpherePrimitive(pose=pose, size=Vector3(x=0.15, y=0.15, z=0.15),
                                     color=c),
                     SpherePrimitive(pose=pose, size=Vector3(x=2 * r_s, y=2 * r_s, z=2 * r_s),
                                     color=_colour(i, 0.08))],
            arrows=[ArrowPrimitive(pose=pose, shaft_length=0.3, shaft_diameter=0.03,
                                   head_length=0.1, head_diameter=0.07, color=c)],
            lines=[LinePrimitive(type=LinePrimitiveLineType.LineList, thickness=2.0,
                                 scale_invariant=True, color=c,
                                 points=[Point3(x=float(a), y=float(b), z=float(z))
                                         for a, b, z in seg[k]])],
            texts=[TextPrimitive(pose=_pose(p[k] + np.array([0.0, 0.0, 0.25])), billboard=True,
                                 font_size=14.0, scale_invariant=True, color=c,
                                 text=labels[k])]))
    return SceneUpdate(entities=ents)


def landmark_cloud(q: Array, ids: NDArray[np.int64], owner: NDArray[np.intp],
                   wall: float) -> PointCloud:
    """Landmarks q (m, 3) [m] as a point cloud coloured by owner, with id and owner fields."""
    pts = np.zeros(q.shape[0], dtype=_CLOUD)
    for k, axis in enumerate("xyz"):
        pts[axis] = q[:, k]
    rgba = landmark_colours(owner)
    for k, ch in enumerate(("red", "green", "blue", "alpha")):
        pts[ch] = rgba[:, k]
    pts["id"] = ids
    pts["owner"] = owner
    fields = [PackedElementField(name=n, offset=off, type=t) for n, off, t in _FIELDS]
    return PointCloud(timestamp=stamp(wall), frame_id=WORLD, pose=_pose(np.zeros(3)),
                      point_stride=_CLOUD.itemsize, fields=fields, data=pts.tobytes())


def space_update(lo: Array, hi: Array, wall: float) -> SceneUpdate | None:
    """The mission space's edges [m] (planar: z = 0); None when x or y is unbounded."""
    if not (np.all(np.isfinite(lo[:2])) and np.all(np.isfinite(hi[:2]))):
        return None
    if not (np.isfinite(lo[2]) and np.isfinite(hi[2])):
        lo, hi = np.append(lo[:2], 0.0), np.append(hi[:2], 0.0)
    c = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1])
                  for z in (lo[2], hi[2])])
    i, j = np.nonzero(np.triu((np.abs(c[:, None] - c[None]) > 0).sum(axis=-1) == 1))
    pts = c[np.stack([i, j], axis=1).reshape(-1)]
    return SceneUpdate(entities=[SceneEntity(
        timestamp=stamp(wall), frame_id=WORLD, id="mission_space",
        lines=[LinePrimitive(type=LinePrimitiveLineType.LineList, thickness=1.0,
                             scale_invariant=True, color=Color(r=0.5, g=0.5, b=0.5, a=1.0),
                             points=[Point3(x=float(a), y=float(b), z=float(z))
                                     for a, b, z in pts])])])


def log_of(ev: MissionEvent) -> Log:
    """An event as a Foxglove log line (stamped with its time [s since the epoch])."""
    return Log(timestamp=stamp(ev.time), level=_LEVELS.get(ev.level, LogLevel.Info),
               message=ev.text, name=f"{ev.source}/{ev.kind}")
