"""Inside, outside and reachable, for meshes of parts that touch or overlap, and open scans.

*Inside* is decided by the generalised winding number (Jacobson, Kavan and Sorkine-Hornung,
SIGGRAPH 2013): w(p) = Σ_f Ω_f(p) / 4π over the triangles' signed solid angles, about 1
inside one closed part, 2 inside an overlap of two, 0 outside, and a smooth in-between
near the holes of an open scan; p is inside the structure when w(p) ≥ 1/2. Unlike the
nearest face's normal or ray parity it is right inside overlaps, under coincident faces and
next to holes. It is evaluated by libigl's fast winding number (a Barnes-Hut tree over the
triangles, exact in the near field).

*Reachable* is the free space a drone can fly to from outside: a grid of cells of edge
``pitch`` [m] over the structure's bounding box (padded), where every cell the surface
passes through is a wall (the surface is sampled at most pitch/2.5 apart, so no 6-connected
path of free cells crosses it); the free cells connected to the box's border are the
outside; every other component of free cells is *enclosed*: solid (its winding number ≥ 1/2)
or a closed cavity no drone can enter.

A landmark (q, u) is *buried* when its point lifted off the surface, q + lift·u, is inside
(a face inside another part, or between two touching parts), and *faces a cavity* when the
free space in front of it (along u, with a clear line from the landmark) is an enclosed
component (the nearest free cell in front of it that it sees). Neither can ever be imaged.
All positions [m; world ENU].
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

if TYPE_CHECKING:
    import trimesh

Array = NDArray[np.float64]
Mask = NDArray[np.bool_]
SegmentClear = Callable[[Array, Array], Mask]

#: Most cells in the free-space grid (its pitch grows past the asked one beyond this).
MAX_CELLS = 1 << 23
#: Surface samples per cell edge: samples at most pitch / SAMPLES_PER_CELL apart.
SAMPLES_PER_CELL = 2.5
#: The free space a landmark faces is looked for in the cells at most this many cells away
#: on each axis, the nearest PROBE_TRIES of them tried for a clear line of sight.
PROBE_REACH = 2
PROBE_TRIES = 8
#: Hidden-surface codes of :meth:`Solid.hidden` (0: neither).
BURIED, CAVITY = 4, 5
#: Cell classes of :meth:`Solid.cell_class`.
OUTSIDE, WALL, SOLID, HOLLOW = 0, 1, 2, 3


class Winding:
    """The generalised winding number of one mesh (the mesh must not change after)."""

    def __init__(self, mesh: trimesh.Trimesh) -> None:
        import igl

        self._bvh = igl.FastWindingNumberBVH()
        self._bvh.init(np.ascontiguousarray(mesh.vertices, dtype=np.float64),
                       np.ascontiguousarray(mesh.faces, dtype=np.int64), 2)

    def __call__(self, points: Array) -> Array:
        """w(p) (n,) for points (n, 3) [m; world ENU]: ~1 inside a part, ~0 outside."""
        pts = np.ascontiguousarray(np.asarray(points, dtype=np.float64).reshape(-1, 3))
        if pts.shape[0] == 0:
            return np.zeros(0)
        return np.asarray(self._bvh.winding_number(pts), dtype=np.float64)

    def inside(self, points: Array) -> Mask:
        """Points (n, 3) [m] inside the structure: w ≥ 1/2 (overlaps count once)."""
        return np.asarray(self(points) >= 0.5, dtype=np.bool_)


def surface_samples(tri: Array, spacing: float) -> Array:
    """Points (k, 3) [m] on triangles (F, 3, 3): a barycentric lattice per triangle, its
    neighbours at most ``spacing`` apart (corners included). Triangles are grouped by their
    number of divisions (few distinct values), each group one vectorised product."""
    edge = np.linalg.norm(tri - np.roll(tri, -1, axis=1), axis=2).max(axis=1)
    n = np.maximum(np.ceil(edge / spacing), 1).astype(np.int64)  # divisions per triangle
    out = []
    for d in np.unique(n):  # one lattice per division count, not per triangle
        i, j = np.nonzero(np.add.outer(np.arange(d + 1), np.arange(d + 1)) <= d)
        st = np.stack([i, j], axis=1) / float(d)  # (L, 2) barycentric (s, t)
        group = tri[n == d]
        a = group[:, 0]
        e = np.stack([group[:, 1] - a, group[:, 2] - a], axis=1)  # (g, 2, 3)
        out.append((a[:, None, :] + np.einsum("lk,gkc->glc", st, e)).reshape(-1, 3))
    return np.concatenate(out) if out else np.zeros((0, 3))


class Solid:
    """Inside, reachable free space, and hidden surface of one structure mesh."""

    def __init__(self, mesh: trimesh.Trimesh, pitch: float, segment_clear: SegmentClear,
                 winding: Winding | None = None) -> None:
        from scipy import ndimage

        if not (np.isfinite(pitch) and pitch > 0):
            raise ValueError(f"pitch must be a positive distance [m], got {pitch}")
        self.winding = winding if winding is not None else Winding(mesh)
        self.segment_clear = segment_clear
        lo, hi = (np.asarray(b, dtype=np.float64) for b in mesh.bounds)
        volume = float(np.prod(hi - lo + 4.0 * pitch))
        self.pitch = max(float(pitch), (volume / MAX_CELLS) ** (1.0 / 3.0))
        self.lo = lo - 2.0 * self.pitch
        self.shape = tuple(int(s) for s in np.ceil((hi + 2.0 * self.pitch - self.lo)
                                                   / self.pitch).astype(np.int64) + 1)
        tri = np.asarray(mesh.triangles, dtype=np.float64)
        wall = np.zeros(self.shape, dtype=np.bool_)
        cells = self._cells(surface_samples(tri, self.pitch / SAMPLES_PER_CELL))
        wall[cells[:, 0], cells[:, 1], cells[:, 2]] = True
        label, count = ndimage.label(~wall)
        outer = label[0, 0, 0]
        # One winding number per enclosed component (at its first cell) tells solid from
        # hollow; a component's cells lie all inside or all outside (no wall between).
        first = ndimage.minimum_position(label, label, np.arange(1, count + 1)) if count else []
        centres = self.lo + np.asarray(first, dtype=np.float64).reshape(-1, 3) * self.pitch \
            + 0.5 * self.pitch
        solid = np.concatenate([[False], self.winding.inside(centres)])
        kind = np.where(solid, SOLID, HOLLOW).astype(np.int8)
        kind[0], kind[outer] = WALL, OUTSIDE
        self.cls = kind[label]  # (nx, ny, nz) cell classes
        self.hollow_cells = int((self.cls == HOLLOW).sum())

    def _cells(self, points: Array) -> NDArray[np.int64]:
        """Grid indices (n, 3) of points (n, 3) [m], clipped to the grid."""
        idx = np.floor((points - self.lo) / self.pitch).astype(np.int64)
        return np.asarray(np.clip(idx, 0, np.asarray(self.shape) - 1), dtype=np.int64)

    def cell_class(self, points: Array) -> NDArray[np.int8]:
        """OUTSIDE, WALL (the surface passes through the cell), SOLID or HOLLOW per point
        (n, 3) [m]; points beyond the grid are OUTSIDE."""
        pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        idx = np.floor((pts - self.lo) / self.pitch).astype(np.int64)
        beyond = np.any((idx < 0) | (idx >= np.asarray(self.shape)), axis=1)
        idx = np.clip(idx, 0, np.asarray(self.shape) - 1)
        out = self.cls[idx[:, 0], idx[:, 1], idx[:, 2]]
        return np.asarray(np.where(beyond, OUTSIDE, out), dtype=np.int8)

    def reachable(self, points: Array) -> Mask:
        """Points (n, 3) [m] in free space connected to the outside: in an outside cell,
        or in a wall cell and not inside (w < 1/2; a cavity thinner than a cell is not
        told from the outside there)."""
        pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        cls = self.cell_class(pts)
        out = cls == OUTSIDE
        at_wall = np.flatnonzero(cls == WALL)
        if at_wall.size:
            out[at_wall] = ~self.winding.inside(pts[at_wall])
        return np.asarray(out, dtype=np.bool_)

    def _free_in_front(self, start: Array, u: Array) -> NDArray[np.int8]:
        """Per point (n, 3) [m] off the surface, not inside, with normal u: the class of the
        nearest outside or hollow cell within PROBE_REACH cells, in front of it (along u)
        and seen from it (a clear segment); WALL when there is none."""
        n = start.shape[0]
        r = np.arange(-PROBE_REACH, PROBE_REACH + 1)
        off = np.stack(np.meshgrid(r, r, r, indexing="ij"), axis=-1).reshape(-1, 3)
        base = np.floor((start - self.lo) / self.pitch).astype(np.int64)
        centre = self.lo + (base[:, None, :] + off[None, :, :] + 0.5) * self.pitch  # (n, O, 3)
        gap = centre - start[:, None, :]
        cls = self.cell_class(centre.reshape(-1, 3)).reshape(n, -1)
        # The point is not inside (not buried): the free space it is in is outside or hollow.
        ok = ((cls == OUTSIDE) | (cls == HOLLOW)) & (np.einsum("noc,nc->no", gap, u) > 0.0)
        dist = np.where(ok, np.einsum("noc,noc->no", gap, gap), np.inf)
        order = np.argsort(dist, axis=1)[:, :PROBE_TRIES]  # nearest few candidates each
        rows = np.repeat(np.arange(n), order.shape[1])
        cols = order.reshape(-1)
        live = np.isfinite(dist[rows, cols])
        seen = np.zeros(rows.size, dtype=np.bool_)
        if live.any():
            seen[live] = self.segment_clear(start[rows[live]], centre[rows[live], cols[live]])
        clear = seen.reshape(n, -1)
        first = np.argmax(clear, axis=1)
        found = cls[np.arange(n), order[np.arange(n), first]]
        return np.asarray(np.where(clear.any(axis=1), found, WALL), dtype=np.int8)

    def hidden(self, q: Array, u: Array, lift: float) -> NDArray[np.int8]:
        """Per landmark (q, u) (m, 3): BURIED when q + lift·u is inside the structure,
        CAVITY when the nearest free cell in front of it, seen from q + lift·u, is hollow,
        else 0."""
        q = np.asarray(q, dtype=np.float64).reshape(-1, 3)
        u = np.asarray(u, dtype=np.float64).reshape(-1, 3)
        m = q.shape[0]
        out = np.zeros(m, dtype=np.int8)
        if m == 0:
            return out
        start = q + lift * u
        buried = self.winding.inside(start)
        out[buried] = BURIED
        if self.hollow_cells == 0:
            return out
        rows = np.flatnonzero(~buried)
        facing = self._free_in_front(start[rows], u[rows])
        out[rows[facing == HOLLOW]] = CAVITY
        return out
