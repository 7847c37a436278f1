"""Structure meshes from files (STL, OBJ, PLY) placed in the world frame (ENU).

A mesh file is read in its own model frame and placed by a pose: scaled by ``scale``
(model units → metres), rotated by ``rotation`` (3×3, model → world) or a ``yaw`` [rad]
about the world z axis, then translated to ``position`` [m; world ENU].

Every user mistake (missing file, unknown format, unreadable or empty mesh, an open mesh
where a closed one is required, a bad pose) raises a one-line :class:`ValueError` that names
the file and the problem.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import trimesh
from numpy.typing import ArrayLike, NDArray

Array = NDArray[np.float64]

#: File suffixes accepted by :func:`load_mesh` (lower case, with the dot).
MESH_SUFFIXES = (".stl", ".obj", ".ply")


def _first_line(exc: BaseException) -> str:
    """The first non-empty line of an exception's message (or its type name)."""
    lines = [s.strip() for s in str(exc).splitlines() if s.strip()]
    return lines[0] if lines else type(exc).__name__


def load_mesh(path: str | Path, *, require_watertight: bool = False) -> trimesh.Trimesh:
    """A triangle mesh read from ``path`` in its model frame (units as stored in the file)."""
    p = Path(path)
    if not p.exists():
        raise ValueError(f"{p}: no such mesh file")
    if not p.is_file():
        raise ValueError(f"{p}: not a file")
    suffix = p.suffix.lower()
    if suffix not in MESH_SUFFIXES:
        raise ValueError(
            f"{p}: unsupported mesh format '{p.suffix}' (use {', '.join(MESH_SUFFIXES)})"
        )
    try:
        loaded = trimesh.load_mesh(str(p), file_type=suffix[1:])
    except Exception as exc:  # any parser failure is a user-file problem, reported in one line
        raise ValueError(f"{p}: cannot read mesh ({_first_line(exc)})") from None
    if not isinstance(loaded, trimesh.Trimesh):
        raise ValueError(f"{p}: file holds no triangle mesh")
    if len(loaded.faces) == 0:
        raise ValueError(f"{p}: mesh has no triangles")
    loaded.remove_unreferenced_vertices()
    if not np.all(np.isfinite(loaded.vertices)):
        raise ValueError(f"{p}: mesh has non-finite vertex coordinates")
    if require_watertight:
        check_watertight(loaded, str(p))
    return loaded


def check_watertight(mesh: trimesh.Trimesh, name: str = "mesh") -> None:
    """Raise a one-line ValueError unless ``mesh`` is closed (every edge shared by two faces)."""
    if not mesh.is_watertight:
        raise ValueError(f"{name}: mesh is not watertight (it has open edges)")


def yaw_rotation(yaw: float) -> Array:
    """3×3 rotation by ``yaw`` [rad] about the world z axis (counter-clockwise seen from above)."""
    c, s = np.cos(yaw), np.sin(yaw)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def pose_matrix(
    position: ArrayLike = (0.0, 0.0, 0.0),
    yaw: float = 0.0,
    rotation: ArrayLike | None = None,
    scale: float = 1.0,
) -> Array:
    """4×4 model → world transform: x_world = position + R·(scale·x_model) [m; world ENU]."""
    t = np.asarray(position, dtype=np.float64).reshape(-1)
    if t.size != 3 or not np.all(np.isfinite(t)):
        raise ValueError(f"position must be three finite numbers [m], got {t.tolist()}")
    if not (np.isfinite(scale) and scale > 0):
        raise ValueError(f"scale must be a positive finite number, got {scale}")
    if not np.isfinite(yaw):
        raise ValueError(f"yaw must be a finite angle [rad], got {yaw}")
    if rotation is None:
        r = yaw_rotation(float(yaw))
    else:
        if yaw != 0.0:
            raise ValueError("give either yaw or rotation, not both")
        r = np.asarray(rotation, dtype=np.float64)
        if r.shape != (3, 3):
            raise ValueError(f"rotation must be a 3x3 matrix, got shape {r.shape}")
        if not (np.allclose(r.T @ r, np.eye(3), atol=1e-9) and np.linalg.det(r) > 0):
            raise ValueError("rotation must be a proper rotation matrix (orthonormal, det +1)")
    out = np.eye(4)
    out[:3, :3] = r * float(scale)
    out[:3, 3] = t
    return out


def posed_mesh(
    mesh: trimesh.Trimesh,
    position: ArrayLike = (0.0, 0.0, 0.0),
    yaw: float = 0.0,
    rotation: ArrayLike | None = None,
    scale: float = 1.0,
) -> trimesh.Trimesh:
    """A copy of ``mesh`` scaled, rotated and moved into the world frame [m; world ENU]."""
    out = mesh.copy()
    out.apply_transform(pose_matrix(position, yaw, rotation, scale))
    return out


def load_structure(
    path: str | Path,
    position: ArrayLike = (0.0, 0.0, 0.0),
    yaw: float = 0.0,
    rotation: ArrayLike | None = None,
    scale: float = 1.0,
    *,
    require_watertight: bool = False,
) -> trimesh.Trimesh:
    """The mesh in ``path`` placed in the world by the pose of :func:`pose_matrix` [m; ENU]."""
    try:
        transform = pose_matrix(position, yaw, rotation, scale)
    except ValueError as exc:
        raise ValueError(f"{Path(path)}: {exc}") from None
    mesh = load_mesh(path, require_watertight=require_watertight)
    mesh.apply_transform(transform)
    return mesh
