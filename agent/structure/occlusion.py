"""Occlusion by the structure: which landmarks a camera can see without the mesh in between.

A landmark (q, u) is *unoccluded* from a camera at p [m; world ENU] when the segment from p
to the target t = q + ε·u (the landmark lifted by ε [m] along its outward normal, so its own
surface does not hide it) crosses no triangle of the mesh. All landmarks are tested in one
batched ray query: one ray per landmark from p towards t, and the first triangle each ray
hits; the landmark is hidden when that hit lies before t.

Ray casting uses trimesh's Embree backend (package ``embreex``, single precision on a
rescaled copy of the mesh) when it is installed, else trimesh's pure numpy/rtree backend.
``embreex`` is the optional extra ``occlusion-fast`` (it has no aarch64 wheel, so a Raspberry
Pi or Jetson runs without it): backend "auto" falls back to the pure caster and says so once
per process, in one log line.
A landmark facing away from the camera is hidden by its own surface, in agreement with the
visibility condition ⟨p − q, u⟩ > 0 of eq. 3.8.
"""

from __future__ import annotations

import functools
import logging
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

if TYPE_CHECKING:  # imported where used: loading them costs start-up time
    import trimesh

Array = NDArray[np.float64]
Mask = NDArray[np.bool_]
Backend = Literal["auto", "embree", "triangle"]

#: Default lift [m] of the ray target off the landmark's own surface, along its normal.
TARGET_LIFT = 1e-3

#: The one line logged (once per process) when "auto" falls back to the pure caster.
SLOW_CASTER = ("occlusion: embreex is not installed, using trimesh's slower pure-numpy ray "
               "caster (pip install 'viscover[occlusion-fast]' where a wheel exists)")

_log = logging.getLogger(f"viscover.{__name__}")


@functools.cache
def _say_slow_caster() -> None:
    """Log :data:`SLOW_CASTER`, once per process."""
    _log.warning(SLOW_CASTER)


def embree_available() -> bool:
    """Whether trimesh's Embree ray backend (package ``embreex``) can be used."""
    import trimesh
    return bool(trimesh.ray.has_embree)


def ray_intersector(mesh: trimesh.Trimesh, backend: Backend = "auto") -> Any:
    """A trimesh ray intersector for ``mesh``: Embree if available ("auto"), or as named."""
    import trimesh
    if backend == "auto":
        backend = "embree" if embree_available() else "triangle"
        if backend == "triangle":
            _say_slow_caster()
    if backend == "embree":
        if not embree_available():
            raise ValueError("ray backend 'embree' needs the package embreex: install "
                             "viscover[occlusion-fast] (pip install 'viscover[occlusion-fast]')")
        return trimesh.ray.ray_pyembree.RayMeshIntersector(mesh)
    if backend == "triangle":
        return trimesh.ray.ray_triangle.RayMeshIntersector(mesh)  # type: ignore[no-untyped-call]
    raise ValueError(f"unknown ray backend {backend!r}; use 'auto', 'embree' or 'triangle'")


class OcclusionCaster:
    """Batched segment-vs-mesh tests for one structure (the mesh must not change after)."""

    def __init__(self, mesh: trimesh.Trimesh, backend: Backend = "auto",
                 lift: float = TARGET_LIFT) -> None:
        if not (np.isfinite(lift) and lift > 0):
            raise ValueError(f"lift must be a positive distance [m], got {lift}")
        self.mesh = mesh
        self.lift = float(lift)
        self.backend = backend
        self._rays = ray_intersector(mesh, backend)
        #: Casts may run in several threads at once (Embree's; not trimesh's R-tree caster).
        self.thread_safe = type(self._rays).__module__.endswith("ray_pyembree")
        self._corner = np.asarray(mesh.triangles[:, 0, :], dtype=np.float64)
        self._normal = np.asarray(mesh.face_normals, dtype=np.float64)

    def segment_clear(self, origins: Array, targets: Array, tol: float | Array = 0.0) -> Mask:
        """For rows of origins, targets (n, 3) [m; world ENU]: no triangle on the segment
        before ``tol`` [m] (one, or one per row) short of its target (a hit within ``tol`` of
        it is the target's own surface)."""
        d = targets - origins
        length = np.sqrt((d * d).sum(axis=1))
        short = np.broadcast_to(np.asarray(tol, dtype=np.float64), length.shape)
        ok = length > 0.0
        out = np.ones(length.shape, dtype=bool)
        if not ok.any():
            return out
        if ok.all():  # the usual case: no copies
            o = origins
            d /= length[:, None]
        else:
            o, d, length, short = origins[ok], d[ok] / length[ok, None], length[ok], short[ok]
        tri = np.asarray(self._rays.intersects_first(o, d), dtype=np.intp)
        hit = np.flatnonzero(tri >= 0)
        n = self._normal[tri[hit]]
        nd = (n * d[hit]).sum(axis=1)
        # Distance along the ray to the hit triangle's plane (float64, exact for the face hit).
        t = (n * (self._corner[tri[hit]] - o[hit])).sum(axis=1) / np.where(nd != 0.0, nd, 1.0)
        t = np.where(nd != 0.0, t, 0.0)  # a ray inside a triangle's plane counts as blocked
        clear = np.ones(length.shape, dtype=bool)
        clear[hit] = t >= length[hit] - short[hit]
        out[ok] = clear
        return out

    def unoccluded(self, p: ArrayLike, q: ArrayLike, u: ArrayLike) -> Mask:
        """Mask (m,) for one camera p (3,), or (n, m) for cameras p (n, 3): p → q + lift·u clear."""
        pa = np.asarray(p, dtype=np.float64)
        qa = np.asarray(q, dtype=np.float64).reshape(-1, 3)
        ua = np.asarray(u, dtype=np.float64).reshape(-1, 3)
        if qa.shape != ua.shape:
            raise ValueError(f"q and u must have the same shape, got {qa.shape} and {ua.shape}")
        target = qa + self.lift * ua
        cams = pa.reshape(-1, 3)
        m = target.shape[0]
        origins = np.repeat(cams, m, axis=0)
        targets = np.tile(target, (cams.shape[0], 1))
        mask = self.segment_clear(origins, targets).reshape(cams.shape[0], m)
        return mask[0] if pa.ndim == 1 else mask


    def unoccluded_facing(self, p: ArrayLike, q: ArrayLike, u: ArrayLike) -> Mask:
        """Mask (m,) for one camera p (3,): the landmark faces p (⟨p − q, u⟩ > 0, eq. 3.8) and
        p → q + lift·u is clear. Rays are cast for the facing landmarks only (on a closed
        mesh a landmark facing away is hidden by its own surface anyway)."""
        pa = np.asarray(p, dtype=np.float64).reshape(3)
        qa = np.asarray(q, dtype=np.float64).reshape(-1, 3)
        ua = np.asarray(u, dtype=np.float64).reshape(-1, 3)
        facing = np.flatnonzero(np.einsum("ij,ij->i", pa - qa, ua) > 0.0)
        out = np.zeros(qa.shape[0], dtype=bool)
        if facing.size:
            out[facing] = self.unoccluded(pa, qa[facing], ua[facing])
        return out


def unoccluded(mesh: trimesh.Trimesh, p: ArrayLike, q: ArrayLike, u: ArrayLike,
               lift: float = TARGET_LIFT, backend: Backend = "auto") -> Mask:
    """One-off :meth:`OcclusionCaster.unoccluded` (builds the ray structure each call)."""
    return OcclusionCaster(mesh, backend, lift).unoccluded(p, q, u)


@dataclass
class OcclusionCache:
    """The unoccluded mask of one landmark set, recast only when the camera has moved more
    than ``refresh_distance`` [m] since the last cast or the landmark set changed.

    Pure: no clocks; the caller decides when to ask (:meth:`needs_refresh`, :meth:`mask`).
    ``facing_only`` casts only for landmarks facing the camera (the others are False).
    """

    caster: OcclusionCaster
    refresh_distance: float
    casts: int = 0
    facing_only: bool = False
    _p: Array | None = field(default=None, repr=False)
    _q: Array | None = field(default=None, repr=False)
    _u: Array | None = field(default=None, repr=False)
    _mask: Mask | None = field(default=None, repr=False)

    def __post_init__(self) -> None:
        if not (self.refresh_distance >= 0 and np.isfinite(self.refresh_distance)):
            raise ValueError(
                f"refresh_distance must be a finite distance >= 0 [m], got {self.refresh_distance}"
            )

    def needs_refresh(self, p: ArrayLike, q: ArrayLike, u: ArrayLike) -> bool:
        """Whether the cached mask is stale for camera p [m] and landmarks (q, u)."""
        if self._p is None or self._q is None or self._u is None:
            return True
        pa = np.asarray(p, dtype=np.float64)
        if float(np.sqrt(((pa - self._p) ** 2).sum())) > self.refresh_distance:
            return True
        return not (np.array_equal(np.asarray(q), self._q)
                    and np.array_equal(np.asarray(u), self._u))

    def invalidate(self) -> None:
        """Forget the cached mask: the next :meth:`mask` casts again."""
        self._mask = None

    @property
    def current(self) -> Mask | None:
        """The mask of the last cast (None before the first, or after :meth:`invalidate`)."""
        return self._mask

    @property
    def origin(self) -> Array | None:
        """The camera position [m] of the last cast (None before the first)."""
        return self._p

    def mask(self, p: ArrayLike, q: ArrayLike, u: ArrayLike) -> Mask:
        """The unoccluded mask (m,) for camera p (3,) [m], recast only when stale."""
        if self._mask is None or self.needs_refresh(p, q, u):
            self._p = np.array(p, dtype=np.float64)
            self._q = np.array(q, dtype=np.float64)
            self._u = np.array(u, dtype=np.float64)
            cast = self.caster.unoccluded_facing if self.facing_only else self.caster.unoccluded
            self._mask = cast(self._p, self._q, self._u)
            self.casts += 1
        return self._mask
