"""Frame conventions and quaternion helpers (thesis section 2.2; MAVLink conventions).

Mission frames: world ENU (x east, y north, z up), body FLU (x forward, y left, z up).
MAVLink frames: local NED (x north, y east, z down), body FRD (x forward, y right, z down).

Quaternions are numpy arrays (w, x, y, z), unit-normalised, and represent the rotation that
takes body-frame vectors into the world frame (R_world_body), which is what MAVLink's
SET_ATTITUDE_TARGET.q ("from local NED to body FRD") and PX4's attitude setpoint hold.
Euler angles are the ZYX (yaw γ, pitch β, roll α) angles of eq. 2.2.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

Array = NDArray[np.float64]

#: ENU→NED axis permutation (x, y, z) → (y, x, −z); its own inverse.
ENU_TO_NED: Array = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
#: FLU→FRD axis flip (x, y, z) → (x, −y, −z); its own inverse.
FLU_TO_FRD: Array = np.diag([1.0, -1.0, -1.0])

#: How far from 1 a quaternion norm may be and still count as unit (ArduPilot: ~1e-3).
UNIT_TOL = 1e-3


def enu_to_ned(v: ArrayLike) -> Array:
    """facts.md: world vector(s) (..., 3) ENU [any unit] → NED: (x, y, z) → (y, x, −z)."""
    a = np.asarray(v, dtype=np.float64)
    return np.stack([a[..., 1], a[..., 0], -a[..., 2]], axis=-1)


def ned_to_enu(v: ArrayLike) -> Array:
    """facts.md: world vector(s) (..., 3) NED → ENU: (x, y, z) → (y, x, −z) (an involution)."""
    return enu_to_ned(v)


def flu_to_frd(v: ArrayLike) -> Array:
    """facts.md: body vector(s) (..., 3) FLU → FRD: (x, y, z) → (x, −y, −z)."""
    a = np.asarray(v, dtype=np.float64)
    return np.stack([a[..., 0], -a[..., 1], -a[..., 2]], axis=-1)


def frd_to_flu(v: ArrayLike) -> Array:
    """facts.md: body vector(s) (..., 3) FRD → FLU (an involution)."""
    return flu_to_frd(v)


def wrap_pi(angle: float) -> float:
    """Angle [rad] wrapped into [−π, π)."""
    return float((angle + math.pi) % (2.0 * math.pi) - math.pi)


def yaw_enu_to_ned(yaw_enu: float) -> float:
    """facts.md: heading [rad] from ENU (from east, counter-clockwise) to NED (from north,
    clockwise): ψ_ned = π/2 − ψ_enu, wrapped."""
    return wrap_pi(math.pi / 2.0 - yaw_enu)


def yaw_ned_to_enu(yaw_ned: float) -> float:
    """facts.md: heading [rad] NED → ENU: ψ_enu = π/2 − ψ_ned, wrapped (an involution)."""
    return wrap_pi(math.pi / 2.0 - yaw_ned)


# ---------------------------------------------------------------------------------------
# Quaternions (w, x, y, z).
# ---------------------------------------------------------------------------------------


def quat_normalize(q: ArrayLike) -> Array:
    """Unit quaternion (w, x, y, z) with w ≥ 0; raises ValueError on zero or non-finite input."""
    a = np.asarray(q, dtype=np.float64)
    n = float(np.linalg.norm(a))
    if not math.isfinite(n) or n < 1e-12:
        raise ValueError(f"cannot normalise quaternion {a!r}")
    a = a / n
    return -a if a[0] < 0.0 else a


def quat_is_unit(q: ArrayLike, tol: float = UNIT_TOL) -> bool:
    """True if q (w, x, y, z) is finite with |‖q‖ − 1| ≤ tol."""
    a = np.asarray(q, dtype=np.float64)
    return bool(a.shape == (4,) and np.all(np.isfinite(a)) and abs(np.linalg.norm(a) - 1) <= tol)


def quat_mul(a: ArrayLike, b: ArrayLike) -> Array:
    """Hamilton product a ⊗ b of quaternions (w, x, y, z) (rotation b first, then a)."""
    w1, x1, y1, z1 = np.asarray(a, dtype=np.float64)
    w2, x2, y2, z2 = np.asarray(b, dtype=np.float64)
    return np.array([
        w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
        w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
        w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
        w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2,
    ])


def quat_conj(q: ArrayLike) -> Array:
    """Conjugate (inverse of a unit quaternion) (w, −x, −y, −z)."""
    w, x, y, z = np.asarray(q, dtype=np.float64)
    return np.array([w, -x, -y, -z])


def quat_to_matrix(q: ArrayLike) -> Array:
    """Rotation matrix R (3, 3) of quaternion q (w, x, y, z); normalises q first."""
    w, x, y, z = quat_normalize(q)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ])


def quat_from_matrix(r: ArrayLike) -> Array:
    """Unit quaternion (w, x, y, z), w ≥ 0, of a rotation matrix R (3, 3) (Shepperd's method)."""
    m = np.asarray(r, dtype=np.float64)
    tr = m[0, 0] + m[1, 1] + m[2, 2]
    if tr > 0.0:
        s = 2.0 * math.sqrt(tr + 1.0)
        q = [0.25 * s, (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s]
    elif m[0, 0] > m[1, 1] and m[0, 0] > m[2, 2]:
        s = 2.0 * math.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2])
        q = [(m[2, 1] - m[1, 2]) / s, 0.25 * s, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s]
    elif m[1, 1] > m[2, 2]:
        s = 2.0 * math.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2])
        q = [(m[0, 2] - m[2, 0]) / s, (m[0, 1] + m[1, 0]) / s, 0.25 * s, (m[1, 2] + m[2, 1]) / s]
    else:
        s = 2.0 * math.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1])
        q = [(m[1, 0] - m[0, 1]) / s, (m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, 0.25 * s]
    return quat_normalize(q)


def quat_from_euler(roll: float, pitch: float, yaw: float) -> Array:
    """Eq. 2.2: unit quaternion of R = R_z(γ=yaw) R_y(β=pitch) R_x(α=roll), angles [rad]."""
    cr, sr = math.cos(roll / 2), math.sin(roll / 2)
    cp, sp = math.cos(pitch / 2), math.sin(pitch / 2)
    cy, sy = math.cos(yaw / 2), math.sin(yaw / 2)
    q = np.array([
        cy * cp * cr + sy * sp * sr,
        cy * cp * sr - sy * sp * cr,
        cy * sp * cr + sy * cp * sr,
        sy * cp * cr - cy * sp * sr,
    ])
    return quat_normalize(q)


def euler_from_matrix(r: ArrayLike) -> tuple[float, float, float]:
    """Eq. 2.2 inverted: (roll α, pitch β, yaw γ) [rad] of R = R_z(γ) R_y(β) R_x(α)."""
    m = np.asarray(r, dtype=np.float64)
    pitch = -math.asin(max(-1.0, min(1.0, float(m[2, 0]))))
    roll = math.atan2(float(m[2, 1]), float(m[2, 2]))
    yaw = math.atan2(float(m[1, 0]), float(m[0, 0]))
    return roll, pitch, yaw


def euler_from_quat(q: ArrayLike) -> tuple[float, float, float]:
    """Eq. 2.2 inverted: (roll, pitch, yaw) [rad] of quaternion q (w, x, y, z)."""
    return euler_from_matrix(quat_to_matrix(q))


def yaw_from_quat(q: ArrayLike) -> float:
    """Heading γ [rad] (ZYX yaw of eq. 2.2) of quaternion q, in q's own world frame."""
    w, x, y, z = quat_normalize(q)
    return math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


def quat_enu_flu_to_ned_frd(q_enu_flu: ArrayLike) -> Array:
    """Attitude R_ENU←FLU → R_NED←FRD = P R D (P = ENU_TO_NED, D = FLU_TO_FRD), as (w, x, y, z)."""
    r = ENU_TO_NED @ quat_to_matrix(q_enu_flu) @ FLU_TO_FRD
    return quat_from_matrix(r)


def quat_ned_frd_to_enu_flu(q_ned_frd: ArrayLike) -> Array:
    """Attitude R_NED←FRD → R_ENU←FLU (the inverse of :func:`quat_enu_flu_to_ned_frd`)."""
    r = ENU_TO_NED @ quat_to_matrix(q_ned_frd) @ FLU_TO_FRD
    return quat_from_matrix(r)
