"""Clearance to the structure: closest mesh points as obstacles for section 4.3.

Collision avoidance (:mod:`agent.core.avoidance`) takes obstacles as unit normals ŵ_i
pointing away from the obstacle and distances d_i [m] (λ_i = −d_i / D_w in smooth mode,
eq. 4.10). For a mesh, an obstacle is a nearby surface patch: ŵ = (p − c)/‖p − c‖ for the
closest point c of that patch and d = ‖p − c‖ − margin, where ``margin`` [m] is the distance
the agent must keep from the structure (as R_s is for other agents).

A single closest point is not enough in a concave corner (two walls at once), so
:meth:`MeshClearance.obstacles` returns every local minimum of the distance over the surface
within a radius (the closest point of a nearby triangle, unless a neighbouring triangle
through that point comes closer: that drops the spurious edge points of a flat wall split
into triangles), thinned to the nearest one per direction cone.

:class:`MeshClearance` snapshots the triangles and their R-tree (package ``rtree``) once;
each query is then a box query plus vectorised point-triangle distances.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike, NDArray

from agent.structure.solid import Winding

if TYPE_CHECKING:  # imported where used: loading them costs start-up time
    import trimesh

Array = NDArray[np.float64]
Mask = NDArray[np.bool_]

#: Two nearby-triangle obstacles whose normals ŵ are closer than this angle [rad] are merged.
MERGE_ANGLE = np.deg2rad(20.0)
#: Most mesh obstacles returned by :func:`structure_obstacles` (keeps problem 4.11 small).
MAX_OBSTACLES = 6


@dataclass(frozen=True)
class ClosestPoints:
    """Closest mesh points to query positions, rows matching the queries [m; world ENU]."""

    point: Array  #: closest point c on the mesh (n, 3) [m]
    distance: Array  #: ‖p − c‖ (n,) [m], negative inside (winding number ≥ 1/2)
    direction: Array  #: outward unit direction (n, 3): (p − c)/‖p − c‖, flipped inside
    face: NDArray[np.intp]  #: index of the triangle holding c (n,)


def _rows_dot(a: Array, b: Array) -> Array:
    """Row-wise ⟨a, b⟩ of (k, 3) arrays."""
    return np.asarray(np.einsum("ij,ij->i", a, b), dtype=np.float64)


def closest_on_triangles(tri: Array, p: Array) -> Array:
    """Closest point (k, 3) [m] of each triangle tri (k, 3, 3) to p (3,) or to rows p (k, 3).

    Inside the triangle (barycentric test) the projection onto its plane, else the nearest
    of the three edge points (each the projection onto the edge clamped to its ends).
    """
    a = tri[:, 0]
    e0, e1 = tri[:, 1] - a, tri[:, 2] - a
    r = p - a
    d00, d01, d11 = _rows_dot(e0, e0), _rows_dot(e0, e1), _rows_dot(e1, e1)
    d0, d1 = _rows_dot(r, e0), _rows_dot(r, e1)
    det = d00 * d11 - d01 * d01
    ok = det > 0.0
    det = np.where(ok, det, 1.0)
    s, t = (d11 * d0 - d01 * d1) / det, (d00 * d1 - d01 * d0) / det
    inside = ok & (s >= 0.0) & (t >= 0.0) & (s + t <= 1.0)
    best = a + s[:, None] * e0 + t[:, None] * e1
    if inside.all():
        return best
    best_d2 = np.where(inside, -1.0, np.inf)
    for s0, e in ((a, e0), (a, e1), (tri[:, 1], e1 - e0)):  # the three edges, vectorised
        ee = _rows_dot(e, e)
        h = np.clip(_rows_dot(p - s0, e) / np.where(ee > 0.0, ee, 1.0), 0.0, 1.0)
        q = s0 + h[:, None] * e
        gap = p - q
        d2 = _rows_dot(gap, gap)
        better = d2 < best_d2
        best = np.where(better[:, None], q, best)
        best_d2 = np.where(better, d2, best_d2)
    return best


def _unit_or(v: Array, dist: Array, fallback: Array) -> Array:
    """Rows v / dist, or the fallback rows where dist is 0."""
    pos = dist > 0.0
    return np.where(pos[:, None], v / np.where(pos, dist, 1.0)[:, None], fallback)


def _vertex_neighbours(faces: NDArray[np.intp]) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
    """CSR (indptr (F+1,), indices) of the triangles sharing at least one vertex with each."""
    n_faces = faces.shape[0]
    corner_face = np.repeat(np.arange(n_faces), 3)
    order = np.argsort(faces.ravel(), kind="stable")
    vert, face = faces.ravel()[order], corner_face[order]
    first = np.flatnonzero(np.concatenate([[True], vert[1:] != vert[:-1]]))
    size = np.diff(np.append(first, vert.size))
    group_size = np.repeat(size, size)  # for every corner, the size of its vertex's group
    group_first = np.repeat(first, size)
    a = np.repeat(face, group_size)
    offset = np.arange(int(group_size.sum())) - np.repeat(np.cumsum(group_size) - group_size,
                                                        group_size)
    b = face[np.repeat(group_first, group_size) + offset]
    key = np.sort(a * n_faces + b)
    key = key[np.concatenate([[True], key[1:] != key[:-1]])]  # unique pairs
    a, b = key // n_faces, key % n_faces
    return np.searchsorted(a, np.arange(n_faces + 1)), b


class MeshClearance:
    """Distance queries against one structure mesh (the mesh must not change after)."""

    def __init__(self, mesh: trimesh.Trimesh, winding: Winding | None = None) -> None:
        self.tri = np.ascontiguousarray(mesh.triangles, dtype=np.float64)  # (F, 3, 3) [m]
        self.normal = np.ascontiguousarray(mesh.face_normals, dtype=np.float64)  # (F, 3)
        self.lo = self.tri.min(axis=1)
        self.hi = self.tri.max(axis=1)
        self.tree = mesh.triangles_tree  # R-tree over triangle bounding boxes
        #: Length tolerance [m]: ties and "point on triangle" tests.
        self.tol = 1e-9 * max(1.0, float(np.abs(self.tri).max()))
        self._ring_ptr, self._ring = _vertex_neighbours(np.asarray(mesh.faces, dtype=np.intp))
        #: Inside or outside: the generalised winding number (right for overlapping parts).
        self.winding = winding if winding is not None else Winding(mesh)

    def _neighbour_pairs(self, faces: NDArray[np.intp]) -> tuple[NDArray[np.intp],
                                                                  NDArray[np.intp]]:
        """(i, f): position i in ``faces`` and each triangle f sharing a vertex with faces[i]."""
        start, stop = self._ring_ptr[faces], self._ring_ptr[faces + 1]
        count = stop - start
        i = np.repeat(np.arange(faces.size), count)
        offset = np.arange(int(count.sum())) - np.repeat(np.cumsum(count) - count, count)
        return i, self._ring[np.repeat(start, count) + offset]

    def _in_box(self, p: Array, half: float) -> NDArray[np.intp]:
        """Triangles whose bounding boxes meet the cube p ± half [m]."""
        bounds = np.concatenate([p - half, p + half])
        return np.fromiter(self.tree.intersection(bounds), dtype=np.intp)

    def _closest_on(self, faces: NDArray[np.intp], p: Array) -> tuple[Array, Array, Array]:
        """Closest points c (k, 3) on the given triangles to p (3,), p − c, and ‖p − c‖ [m]."""
        c = closest_on_triangles(self.tri[faces], p)
        diff = p - c
        return c, diff, np.sqrt((diff * diff).sum(axis=1))

    def _closest_one(self, p: Array) -> tuple[Array, float, Array, int]:
        """(c, signed distance, outward direction, face) for one position p (3,) [m]."""
        count, point_box = 16, np.concatenate([p, p])
        while True:  # widen the R-tree's nearest-box query until no box left can be nearer
            faces = np.fromiter(self.tree.nearest(point_box, count), dtype=np.intp)
            c, diff, dist = self._closest_on(faces, p)
            if faces.size < count or faces.size >= self.tri.shape[0]:
                break
            gap = np.maximum(np.maximum(self.lo[faces] - p, p - self.hi[faces]), 0.0)
            if float(np.sqrt(_rows_dot(gap, gap)).max()) >= float(dist.min()):
                break
            count *= 4
        tie = dist <= dist.min() + self.tol
        # Among equally near triangles (an edge or vertex) the one facing p gives ŵ on it.
        facing = np.where(tie, (diff * self.normal[faces]).sum(axis=1), -np.inf)
        k = int(np.argmax(facing))
        n = self.normal[faces[k]]
        # The side from the winding number, not from that triangle's normal: the nearest
        # face may belong to another part that p is inside (a roof set into a body).
        inside = dist[k] > self.tol and bool(self.winding.inside(p[None, :])[0])
        w = _unit_or(diff[k:k + 1], dist[k:k + 1], n[None, :])[0]
        return c[k], (-1.0 if inside else 1.0) * float(dist[k]), -w if inside else w, int(faces[k])

    def closest(self, p: ArrayLike) -> ClosestPoints:
        """Closest mesh points to positions p (3,) or (n, 3) [m; world ENU] (n = few agents)."""
        pts = np.asarray(p, dtype=np.float64).reshape(-1, 3)
        c, w = np.empty_like(pts), np.empty_like(pts)
        dist, face = np.empty(pts.shape[0]), np.empty(pts.shape[0], dtype=np.intp)
        for i in range(pts.shape[0]):  # one query per agent position
            c[i], dist[i], w[i], face[i] = self._closest_one(pts[i])
        return ClosestPoints(c, dist, w, face)

    def nearer_than(self, p: ArrayLike, d: float, block: int = 1 << 20) -> Mask:
        """For positions p (n, 3) [m; world ENU]: whether some point of the surface lies
        closer than ``d`` [m] (unsigned distance < d; the same closest points as
        :meth:`closest`). Vectorised: the R-tree's bulk box query gives every triangle whose
        box meets the cube p ± d, then point-triangle distances for those pairs only, in
        blocks of about ``block`` pairs."""
        pts = np.asarray(p, dtype=np.float64).reshape(-1, 3)
        out = np.zeros(pts.shape[0], dtype=np.bool_)
        step = max(1, block // 64)
        for a in range(0, pts.shape[0], step):  # blocks of points, for memory
            sub = pts[a:a + step]
            faces, counts = self.tree.intersection_v(sub - d, sub + d)
            faces = np.asarray(faces, dtype=np.intp)
            row = np.repeat(np.arange(sub.shape[0]), np.asarray(counts, dtype=np.intp))
            if faces.size == 0:
                continue
            c = closest_on_triangles(self.tri[faces], sub[row])
            diff = sub[row] - c
            close = np.sqrt((diff * diff).sum(axis=1)) < d
            out[a + row[close]] = True
        return out

    def obstacles(
        self,
        p: ArrayLike,
        radius: float,
        margin: float = 0.0,
        *,
        merge_angle: float = MERGE_ANGLE,
        max_count: int = MAX_OBSTACLES,
    ) -> tuple[Array, Array]:
        """Obstacles (ŵ (k, 3), d (k,)) of the surface within ``radius`` [m] of p (3,) [m].

        ŵ_i = (p − c_i)/‖p − c_i‖ (unit, away from the structure; the triangle's normal when
        p is on it) and d_i = ‖p − c_i‖ − margin [m] for every local minimum c_i of the
        distance closer than ``radius`` (use radius ≥ margin + D_w for smooth avoidance);
        nearest first; one per ``merge_angle`` [rad] cone; at most ``max_count``. Shapes as
        :func:`agent.core.avoidance.obstacle_distances` returns them, ready to stack.
        """
        pa = np.asarray(p, dtype=np.float64).reshape(3)
        faces = self._in_box(pa, radius)
        c, diff, dist = self._closest_on(faces, pa)
        near = dist < radius
        faces, c, diff, dist = faces[near], c[near], diff[near], dist[near]
        if faces.size == 0:
            return np.zeros((0, 3)), np.zeros(0)
        # Local minima: drop c_a when a triangle b sharing a vertex with a passes through c_a
        # and comes closer (on a conforming mesh only such b can pass through c_a).
        a, nb = self._neighbour_pairs(faces)
        local = np.full(self.tri.shape[0], -1, dtype=np.intp)
        local[faces] = np.arange(faces.size)
        b = local[nb]
        sel = b >= 0
        a, b = a[sel], b[sel]
        sel = dist[b] < dist[a] - self.tol
        a, b = a[sel], b[sel]
        if a.size:
            on_b = closest_on_triangles(self.tri[faces[b]], c[a])
            gap = np.sqrt(((on_b - c[a]) ** 2).sum(axis=1))
            dominated = np.zeros(faces.size, dtype=bool)
            dominated[a[gap <= self.tol]] = True
            keep_min = ~dominated
            faces, diff, dist = faces[keep_min], diff[keep_min], dist[keep_min]
        order = np.argsort(dist, kind="stable")
        d = dist[order]
        w = _unit_or(diff[order], d, self.normal[faces[order]])
        cos_merge = np.cos(merge_angle)
        left = np.ones(d.size, dtype=bool)
        keep: list[int] = []
        while left.any() and len(keep) < max_count:  # one pass per kept obstacle (≤ max_count)
            k = int(np.argmax(left))  # the nearest one not yet merged
            keep.append(k)
            left &= w @ w[k] <= cos_merge
            left[k] = False
        idx = np.array(keep, dtype=np.intp)
        return w[idx], d[idx] - margin

    def max_step(
        self,
        p: ArrayLike,
        direction: ArrayLike,
        margin: float,
        max_step: float,
        *,
        tol: float = 1e-3,
        max_iter: int = 32,
    ) -> float:
        """A step α ∈ [0, max_step] [m] such that p + s·dir, s ∈ [0, α], stays ≥ margin away.

        Conservative advancement (sphere tracing): advance by the clearance − margin until it
        is within ``tol`` [m] of the margin, ``max_step`` is reached or ``max_iter`` queries
        are spent. Every α returned is safe; near grazing incidence it may be short.
        """
        pa = np.asarray(p, dtype=np.float64).reshape(3)
        dvec = np.asarray(direction, dtype=np.float64).reshape(3)
        norm = float(np.sqrt(dvec @ dvec))
        if norm == 0.0:
            return 0.0
        dvec = dvec / norm
        alpha = 0.0
        for _ in range(max_iter):  # one closest-point query per advance (not per landmark)
            gap = self._closest_one(pa + alpha * dvec)[1] - margin
            if gap <= tol:
                break
            alpha = min(alpha + gap, max_step)
            if alpha >= max_step:
                break
        return alpha
