"""Landmark generators for common structures (thesis sections 5.3 and 6.2).

Every generator is a pure numpy function returning ``(q, u)``: landmark positions ``q``
(m, 3) [m; world ENU] and unit outward surface normals ``u`` (m, 3). No Python loops over
landmarks; the order of the landmarks is documented per generator because scenario files
refer to landmarks by their position in that order.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

Array = NDArray[np.float64]

#: Face names accepted by :func:`box_faces`, in their default order.
BOX_FACES: tuple[str, ...] = ("+x", "-x", "+y", "-y", "+z", "-z")

#: Outward normal axis index and sign of every face.
_FACE_AXIS = {"+x": (0, 1.0), "-x": (0, -1.0), "+y": (1, 1.0), "-y": (1, -1.0),
              "+z": (2, 1.0), "-z": (2, -1.0)}
#: The two in-face axes (first, second) of a face normal to axis k. The first axis is the
#: horizontal one on the side faces (y on ±x, x on ±y) and x on the top/bottom faces.
_FACE_TANGENTS = {0: (1, 2), 1: (0, 2), 2: (0, 1)}


def _vec3(x: ArrayLike, name: str) -> Array:
    """A 3-vector from 2 or 3 numbers (z = 0 for 2 numbers)."""
    a = np.asarray(x, dtype=np.float64).reshape(-1)
    if a.size == 2:
        a = np.append(a, 0.0)
    if a.size != 3:
        raise ValueError(f"{name} must have 2 or 3 components, got {a.size}")
    return a


def _cell_centres(n: int) -> Array:
    """n cell-centred offsets in (−1/2, 1/2): 1 → [0], 3 → [−1/3, 0, 1/3]."""
    return (np.arange(n, dtype=np.float64) + 0.5) / n - 0.5


def regular_polygon(
    sides: int, side: float, center: ArrayLike = (0.0, 0.0, 0.0), phase: float = 0.0
) -> tuple[Array, Array]:
    """One landmark at the centre of each edge of a regular polygon in a horizontal plane.

    ``sides`` ≥ 3 edges of length ``side`` [m] around ``center`` (2 or 3 numbers [m]);
    landmark k (k = 0..sides−1) is at angle φ_k = phase + 2πk/sides [rad] and distance
    apothem = side / (2·tan(π/sides)) from the centre, with outward radial normal
    (cos φ_k, sin φ_k, 0). The hexagon of section 5.3 is sides=6, side=0.5, phase=π/6.
    """
    if sides < 3:
        raise ValueError(f"a polygon needs at least 3 sides, got {sides}")
    if not side > 0:
        raise ValueError(f"side must be a positive length in metres, got {side}")
    c = _vec3(center, "center")
    phi = phase + 2.0 * np.pi * np.arange(sides) / sides
    u = np.stack([np.cos(phi), np.sin(phi), np.zeros(sides)], axis=1)
    apothem = side / (2.0 * np.tan(np.pi / sides))
    return c[None, :] + apothem * u, u


def box_faces(
    center: ArrayLike,
    size: ArrayLike,
    faces: Sequence[str] = BOX_FACES,
    grid: tuple[int, int] = (1, 1),
) -> tuple[Array, Array]:
    """Landmarks on the faces of an axis-aligned box, normals = outward face normals.

    ``center`` (3,) [m] is the box centre, ``size`` (3,) [m] its edge lengths along x, y, z.
    On every face listed in ``faces`` (subset of :data:`BOX_FACES`, in the order given) an
    ``grid = (n1, n2)`` cell-centred grid is placed: n1 points along the face's first axis
    and n2 along its second. The axes are (y, z) on ±x, (x, z) on ±y and (x, y) on ±z, so
    ``grid = (3, 1)`` is a horizontal row of three through the centre of each side face
    (and a row along x on the top face): the cube of section 6.2. ``(1, 1)`` is the centre.
    Order: face by face; within a face index = i2·n1 + i1 (first axis fastest).
    """
    c = _vec3(center, "center")
    s = _vec3(size, "size")
    if np.any(s <= 0):
        raise ValueError(f"size must be three positive lengths in metres, got {s.tolist()}")
    bad = [f for f in faces if f not in _FACE_AXIS]
    if bad:
        raise ValueError(f"unknown face(s) {bad}; use a subset of {list(BOX_FACES)}")
    n1, n2 = int(grid[0]), int(grid[1])
    if n1 < 1 or n2 < 1:
        raise ValueError(f"grid must be two positive counts, got {list(grid)}")
    nf = len(faces)
    axis = np.array([_FACE_AXIS[f][0] for f in faces], dtype=np.intp)
    sign = np.array([_FACE_AXIS[f][1] for f in faces])
    t1 = np.array([_FACE_TANGENTS[int(k)][0] for k in axis], dtype=np.intp)  # over faces
    t2 = np.array([_FACE_TANGENTS[int(k)][1] for k in axis], dtype=np.intp)
    eye = np.eye(3)
    normal = sign[:, None] * eye[axis] + 0.0  # (nf, 3); + 0.0 turns −0 into 0
    a1 = np.repeat(_cell_centres(n1)[None, :], n2, axis=0).reshape(-1)  # (n1·n2,)
    a2 = np.repeat(_cell_centres(n2), n1)
    off = (
        (normal * (s[axis] / 2.0)[:, None])[:, None, :]
        + a1[None, :, None] * (eye[t1] * s[t1][:, None])[:, None, :]
        + a2[None, :, None] * (eye[t2] * s[t2][:, None])[:, None, :]
    )  # (nf, n1·n2, 3)
    q = (c[None, None, :] + off).reshape(-1, 3)
    u = np.repeat(normal, n1 * n2, axis=0)
    return q.reshape(nf * n1 * n2, 3), u


def cylinder(
    center: ArrayLike, radius: float, height: float, around: int, rows: int = 1,
    phase: float = 0.0,
) -> tuple[Array, Array]:
    """Landmarks on the lateral surface of a vertical cylinder, outward radial normals.

    ``center`` (3,) [m] is the centre of the bottom disc; ``radius``, ``height`` [m].
    ``around`` landmarks per ring at angles phase + 2πk/around [rad] and ``rows`` rings at
    cell-centred heights (i + 1/2)·height/rows. Order: ring by ring from the bottom.
    """
    c = _vec3(center, "center")
    if not (radius > 0 and height > 0):
        raise ValueError(f"radius and height must be positive, got {radius}, {height}")
    if around < 1 or rows < 1:
        raise ValueError(f"around and rows must be positive counts, got {around}, {rows}")
    phi = np.tile(phase + 2.0 * np.pi * np.arange(around) / around, rows)
    z = np.repeat((np.arange(rows) + 0.5) * height / rows, around)
    u = np.stack([np.cos(phi), np.sin(phi), np.zeros(phi.size)], axis=1)
    q = c[None, :] + radius * u + z[:, None] * np.array([0.0, 0.0, 1.0])
    return q, u
