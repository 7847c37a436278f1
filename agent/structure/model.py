"""A structure as the planner of chapter 4 sees it: occlusion masks, obstacles and safe steps.

:class:`StructureModel` bundles one placed mesh with its ray caster
(:class:`~agent.structure.occlusion.OcclusionCaster`) and clearance queries
(:class:`~agent.structure.clearance.MeshClearance`) and answers, as plain arrays, what
:func:`agent.core.planner.plan_step` takes: the section-4.3 obstacle rows (ŵ, d) of the
surface near the camera, the longest step along a direction that keeps ``margin`` [m] from
the surface, and which landmarks the structure hides.

:class:`OcclusionTracker` is one agent's unoccluded mask, recast only when the agent has
moved ``refresh`` [m] from where it was cast (or its landmark set changed). The mask is
trusted inside that ball only: :meth:`OcclusionTracker.reach` truncates linear steps at the
ball's surface, so every step the planner accepts is evaluated on the set of the last cast
while the camera is within ``refresh`` of it, and the mask is recast at the next step.
All positions [m; world ENU].
"""

from __future__ import annotations

import functools
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike, NDArray

from agent.structure.clearance import MeshClearance
from agent.structure.occlusion import Backend, OcclusionCache, OcclusionCaster
from agent.structure.solid import Solid, Winding

if TYPE_CHECKING:  # imported where used: loading them costs start-up time
    import trimesh

Array = NDArray[np.float64]
Mask = NDArray[np.bool_]

#: Relative slack on the refresh radius: at the ball's surface the mask is recast.
BALL_SLACK = 1e-9
#: Steps stop within this distance [m] of the margin (MeshClearance.max_step's tolerance);
#: obstacle distances are offset by it so that such a stop counts as touching (problem 4.7).
TRACE_TOL = 1e-3


class StructureModel:
    """One structure mesh in the world frame and the queries the planner needs."""

    def __init__(self, mesh: trimesh.Trimesh, margin: float, backend: Backend = "auto") -> None:
        if not (np.isfinite(margin) and margin > 0):
            raise ValueError(f"margin must be a positive distance [m], got {margin}")
        self.mesh = mesh
        self.margin = float(margin)
        self.caster = OcclusionCaster(mesh, backend)
        self.winding = Winding(mesh)
        self.clearance = MeshClearance(mesh, self.winding)
        self._keepout: Array | None = None

    @functools.cached_property
    def solid(self) -> Solid:
        """Inside, reachable free space and hidden surface, on cells of half the margin;
        built on first use (the capture table's, not a flight's: an agent given a prepared
        table never builds it)."""
        return Solid(self.mesh, self.margin / 2.0, self.caster.segment_clear, self.winding)

    def keepout_boxes(self) -> Array:
        """Boxes (k, 2, 3) [m; world ENU] covering the solid structure: its filled voxels of
        edge ``margin`` (every voxel the surface touches, and the inside), merged along z
        into columns; computed once. Inflated by the margin they keep candidate viewpoints
        clear of the structure without shutting out a concave part's open space (the inner
        corner of an L) as its bounding box does."""
        if self._keepout is None:
            self._keepout = voxel_columns(
                np.asarray(self.mesh.voxelized(self.margin).fill().points, dtype=np.float64),
                self.margin)
        return self._keepout

    def obstacles(self, p: Array, d_w: float) -> tuple[Array, Array]:
        """Section 4.3 obstacle rows for camera p (3,): ŵ (k, 3) away from the surface and
        d = ‖p − c‖ − margin − TRACE_TOL (k,) [m] for the surface within margin + D_w of p."""
        edge = self.margin + TRACE_TOL
        return self.clearance.obstacles(p, edge + max(d_w, 0.0), edge)

    def reach(self, p: Array, direction: Array, limit: float) -> float:
        """Largest α ∈ [0, limit] [m] with p + s·dir, s ∈ [0, α], ≥ margin from the surface
        (sphere tracing: may stop up to TRACE_TOL short of the margin)."""
        return self.clearance.max_step(p, direction, self.margin, limit, tol=TRACE_TOL)

    def distance(self, p: ArrayLike) -> Array:
        """Signed distance (n,) [m] of positions p (n, 3) to the surface (negative inside)."""
        return self.clearance.closest(p).distance

    def reachable(self, p: ArrayLike) -> Mask:
        """Positions p (n, 3) [m] at least the margin from the surface, outside it, in free
        space a drone can fly to from outside (not in a closed cavity)."""
        pa = np.asarray(p, dtype=np.float64).reshape(-1, 3)
        ok = ~self.clearance.nearer_than(pa, self.margin)  # signed distance ≥ margin:
        ok[ok] = ~self.winding.inside(pa[ok])  # that far and outside
        ok[ok] = self.solid.reachable(pa[ok])
        return np.asarray(ok, dtype=np.bool_)

    def hidden(self, q: ArrayLike, u: ArrayLike) -> NDArray[np.int8]:
        """Per landmark (q, u) (m, 3): :data:`~agent.structure.solid.BURIED` (inside another
        part), :data:`~agent.structure.solid.CAVITY` (facing a closed cavity) or 0."""
        return self.solid.hidden(np.asarray(q, dtype=np.float64),
                                 np.asarray(u, dtype=np.float64), self.caster.lift)

    def unoccluded(self, p: ArrayLike, q: ArrayLike, u: ArrayLike) -> Mask:
        """Fresh cast: landmarks (q, u) (m, 3) whose line of sight from p (3,) is clear."""
        return self.caster.unoccluded(p, q, u)

    def segments_clear(self, a: Array, b: Array) -> Mask:
        """For rows a, b (n, 3) [m]: whether the segment a → b crosses no triangle."""
        return self.caster.segment_clear(np.asarray(a, dtype=np.float64),
                                         np.asarray(b, dtype=np.float64))


def voxel_columns(centres: Array, pitch: float) -> Array:
    """Voxels of edge ``pitch`` [m] at ``centres`` (n, 3) as boxes (k, 2, 3), each run of
    voxels stacked along z one box."""
    if centres.shape[0] == 0:
        return np.zeros((0, 2, 3))
    idx = np.round((centres - centres.min(axis=0)) / pitch).astype(np.int64)
    order = np.lexsort((idx[:, 2], idx[:, 1], idx[:, 0]))
    idx, c = idx[order], centres[order]
    first = np.ones(idx.shape[0], dtype=np.bool_)
    first[1:] = (idx[1:, 0] != idx[:-1, 0]) | (idx[1:, 1] != idx[:-1, 1]) \
        | (idx[1:, 2] != idx[:-1, 2] + 1)
    start = np.flatnonzero(first)
    end = np.r_[start[1:], idx.shape[0]] - 1
    return np.stack([c[start] - pitch / 2.0, c[end] + pitch / 2.0], axis=1)


def ball_exit(p: Array, direction: Array, centre: Array, radius: float) -> float:
    """Distance α ≥ 0 [m] along the unit ``direction`` from p to the surface of the ball
    (centre, radius); 0 when p is already outside."""
    e = p - centre
    b = float(e @ direction)
    c = float(e @ e) - radius * radius
    if c >= 0.0:
        return 0.0
    return -b + float(np.sqrt(b * b - c))


class OcclusionTracker:
    """One agent's unoccluded mask over its landmark set, recast after ``refresh`` [m]."""

    def __init__(self, model: StructureModel, refresh: float) -> None:
        self.model = model
        self.refresh = float(refresh)
        self.cache = OcclusionCache(model.caster, self.refresh, facing_only=True)
        #: At recasts triggered by distance: landmarks the planner was using (unoccluded in the
        #: old mask), and how many of them, still facing the camera, the new cast finds
        #: occluded (how stale the trusted set got within the refresh ball).
        self.used = 0
        self.lost = 0

    @property
    def casts(self) -> int:
        """Ray casts so far (one batched query each)."""
        return self.cache.casts

    def mask(self, p: Array, q: ArrayLike, u: ArrayLike) -> Mask:
        """Unoccluded mask (m,) for camera p over (q, u), recast when p reached the ball's
        surface or the set changed. Landmarks facing away from the cast's origin are False
        (not cast); one that turns to face the camera inside the ball is thus left out of the
        planner's set until the next cast, which keeps the line search's lower bound."""
        origin, old = self.cache.origin, self.cache.current
        moved = False
        if origin is not None:
            e = p - origin
            moved = float(np.sqrt(e @ e)) >= self.refresh * (1.0 - BALL_SLACK)
            if moved:
                self.cache.invalidate()
        new = self.cache.mask(p, q, u)
        if moved and old is not None and old.shape == new.shape:
            qa = np.asarray(q, dtype=np.float64).reshape(-1, 3)
            facing = np.einsum("ij,ij->i", p - qa, np.asarray(u).reshape(-1, 3)) > 0.0
            self.used += int(old.sum())
            self.lost += int((old & ~new & facing).sum())  # still facing p, now occluded
        return new

    def reach(self, p: Array, direction: Array, limit: float) -> float:
        """Largest safe step [m] ≤ limit: clear of the structure and inside the refresh ball
        (where the mask of the last cast is trusted)."""
        origin = self.cache.origin
        if origin is not None:
            limit = min(limit, ball_exit(p, direction, origin, self.refresh))
        return self.model.reach(p, direction, limit) if limit > 0.0 else 0.0
