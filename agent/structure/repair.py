"""Meshes as CAD exports and scans come: cleaned and oriented before anything reads them.

A field team's mesh is rarely one clean closed body. It is often several closed parts that
touch or overlap (an assembly), or an open scan; it may carry zero-area triangles, the same
triangle twice, vertices split at every face (OBJ exports with per-face normals), and
triangles wound the wrong way. :func:`repair_mesh` makes it fit for the winding number
(:mod:`agent.structure.solid`) and for outward landmark normals:

1. vertices at the same position merged; zero-area and repeated triangles dropped;
2. each connected part wound consistently (every interior edge run in opposite directions
   by its two triangles: a parity labelling of the face-adjacency graph, vectorised);
3. each part turned outwards: its triangles flipped when its signed volume about its own
   centroid is negative (the volume for a closed part; for an open scan, the side its
   surface encloses most). A flat open sheet (volume about zero) is left as it is.

Parts are *not* merged or cut: where parts overlap, the faces inside another part stay,
and the winding number later tells they are buried. Every fix is counted in
:class:`MeshRepairs`, which ``viscover scenario check`` prints.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from agent.structure.solid import Winding

if TYPE_CHECKING:
    import trimesh

Array = NDArray[np.float64]
Index = NDArray[np.intp]

#: A part whose |signed volume| is below this fraction of (its area × its extent) is flat:
#: its orientation is left as it is.
FLAT_VOLUME = 1e-6


@dataclass(frozen=True)
class MeshRepairs:
    """What :func:`repair_mesh` found and fixed in one mesh."""

    parts: int  #: connected parts after the repair
    closed_parts: int  #: of them, closed (watertight) ones
    merged_vertices: int  #: vertices merged into another at the same position
    degenerate_faces: int  #: zero-area triangles dropped
    duplicate_faces: int  #: repeated triangles dropped
    rewound_faces: int  #: triangles re-wound to agree with their part
    flipped_parts: int  #: parts turned outwards

    def line(self) -> str:
        """One line: the parts, then each fix made (or that none was needed)."""
        open_parts = self.parts - self.closed_parts
        kinds = f"{self.closed_parts} closed" + (f", {open_parts} open" if open_parts else "")
        fixes = [f"{n} {what}" for n, what in (
            (self.merged_vertices, "duplicate vertices merged"),
            (self.degenerate_faces, "degenerate triangles dropped"),
            (self.duplicate_faces, "repeated triangles dropped"),
            (self.rewound_faces, "triangles re-wound"),
            (self.flipped_parts, "parts turned outwards")) if n]
        return (f"{self.parts} part{'s' if self.parts != 1 else ''} ({kinds}); "
                + ("repaired: " + ", ".join(fixes) if fixes else "no repair needed"))


def _directed(faces: Index, a: Index, b: Index, f: Index) -> NDArray[np.bool_]:
    """Whether triangle faces[f] runs its edge from vertex a to vertex b (rows)."""
    tri = faces[f]
    nxt = np.roll(tri, -1, axis=1)
    return np.asarray(((tri == a[:, None]) & (nxt == b[:, None])).any(axis=1), dtype=np.bool_)


def winding_flips(faces: Index, pairs: Index, edges: Index) -> tuple[Index, Index]:
    """(flip, part): which triangles to re-wind (F,) in {0, 1} so that every adjacent pair
    (pairs (k, 2), sharing the vertex pair ``edges`` (k, 2)) runs its edge in opposite
    directions, and the connected part (F,) of each triangle. Parity labelling of one
    breadth-first spanning forest, by pointer jumping (no loop over triangles or parts)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import breadth_first_order, connected_components

    n = faces.shape[0]
    a, b = edges[:, 0], edges[:, 1]
    same = _directed(faces, a, b, pairs[:, 0]) == _directed(faces, a, b, pairs[:, 1])
    _, part = connected_components(
        coo_matrix((np.ones(pairs.shape[0]), (pairs[:, 0], pairs[:, 1])), shape=(n, n)),
        directed=False)
    roots = np.unique(part, return_index=True)[1]
    # Edge values 1 (opposite: consistent) or 2 (alike); a super-root n joins every part.
    i = np.concatenate([pairs[:, 0], np.full(roots.size, n)])
    j = np.concatenate([pairs[:, 1], roots])
    val = np.concatenate([1.0 + same, np.ones(roots.size)])
    sym = coo_matrix((np.concatenate([val, val]), (np.concatenate([i, j]),
                                                   np.concatenate([j, i]))),
                     shape=(n + 1, n + 1)).tocsr()  # duplicates summed: only read for BFS
    _, pred = breadth_first_order(sym, n, directed=False)
    up = np.asarray(pred[:n], dtype=np.intp)
    up = np.where(up == n, np.arange(n), up)  # each part's root points to itself
    node = np.flatnonzero(up != np.arange(n))
    acc = np.zeros(n, dtype=np.int8)
    if node.size:  # the tree edge (node, up[node]) runs its shared edge alike: parity 1
        key = np.concatenate([i * (n + 1) + j, j * (n + 1) + i])
        alike = np.concatenate([val, val]) == 2.0
        order = np.argsort(key, kind="stable")
        at = order[np.searchsorted(key, node * (n + 1) + up[node], sorter=order)]
        acc[node] = alike[at].astype(np.int8)
    while True:  # pointer jumping: acc[i] = parity of the path from i to up[i]
        nxt = up[up]
        if np.array_equal(nxt, up):
            break
        acc ^= acc[up]
        up = nxt
    return acc.astype(np.intp), np.asarray(part, dtype=np.intp)


def _part_volumes(tri: Array, part: Index, count: int) -> tuple[Array, Array, Array]:
    """Per part: signed volume about its own centroid [m³], area [m²], extent [m]."""
    area2 = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])  # 2·area·n
    area = 0.5 * np.linalg.norm(area2, axis=1)
    centre = tri.mean(axis=1)
    w = np.maximum(np.bincount(part, weights=area, minlength=count), 1e-300)
    c = np.stack([np.bincount(part, weights=area * centre[:, k], minlength=count)
                  for k in range(3)], axis=1) / w[:, None]
    rel = tri - c[part][:, None, :]
    vol = np.einsum("ij,ij->i", rel[:, 0], np.cross(rel[:, 1], rel[:, 2])) / 6.0
    lo = np.full((count, 3), np.inf)
    hi = np.full((count, 3), -np.inf)
    np.minimum.at(lo, part, tri.min(axis=1))
    np.maximum.at(hi, part, tri.max(axis=1))
    extent = np.asarray(np.linalg.norm(hi - lo, axis=1), dtype=np.float64)
    return (np.asarray(np.bincount(part, weights=vol, minlength=count), dtype=np.float64),
            np.asarray(w, dtype=np.float64), extent)


def repair_mesh(mesh: trimesh.Trimesh) -> tuple[trimesh.Trimesh, MeshRepairs]:
    """A cleaned, consistently wound, outward-facing copy of ``mesh`` and what was fixed
    (the module docstring says what and in which order)."""
    import trimesh as tm

    vertices = np.asarray(mesh.vertices, dtype=np.float64)
    faces = np.asarray(mesh.faces, dtype=np.intp)
    out = tm.Trimesh(vertices=vertices, faces=faces, process=False)
    n_vertices = len(out.vertices)
    out.merge_vertices(merge_tex=True, merge_norm=True)
    merged = n_vertices - len(out.vertices)
    keep = out.nondegenerate_faces()
    degenerate = int((~keep).sum())
    out.update_faces(keep)
    n_faces = len(out.faces)
    out.update_faces(out.unique_faces())
    duplicate = n_faces - len(out.faces)
    out.remove_unreferenced_vertices()
    faces = np.asarray(out.faces, dtype=np.intp).copy()
    pairs = np.asarray(out.face_adjacency, dtype=np.intp).reshape(-1, 2)
    edges = np.asarray(out.face_adjacency_edges, dtype=np.intp).reshape(-1, 2)
    flip, part = winding_flips(faces, pairs, edges)
    count = int(part.max()) + 1 if part.size else 0
    # Re-wind the smaller side of each part's parity classes (fewest triangles changed).
    ones = np.bincount(part, weights=flip, minlength=count)
    size = np.bincount(part, minlength=count)
    minority = (ones > size / 2.0)[part]
    rewind = flip.astype(bool) != minority
    faces[rewind] = faces[rewind][:, ::-1]
    tri = np.asarray(out.vertices, dtype=np.float64)[faces]
    vol, area, extent = _part_volumes(tri, part, count)
    inward = vol < -FLAT_VOLUME * area * np.maximum(extent, 1e-300)
    closed_part = _closed(faces, part, count)
    inward &= ~(closed_part & _nested(np.asarray(out.vertices), faces, part, count, vol))
    faces[inward[part]] = faces[inward[part]][:, ::-1]
    fixed = tm.Trimesh(vertices=np.asarray(out.vertices), faces=faces, process=False)
    fixed.metadata["part"] = part  # each triangle's connected part (0, 1, ...)
    closed = int(closed_part.sum())
    return fixed, MeshRepairs(parts=count, closed_parts=closed, merged_vertices=merged,
                              degenerate_faces=degenerate, duplicate_faces=duplicate,
                              rewound_faces=int(rewind.sum()),
                              flipped_parts=int(inward.sum()))


def _closed(faces: Index, part: Index, count: int) -> NDArray[np.bool_]:
    """Per part: every edge of it run by exactly two of its triangles (closed)."""
    edges = np.sort(np.stack([faces, np.roll(faces, -1, axis=1)], axis=2).reshape(-1, 2),
                    axis=1)
    owner = np.repeat(part, 3)
    _, inverse, uses = np.unique(edges, axis=0, return_inverse=True, return_counts=True)
    open_edge = uses[inverse.reshape(-1)] != 2
    out = np.ones(count, dtype=np.bool_)
    out[np.unique(owner[open_edge])] = False
    return out


def _nested(vertices: Array, faces: Index, part: Index, count: int, vol: Array
            ) -> NDArray[np.bool_]:
    """Per part: whether it lies inside another part (a cavity's shell or a part buried in
    another: its orientation is the author's word and is kept). At the centroid c of the
    part's largest triangle (normal n) the mean winding number of c ± ε·n is the other
    parts' winding there plus ±1/2 for the part itself (its sign that of its volume)."""
    import trimesh as tm

    tri = vertices[faces]
    area2 = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    area = np.linalg.norm(area2, axis=1)
    order = np.lexsort((-area, part))
    first = order[np.unique(part[order], return_index=True)[1]]  # largest triangle per part
    n = area2[first] / np.maximum(area[first], 1e-300)[:, None]
    c = tri[first].mean(axis=1)
    eps = 1e-6 * max(1.0, float(np.abs(vertices).max()))
    w = Winding(tm.Trimesh(vertices=vertices, faces=faces, process=False))
    mean = 0.5 * (w(c + eps * n) + w(c - eps * n))
    others = mean - 0.5 * np.sign(vol[part[first]])
    out = np.zeros(count, dtype=np.bool_)
    out[part[first]] = np.abs(others) >= 0.5
    return out


def landmark_parts(mesh: trimesh.Trimesh, q: Array) -> Index | None:
    """The connected part (0, 1, ...) of the triangle nearest each landmark q (m, 3) [m] of
    a mesh :func:`repair_mesh` made (None for another mesh)."""
    import trimesh as tm

    part = mesh.metadata.get("part")
    if not isinstance(part, np.ndarray) or part.shape[0] != len(mesh.faces):
        return None
    if q.shape[0] == 0:
        return np.zeros(0, dtype=np.intp)
    _, _, face = tm.proximity.closest_point(mesh, q)  # type: ignore[no-untyped-call]
    return np.asarray(part[np.asarray(face, dtype=np.intp)], dtype=np.intp)
