"""Frames of the ROS side (pure functions, scalar maths: they run per mocap sample).

ROS (REP 103) uses the conventions viscover already uses, so positions need no conversion:

* ``world``: the mission's world frame, ENU (x east, y north, z up) [m].
* ``<drone>`` (the body): FLU (x forward, y left, z up). With motion capture its attitude is
  the mocap quaternion (the wire's (w, x, y, z) R_ENU←FLU, written (x, y, z, w) as ROS does);
  without, the body is level and heads where the camera looks (yaw of v).
* ``<drone>/camera``: x along the camera's unit viewing direction v, y horizontal to the
  left, z up (no roll): yaw ψ = atan2(v_y, v_x) about z, then pitch θ = −asin(v_z) about y
  (a positive pitch looks down). Its origin is the drone's position (the agent's pose p).

Quaternions are (x, y, z, w) tuples, unit, rotating vectors from the child frame to the
parent (R_parent←child), as ``geometry_msgs`` carries them.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

Quat = tuple[float, float, float, float]
Vec = tuple[float, float, float]

IDENTITY: Quat = (0.0, 0.0, 0.0, 1.0)


def yaw_pitch(v: Sequence[float]) -> tuple[float, float]:
    """(ψ, θ) [rad] of a unit direction v [world ENU]: heading about z, pitch about y
    (positive down); a vertical v has ψ = 0."""
    x, y, z = float(v[0]), float(v[1]), float(v[2])
    yaw = math.atan2(y, x) if (x or y) else 0.0
    return yaw, -math.asin(max(-1.0, min(1.0, z)))


def yaw_quat(yaw: float) -> Quat:
    """A rotation by ``yaw`` [rad] about z."""
    return (0.0, 0.0, math.sin(yaw / 2.0), math.cos(yaw / 2.0))


def pitch_quat(pitch: float) -> Quat:
    """A rotation by ``pitch`` [rad] about y."""
    return (0.0, math.sin(pitch / 2.0), 0.0, math.cos(pitch / 2.0))


def multiply(a: Quat, b: Quat) -> Quat:
    """The Hamilton product a·b (apply b, then a)."""
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return (aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
            aw * bw - ax * bx - ay * by - az * bz)


def conjugate(q: Quat) -> Quat:
    """The inverse of a unit quaternion."""
    return (-q[0], -q[1], -q[2], q[3])


def normalized(q: Sequence[float]) -> Quat:
    """``q`` scaled to unit length (identity for a zero quaternion)."""
    n = math.sqrt(sum(float(c) * float(c) for c in q))
    if not n > 0.0:
        return IDENTITY
    return (float(q[0]) / n, float(q[1]) / n, float(q[2]) / n, float(q[3]) / n)


def rotate(q: Quat, p: Sequence[float]) -> Vec:
    """Vector p rotated by unit quaternion q."""
    x, y, z, w = q
    px, py, pz = float(p[0]), float(p[1]), float(p[2])
    # t = 2 q_v × p; p' = p + w t + q_v × t
    tx, ty, tz = 2.0 * (y * pz - z * py), 2.0 * (z * px - x * pz), 2.0 * (x * py - y * px)
    return (px + w * tx + (y * tz - z * ty), py + w * ty + (z * tx - x * tz),
            pz + w * tz + (x * ty - y * tx))


def camera_quat(v: Sequence[float]) -> Quat:
    """R_world←camera of a camera looking along unit v [world ENU] (module docstring)."""
    yaw, pitch = yaw_pitch(v)
    return multiply(yaw_quat(yaw), pitch_quat(pitch))


def level_body_quat(v: Sequence[float]) -> Quat:
    """R_world←body of a level body heading where the camera looks (no mocap attitude)."""
    return yaw_quat(yaw_pitch(v)[0])


def camera_in_body(body: Quat, v: Sequence[float]) -> Quat:
    """R_body←camera: the camera looking along unit v [world ENU] seen from a body whose
    attitude is R_world←body ``body``."""
    return normalized(multiply(conjugate(body), camera_quat(v)))


def mocap_quat(q_wxyz: Sequence[float]) -> Quat:
    """The wire's mocap attitude (w, x, y, z) R_ENU←FLU as a ROS (x, y, z, w), unit."""
    return normalized((q_wxyz[1], q_wxyz[2], q_wxyz[3], q_wxyz[0]))


def stamp(ns: int) -> tuple[int, int]:
    """``builtin_interfaces/Time`` (sec, nanosec) of a time [ns since the Unix epoch]."""
    sec, nanosec = divmod(int(ns), 1_000_000_000)
    return sec, nanosec


def frustum_points(p: Sequence[float], v: Sequence[float], depth: float,
                   half_h: float, half_v: float) -> list[Vec]:
    """A LINE_LIST (16 points, 8 segments) [m; world ENU] of the camera pyramid at p looking
    along unit v, ``depth`` [m] deep, half-angles ``half_h`` (left-right) and ``half_v``
    (up-down) [rad]: 4 edges from the apex, then the 4 edges of the far rectangle."""
    q = camera_quat(v)
    a, b = depth * math.tan(half_h), depth * math.tan(half_v)
    apex = (float(p[0]), float(p[1]), float(p[2]))
    corners = []
    for sy, sz in ((1.0, 1.0), (1.0, -1.0), (-1.0, -1.0), (-1.0, 1.0)):
        c = rotate(q, (depth, sy * a, sz * b))
        corners.append((apex[0] + c[0], apex[1] + c[1], apex[2] + c[2]))
    out: list[Vec] = []
    for c in corners:
        out += [apex, c]
    for k in range(4):
        out += [corners[k], corners[(k + 1) % 4]]
    return out
