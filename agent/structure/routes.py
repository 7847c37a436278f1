"""Routes around a structure: the way to a far viewpoint when the straight line is blocked.

The planner's section-4.3 avoidance keeps a drone off the structure locally, but a straight
transit to a viewpoint behind a wall, under a deck or across a courtyard stops against it.
:class:`RouteGrid` is the free space of the mission box as a 26-connected grid of cells of
edge ``pitch`` [m]: a cell is free when its centre is at least ``margin + pitch`` from the
structure's solid (its filled voxels, by a Euclidean distance transform). A route is the
shortest grid path between the free cells nearest to the two ends (Dijkstra), shortened by
dropping every waypoint the previous one sees over free cells only. Positions [m; world ENU].
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

if TYPE_CHECKING:  # imported where used: loading them costs start-up time
    import trimesh
    from scipy.sparse import csr_matrix

Array = NDArray[np.float64]

#: Neighbour offsets of a 26-connected grid.
_OFFSETS = np.array([(i, j, k) for i in (-1, 0, 1) for j in (-1, 0, 1) for k in (-1, 0, 1)
                     if (i, j, k) != (0, 0, 0)], dtype=np.intp)


class RouteGrid:
    """Free cells of the box [lo, hi] [m] around a structure mesh, and routes through them."""

    def __init__(self, mesh: trimesh.Trimesh, lo: Array, hi: Array, margin: float,
                 pitch: float) -> None:
        from scipy.ndimage import distance_transform_edt
        self.lo = np.asarray(lo, dtype=np.float64)
        self.pitch = float(pitch)
        shape = np.maximum(np.ceil((np.asarray(hi) - self.lo) / pitch).astype(np.intp), 1)
        self.shape = tuple(int(x) for x in shape)
        solid = np.zeros(self.shape, dtype=np.bool_)
        pts = np.asarray(mesh.voxelized(pitch / 2.0).fill().points, dtype=np.float64)
        idx = self._index(pts)
        inside = np.all((idx >= 0) & (idx < shape), axis=1)
        solid[tuple(idx[inside].T)] = True
        clearance = distance_transform_edt(~solid) * pitch if solid.any() else \
            np.full(self.shape, np.inf)
        self._set_free(clearance >= margin + pitch)

    def _set_free(self, free: NDArray[np.bool_]) -> None:
        self.free = free
        self._cells = np.flatnonzero(self.free.reshape(-1))
        self._graph = self._build_graph()

    @classmethod
    def from_free(cls, lo: Array, pitch: float, free: NDArray[np.bool_]) -> RouteGrid:
        """The grid of free cells ``free`` (nx, ny, nz) of edge ``pitch`` [m] from ``lo``
        [m; world ENU], as built before (a prepared file's, :mod:`agent.world.prepared`)."""
        grid = cls.__new__(cls)
        grid.lo = np.asarray(lo, dtype=np.float64)
        grid.pitch = float(pitch)
        grid.shape = tuple(int(x) for x in free.shape)
        grid._set_free(np.asarray(free, dtype=np.bool_))
        return grid

    def _index(self, p: Array) -> NDArray[np.intp]:
        return np.floor((p - self.lo) / self.pitch).astype(np.intp)

    def centre(self, flat: NDArray[np.intp]) -> Array:
        """Centres (k, 3) [m] of cells given by flat indices."""
        ijk = np.stack(np.unravel_index(flat, self.shape), axis=1)
        return np.asarray(self.lo + (ijk + 0.5) * self.pitch, dtype=np.float64)

    def _build_graph(self) -> csr_matrix:
        from scipy.sparse import csr_matrix
        n = int(np.prod(self.shape))
        ijk = np.stack(np.unravel_index(self._cells, self.shape), axis=1)
        rows, cols, w = [], [], []
        for off in _OFFSETS:  # 26 neighbour directions, each vectorised over the cells
            nb = ijk + off
            ok = np.all((nb >= 0) & (nb < self.shape), axis=1)
            flat = np.ravel_multi_index(tuple(nb[ok].T), self.shape)
            good = self.free.reshape(-1)[flat]
            rows.append(self._cells[ok][good])
            cols.append(flat[good])
            w.append(np.full(int(good.sum()), self.pitch * float(np.linalg.norm(off))))
        return csr_matrix((np.concatenate(w), (np.concatenate(rows), np.concatenate(cols))),
                          shape=(n, n))

    def _nearest_free(self, p: Array) -> int:
        c = self.centre(self._cells)
        return int(self._cells[int(np.argmin(((c - p) ** 2).sum(axis=1)))])

    def segment_free(self, a: Array, b: Array) -> bool:
        """Whether the segment a → b [m] runs through free cells only (sampled every
        pitch/4, not within 1.5 pitch of either end, whose own cells may be near the
        structure; points outside the grid count as free: the mission box bounds them)."""
        length = float(np.linalg.norm(b - a))
        n = max(2, int(np.ceil(length / (self.pitch / 4.0))) + 1)
        s = np.linspace(0.0, length, n)
        s = s[(s > 1.5 * self.pitch) & (s < length - 1.5 * self.pitch)]
        pts = a[None, :] + (s / max(length, 1e-12))[:, None] * (b - a)[None, :]
        idx = self._index(pts)
        inside = np.all((idx >= 0) & (idx < self.shape), axis=1)
        return bool(self.free[tuple(idx[inside].T)].all())

    def route(self, a: Array, b: Array) -> Array:
        """Waypoints (k, 3) [m] from a to b, ending at b: just b when the straight segment is
        free (or no grid path exists), else the shortened grid path."""
        from scipy.sparse.csgraph import dijkstra
        if self._cells.size == 0 or self.segment_free(a, b):
            return np.asarray(b, dtype=np.float64)[None, :].copy()
        s, t = self._nearest_free(a), self._nearest_free(b)
        _, pred = dijkstra(self._graph, indices=s, return_predecessors=True)
        if pred[t] < 0 and s != t:
            return np.asarray(b, dtype=np.float64)[None, :].copy()
        path = [t]
        while path[-1] != s:  # walk back along the grid path (cells, not landmarks)
            path.append(int(pred[path[-1]]))
        pts = np.vstack([a[None, :], self.centre(np.asarray(path[::-1], dtype=np.intp)),
                         b[None, :]])
        out = []
        k = 0
        while k < pts.shape[0] - 1:  # string pulling: farthest waypoint seen over free cells
            nxt = pts.shape[0] - 1
            while nxt > k + 1 and not self.segment_free(pts[k], pts[nxt]):
                nxt -= 1
            out.append(pts[nxt])
            k = nxt
        return np.asarray(out, dtype=np.float64)
