"""Landmarks on a structure's surface: even (Poisson-disk) samples with outward normals.

:func:`sample_landmarks` draws uniform candidate points on the mesh in a few batches and
keeps a maximal subset in which no two landmarks are closer than ``spacing`` [m] (a
Poisson-disk set). Each batch is thinned at once by a randomised maximal independent set
(Luby's rounds, vectorised over candidates); later batches only fill the holes the earlier
ones left. Two points closer than ``spacing`` do not conflict when their normals differ by
more than 120° (opposite sides of a thin deck or wall), so both sides of thin parts get
landmarks.

Result: ``(q, u)`` of shape (m, 3) [m; world ENU] and unit outward normals, as in
:mod:`agent.core.landmarks`. Deterministic for a given ``seed``.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike, NDArray

if TYPE_CHECKING:  # imported where used: loading them costs start-up time
    import trimesh

Array = NDArray[np.float64]
Index = NDArray[np.intp]

#: Two landmarks closer than the spacing conflict only if ⟨u_i, u_j⟩ > this (within 120°).
CONFLICT_COS = -0.5
#: Candidate points drawn per batch, per spacing² of sampled surface area.
CANDIDATE_DENSITY = 6.0
#: Candidate batches (the first one sets the pattern; the others fill its holes).
BATCHES = 4


def outward_face_normals(mesh: trimesh.Trimesh) -> Array:
    """Unit face normals (F, 3); for a closed mesh oriented outwards (winding repaired)."""
    import trimesh
    if mesh.is_watertight and (not mesh.is_winding_consistent or mesh.volume < 0):
        fixed = mesh.copy()
        trimesh.repair.fix_normals(fixed)  # type: ignore[no-untyped-call]
        return np.asarray(fixed.face_normals, dtype=np.float64)
    return np.asarray(mesh.face_normals, dtype=np.float64)


def _region(region: tuple[ArrayLike, ArrayLike] | None) -> tuple[Array, Array]:
    """Box bounds (lo, hi) [m]; no region means the whole space."""
    if region is None:
        return np.full(3, -np.inf), np.full(3, np.inf)
    lo = np.asarray(region[0], dtype=np.float64).reshape(-1)
    hi = np.asarray(region[1], dtype=np.float64).reshape(-1)
    if lo.size != 3 or hi.size != 3 or np.any(lo > hi):
        raise ValueError(f"region must be (lo, hi) with three bounds each and lo <= hi, "
                         f"got {lo.tolist()}, {hi.tolist()}")
    return lo, hi


def _points_kept(q: Array, u: Array, z_min: float, lo: Array, hi: Array,
                 min_normal_z: float) -> NDArray[np.bool_]:
    """Which points pass the filters: z ≥ z_min, inside [lo, hi], u_z ≥ min_normal_z."""
    keep = (q[:, 2] >= z_min) & np.all(q >= lo, axis=1) & np.all(q <= hi, axis=1)
    return np.asarray(keep & (u[:, 2] >= min_normal_z), dtype=np.bool_)


def _conflicts(pairs: Index, u: Array, u_other: Array | None = None) -> Index:
    """The close pairs whose normals are within 120° of each other (real conflicts)."""
    other = u if u_other is None else u_other
    dots = (u[pairs[:, 0]] * other[pairs[:, 1]]).sum(axis=1)
    return np.asarray(pairs[dots > CONFLICT_COS], dtype=np.intp)


def maximal_independent_set(n: int, pairs: Index, rng: np.random.Generator) -> Index:
    """Indices of a maximal set of the n nodes with no two joined by an edge in ``pairs``.

    Luby's rounds: every live node with a lower random priority than all its live
    neighbours joins the set, and its neighbours leave. Vectorised over nodes and edges.
    """
    prio = rng.permutation(n)
    alive = np.ones(n, dtype=bool)
    chosen = np.zeros(n, dtype=bool)
    i, j = pairs[:, 0], pairs[:, 1]
    while alive.any():
        live = alive[i] & alive[j]
        i, j = i[live], j[live]
        beaten = np.zeros(n, dtype=bool)
        j_lower = prio[j] < prio[i]
        beaten[i[j_lower]] = True
        beaten[j[~j_lower]] = True
        win = alive & ~beaten
        chosen |= win
        alive &= ~win
        alive[i[win[j]]] = False
        alive[j[win[i]]] = False
    return np.flatnonzero(chosen)


def _face_weights(mesh: trimesh.Trimesh, normals: Array, zmin: float, lo: Array, hi: Array,
                  nzmin: float) -> Array:
    """Each face's area [m²] if it may hold a landmark that passes the filters, else 0."""
    tri = np.asarray(mesh.triangles, dtype=np.float64)
    face_ok = ((tri[:, :, 2].max(axis=1) >= zmin)
               & np.all(tri.max(axis=1) >= lo, axis=1) & np.all(tri.min(axis=1) <= hi, axis=1)
               & (normals[:, 2] >= nzmin))
    return np.where(face_ok, np.asarray(mesh.area_faces, dtype=np.float64), 0.0)


def sampled_area(
    mesh: trimesh.Trimesh,
    *,
    z_min: float | None = None,
    region: tuple[ArrayLike, ArrayLike] | None = None,
    min_normal_z: float | None = None,
) -> float:
    """The surface area [m²] :func:`sample_landmarks` draws from with these filters: about
    0.63 · area / spacing² landmarks are kept, from 24 · area / spacing² candidates (so a
    caller can bound the spacing before sampling)."""
    lo, hi = _region(region)
    return float(_face_weights(
        mesh, outward_face_normals(mesh),
        -np.inf if z_min is None else float(z_min), lo, hi,
        -np.inf if min_normal_z is None else float(min_normal_z)).sum())


def sample_landmarks(
    mesh: trimesh.Trimesh,
    spacing: float,
    *,
    seed: int = 0,
    z_min: float | None = None,
    region: tuple[ArrayLike, ArrayLike] | None = None,
    min_normal_z: float | None = None,
) -> tuple[Array, Array]:
    """Landmarks (q, u), each (m, 3), at least ``spacing`` [m] apart on the mesh surface.

    Filters: ``z_min`` keeps points with z ≥ z_min [m] (above the ground); ``region`` =
    (lo, hi) keeps points inside that axis-aligned box [m; world ENU] (mission space or
    region of interest); ``min_normal_z`` keeps normals with u_z ≥ it (−0.5: normals at most
    30° below horizontal; 0: nothing facing down). Points closer than ``spacing`` are allowed
    only with normals more than 120° apart; every surface point lies within about
    1.5·spacing of a landmark with a normal within 120° of its own.
    """
    import trimesh
    from scipy.spatial import cKDTree
    if not (np.isfinite(spacing) and spacing > 0):
        raise ValueError(f"spacing must be a positive finite distance [m], got {spacing}")
    lo, hi = _region(region)
    zmin = -np.inf if z_min is None else float(z_min)
    nzmin = -np.inf if min_normal_z is None else float(min_normal_z)
    normals = outward_face_normals(mesh)
    weight = _face_weights(mesh, normals, zmin, lo, hi, nzmin)
    area = float(weight.sum())
    if not area > 0.0:
        return np.zeros((0, 3)), np.zeros((0, 3))
    rng = np.random.default_rng(seed)
    per_batch = int(np.ceil(CANDIDATE_DENSITY * area / spacing**2)) + 16
    q, u = np.zeros((0, 3)), np.zeros((0, 3))
    for _ in range(BATCHES):
        cand, face = trimesh.sample.sample_surface(mesh, per_batch, face_weight=weight, seed=rng)
        cand = np.asarray(cand, dtype=np.float64)
        cu = normals[face]
        keep = _points_kept(cand, cu, zmin, lo, hi, nzmin)
        if q.shape[0]:
            near = cKDTree(cand).sparse_distance_matrix(
                cKDTree(q), spacing, output_type="ndarray")
            pairs = np.column_stack([near["i"], near["j"]]).astype(np.intp)
            keep[_conflicts(pairs, cu, u)[:, 0]] = False
        cand, cu = cand[keep], cu[keep]
        if cand.shape[0] == 0:
            continue
        pairs = cKDTree(cand).query_pairs(spacing, output_type="ndarray").astype(np.intp)
        pick = maximal_independent_set(cand.shape[0], _conflicts(pairs.reshape(-1, 2), cu), rng)
        q, u = np.vstack([q, cand[pick]]), np.vstack([u, cu[pick]])
    return q, u
