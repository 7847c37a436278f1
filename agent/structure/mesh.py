"""Structure meshes from files (STL, OBJ, PLY) placed in the world frame (ENU).

A mesh file is read in its own model frame and placed by a pose: scaled by ``scale``
(model units → metres), rotated by ``rotation`` (3×3, model → world) or a ``yaw`` [rad]
about the world z axis, then translated to ``position`` [m; world ENU].

Every user mistake (missing file, unknown format, unreadable or empty mesh, an open mesh
where a closed one is required, a bad pose) raises a one-line :class:`ValueError` that names
the file and the problem.

Before trimesh reads a file, :func:`load_mesh` checks what it can without reading it whole:
at most :data:`MAX_MESH_BYTES` (64 MiB) and :data:`MAX_MESH_TRIANGLES` (1,000,000, also
checked from a binary STL's or a PLY's header; reading takes about 0.7 kB per triangle), a
binary STL's length against its header, and that text (ASCII STL and PLY, OBJ) is UTF-8
(trimesh's fallback for other text needs a package this project does not install).
The mesh read is then repaired (:func:`agent.structure.repair.repair_mesh`: duplicates
merged, degenerate triangles dropped, each part wound consistently and turned outwards);
what was fixed is kept in its ``metadata["repairs"]`` (:func:`mesh_repairs`).
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike, NDArray

from agent.structure.repair import MeshRepairs, repair_mesh

if TYPE_CHECKING:  # imported where used: loading them costs start-up time
    import trimesh

Array = NDArray[np.float64]

#: File suffixes accepted by :func:`load_mesh` (lower case, with the dot).
MESH_SUFFIXES = (".stl", ".obj", ".ply")
#: Largest mesh file [bytes] (a binary STL of MAX_MESH_TRIANGLES is 50 MB).
MAX_MESH_BYTES = 64 * 1024 * 1024
#: Most triangles in a structure mesh.
MAX_MESH_TRIANGLES = 1_000_000
#: The fix named by every "cannot read mesh" found before trimesh reads the file.
_FIX = "check the file is a mesh (STL, OBJ, PLY)"
_PLY_ELEMENT = re.compile(rb"^element\s+(vertex|face)\s+(\d+)\s*$", re.MULTILINE)


def _first_line(exc: BaseException) -> str:
    """The first non-empty line of an exception's message (or its type name)."""
    lines = [s.strip() for s in str(exc).splitlines() if s.strip()]
    return lines[0] if lines else type(exc).__name__


def _too_many(p: Path, n: int, what: str = "triangles") -> ValueError:
    return ValueError(f"{p}: {n:,} {what}, more than the limit of {MAX_MESH_TRIANGLES:,} "
                      f"{'triangles ' if what != 'triangles' else ''}for a structure mesh; "
                      "simplify the mesh")


def _not_text(p: Path, data: bytes, binary: str = "") -> ValueError | None:
    """The error for mesh text that is not UTF-8 (``binary``: why it is not the binary
    form either), else None."""
    try:
        data.decode("utf-8")
    except UnicodeDecodeError as exc:
        why = f"{binary}not UTF-8 text" if binary else f"not UTF-8 text at byte {exc.start}"
        return ValueError(f"{p}: cannot read mesh ({why}); {_FIX}")
    return None


def check_mesh_file(p: Path, suffix: str) -> None:
    """What trimesh would choke on or spend too much memory on, checked first (the module
    docstring says what); a one-line ValueError naming the file."""
    size = p.stat().st_size
    if size > MAX_MESH_BYTES:
        raise ValueError(f"{p}: {size:,} bytes, more than the limit of "
                         f"{MAX_MESH_BYTES // 2**20} MiB for a structure mesh; simplify the mesh")
    with p.open("rb") as fh:
        head = fh.read(65536)
        if suffix == ".stl" and len(head) >= 84:
            n = int.from_bytes(head[80:84], "little")
            if 84 + 50 * n == size:  # binary (trimesh's test too): the header is enough
                if n > MAX_MESH_TRIANGLES:
                    raise _too_many(p, n)
                return
        data = head if suffix == ".ply" and b"format ascii" not in head else head + fh.read()
    if suffix == ".stl":
        binary = (f"not a binary STL: its header announces {n:,} triangles, {84 + 50 * n:,} "
                  f"bytes, the file has {size:,}; nor ASCII STL: " if size >= 84 else
                  "not a binary STL: shorter than its 84-byte header; nor ASCII STL: ")
        if err := _not_text(p, data, binary):
            raise err
        facets = sum(1 for _ in re.finditer(rb"(?i)endfacet", data))
        if facets > MAX_MESH_TRIANGLES:
            raise _too_many(p, facets)
    elif suffix == ".ply":
        header = head[:head.find(b"end_header")] if b"end_header" in head else b""
        for kind, count in _PLY_ELEMENT.findall(header):
            n = int(count)
            if n > (MAX_MESH_TRIANGLES if kind == b"face" else 3 * MAX_MESH_TRIANGLES):
                raise _too_many(p, n, "faces" if kind == b"face" else "vertices")
        if b"format ascii" in header and (err := _not_text(p, data)):
            raise err
    else:  # .obj: text
        if err := _not_text(p, data):
            raise err
        faces = data.count(b"\nf ") + data.startswith(b"f ")
        if faces > MAX_MESH_TRIANGLES:
            raise _too_many(p, faces)


def load_mesh(path: str | Path, *, require_watertight: bool = False) -> trimesh.Trimesh:
    """A triangle mesh read from ``path`` in its model frame (units as stored in the file)."""
    import trimesh
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
        check_mesh_file(p, suffix)
        loaded = trimesh.load_mesh(str(p), file_type=suffix[1:])
    except ValueError as exc:
        if str(exc).startswith(f"{p}: "):  # ours, already one line
            raise
        raise ValueError(f"{p}: cannot read mesh ({_first_line(exc)})") from None
    except Exception as exc:  # any parser failure is a user-file problem, reported in one line
        raise ValueError(f"{p}: cannot read mesh ({_first_line(exc)})") from None
    if not isinstance(loaded, trimesh.Trimesh):
        raise ValueError(f"{p}: file holds no triangle mesh")
    if len(loaded.faces) == 0:
        raise ValueError(f"{p}: mesh has no triangles")
    if len(loaded.faces) > MAX_MESH_TRIANGLES:
        raise _too_many(p, len(loaded.faces))
    loaded.remove_unreferenced_vertices()
    if not np.all(np.isfinite(loaded.vertices)):
        raise ValueError(f"{p}: mesh has non-finite vertex coordinates")
    loaded, repairs = repair_mesh(loaded)
    if len(loaded.faces) == 0:
        raise ValueError(f"{p}: mesh has no triangles of non-zero area")
    loaded.metadata["repairs"] = repairs
    if require_watertight:
        check_watertight(loaded, str(p))
    return loaded


def mesh_repairs(mesh: trimesh.Trimesh) -> MeshRepairs | None:
    """What :func:`load_mesh` repaired in ``mesh`` (None for a mesh not read by it)."""
    found = mesh.metadata.get("repairs")
    return found if isinstance(found, MeshRepairs) else None


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
