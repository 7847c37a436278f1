"""The ``[structure]`` table of a scenario and its ``visibility`` model, validated as data.

A scenario may name a mesh file (STL, OBJ, PLY; the path is relative to the scenario file)
placed in the world by ``position`` [m; world ENU], ``yaw`` [rad] and ``scale`` (model units
→ metres); landmarks are then sampled on its surface ``spacing`` [m] apart with outward
normals. This module only checks the fields (one-line errors naming file, field and fix);
the mesh is read and sampled above this layer (:mod:`agent.world.structure`, with
:mod:`agent.structure`), since :mod:`agent.config` may not import :mod:`agent.structure`.

.. code-block:: toml

    visibility = "occlusion"     # "facing" (eq. 3.8 only, default) | "occlusion" (also: no
                                 # triangle of the structure between camera and landmark)

    [structure]
    mesh = "meshes/l_building.stl"
    position = [0.0, 0.0, 0.0]   # optional [m]
    yaw = 0.0                    # optional [rad], about world z
    scale = 1.0                  # optional, model units → metres
    spacing = 2.0                # landmark spacing on the surface [m]
    z_min = 0.5                  # optional: keep landmarks with z ≥ z_min [m] (above ground)
    min_normal_z = -0.5          # optional, in [-1, 1]: keep normals with u_z ≥ it
    within_space = true          # optional: keep only landmarks inside [space] (default true)
    region_lo = [0.0, 0.0, 0.0]  # optional region of interest [m]; both or neither
    region_hi = [10.0, 10.0, 5.0]
    margin = 1.0                 # clearance the agents keep from the structure [m]
    refresh = 0.5                # occlusion mask recast after moving this far [m]

Mesh landmarks get ids after the explicit and generated ones and belong at the start to the
agent nearest to them (agents' ``landmarks`` lists name the other landmarks only).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import msgspec
import numpy as np

from agent.config.validation import Ctx, finite, positive, suggest, vector

#: Visibility models: eq. 3.8 alone, or eq. 3.8 and an unobstructed line of sight.
VISIBILITY_MODELS = ("facing", "occlusion")
#: Mesh file suffixes (as :data:`agent.structure.mesh.MESH_SUFFIXES`).
MESH_SUFFIXES = (".stl", ".obj", ".ply")


class StructureTable(msgspec.Struct, forbid_unknown_fields=True, kw_only=True):
    mesh: str
    spacing: float
    position: list[float] = msgspec.field(default_factory=lambda: [0.0, 0.0, 0.0])
    yaw: float = 0.0
    scale: float = 1.0
    z_min: float | None = None
    min_normal_z: float | None = None
    within_space: bool = True
    region_lo: list[float] | None = None
    region_hi: list[float] | None = None
    margin: float = 1.0
    refresh: float = 0.5


@dataclass(frozen=True)
class StructureSpec:
    """A validated ``[structure]`` table. Lengths [m; world ENU], angles [rad]; ``region`` is
    the box (lo, hi) landmarks must lie in (mission space ∩ region of interest; infinite
    bounds mean none). Hashable, so a loaded mesh can be cached per spec."""

    mesh: Path  #: the mesh file, resolved against the scenario file's folder
    position: tuple[float, float, float]
    yaw: float
    scale: float
    spacing: float
    z_min: float | None
    min_normal_z: float | None
    region: tuple[tuple[float, float, float], tuple[float, float, float]]
    margin: float  #: clearance kept from the structure [m] (section 4.3 obstacle offset)
    refresh: float  #: distance [m] after which an agent's occlusion mask is recast
    sampled: bool = False  #: True once the mesh landmarks are in the scenario


def _triple(a: np.ndarray) -> tuple[float, float, float]:
    return float(a[0]), float(a[1]), float(a[2])


def parse_visibility(ctx: Ctx, value: str, has_structure: bool) -> str:
    """The ``visibility`` field: a known model; "occlusion" needs a ``[structure]``."""
    if value not in VISIBILITY_MODELS:
        raise ctx.fail("visibility", f"unknown model {value!r}"
                       + suggest(value, VISIBILITY_MODELS).replace("known", "use one of"))
    if value == "occlusion" and not has_structure:
        raise ctx.fail("visibility", "'occlusion' needs a structure; add a [structure] table "
                       "with a mesh, or use visibility = \"facing\"")
    return value


def parse_structure(ctx: Ctx, st: StructureTable, dims: int, space_lo: np.ndarray,
                    space_hi: np.ndarray, base: Path) -> StructureSpec:
    """Check a ``[structure]`` table; ``base`` is the folder relative mesh paths start from."""
    at = "structure."
    if dims != 3:
        raise ctx.fail("structure", "needs a 3-D scenario (dims = 3)")
    path = Path(st.mesh)
    if path.suffix.lower() not in MESH_SUFFIXES:
        raise ctx.fail(at + "mesh", f"unsupported mesh format {path.suffix or '(none)'!r} "
                       f"in {st.mesh!r}; use {', '.join(MESH_SUFFIXES)}")
    full = path if path.is_absolute() else base / path  # that it exists: agent.config.parse
    position = vector(ctx, at + "position", st.position, 3, n=3)
    yaw = finite(ctx, at + "yaw", st.yaw)
    scale = positive(ctx, at + "scale", st.scale, " (model units to metres)")
    spacing = positive(ctx, at + "spacing", st.spacing, " of metres")
    z_min = None if st.z_min is None else finite(ctx, at + "z_min", st.z_min)
    nz = st.min_normal_z
    if nz is not None and not -1.0 <= nz <= 1.0:
        raise ctx.fail(at + "min_normal_z", f"must lie in [-1, 1] (a normal's z component), "
                       f"got {nz}")
    lo = space_lo.copy() if st.within_space else np.full(3, -np.inf)
    hi = space_hi.copy() if st.within_space else np.full(3, np.inf)
    if (st.region_lo is None) != (st.region_hi is None):
        raise ctx.fail(at + ("region_hi" if st.region_hi is None else "region_lo"),
                       "is missing; give both region_lo and region_hi, or neither")
    if st.region_lo is not None and st.region_hi is not None:
        r_lo = vector(ctx, at + "region_lo", st.region_lo, 3, n=3)
        r_hi = vector(ctx, at + "region_hi", st.region_hi, 3, n=3)
        bad = np.flatnonzero(~(r_lo < r_hi))
        if bad.size:
            k = int(bad[0])
            raise ctx.fail(at + "region_hi", f"must be greater than structure.region_lo on "
                           f"every axis; axis {'xyz'[k]} has lo = {r_lo[k]:g}, "
                           f"hi = {r_hi[k]:g}")
        lo, hi = np.maximum(lo, r_lo), np.minimum(hi, r_hi)
        if not np.all(lo < hi):
            raise ctx.fail(at + "region_lo", "the region of interest does not meet the mission "
                           "space; move it inside [space] or set within_space = false")
    margin = positive(ctx, at + "margin", st.margin, " of metres")
    refresh = positive(ctx, at + "refresh", st.refresh, " of metres")
    return StructureSpec(
        mesh=full, position=_triple(position), yaw=yaw, scale=scale, spacing=spacing,
        z_min=z_min, min_normal_z=None if nz is None else float(nz),
        region=(_triple(lo), _triple(hi)), margin=margin, refresh=refresh,
    )
