"""Bounds on every size a scenario file controls, checked before anything of that size is
allocated, so that a mistyped or hostile file fails in one line instead of exhausting memory.

The limits are generous for real missions (the thesis' scenarios have 1-3 agents and at
most a few hundred landmarks; the shipped mesh scenarios under a hundred landmarks):

* :data:`MAX_SCENARIO_BYTES` (16 MiB): the scenario file itself. About 200,000 explicit
  ``[[landmarks]]``; parsing a file this size takes under 300 MB, in time linear in the
  landmarks (ids assigned in one pass, :mod:`agent.config.parse`).
* :data:`MAX_AGENTS` (256): ``[[agents]]`` tables. Every agent plans against every other
  (avoidance, trades), so the work per step grows with the square of the team.
* :data:`MAX_LANDMARKS` (1,000,000): landmarks in all, explicit, generated (polygon
  ``sides``, box faces × ``count`` or ``grid``, cylinder ``around`` × ``rows``) and sampled
  on a mesh, and the view landmarks of a multi-view inspection (``inspection.views`` per
  landmark, :mod:`agent.world.views`); the generator counts are computed from the parsed
  numbers first. A million
  landmarks are 48 MB of positions and normals.
* :data:`MAX_MESH_LANDMARKS` (200,000): the mesh estimate (surface area kept by the filters)
  / ``structure.spacing``², checked before sampling. Sampling draws 24 candidates per
  estimated landmark: about 0.63 × the estimate are kept, so the limit allows about 126,000
  mesh landmarks (10⁵ of them: 15 s and 0.8 GB of sampling, ``bench/bench_prepare.py``;
  the limit keeps it near a gigabyte and 20 s).
* :data:`MAX_VOXELS` (10,000,000): with ``strategy = "potential"`` or ``[inspection]`` the
  structure is voxelised at ``structure.margin`` / 2 (viewpoint keep-out, routes); its
  bounding box in such voxels, checked after the mesh is read (at most 240 MB of voxels).
* :data:`MAX_LANDMARK_ID` (2⁵³ − 1): explicit landmark ids (ids travel as int64 and in JSON,
  where larger integers lose precision).

The mesh file's own bounds (bytes, triangles) are in :mod:`agent.structure.mesh`. Every
error names the file, the field, the limit and the fix, as the other scenario errors do.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

from agent.config.validation import Ctx

#: Largest scenario file [bytes].
MAX_SCENARIO_BYTES = 16 * 1024 * 1024
#: Most ``[[agents]]`` in a scenario.
MAX_AGENTS = 256
#: Most landmarks in a scenario (explicit, generated and sampled on a mesh).
MAX_LANDMARKS = 1_000_000
#: Largest estimated mesh landmark count, surface area / ``structure.spacing``².
MAX_MESH_LANDMARKS = 200_000
#: Most voxels of edge ``structure.margin`` / 2 in the structure's bounding box, when it is
#: voxelised (coverage moves' keep-out, inspection routes).
MAX_VOXELS = 10_000_000
#: Largest explicit landmark id.
MAX_LANDMARK_ID = 2**53 - 1
#: Items a message lists before "...".
SHOWN = 20


def check_agents(ctx: Ctx, n: int) -> None:
    """At most :data:`MAX_AGENTS` agents."""
    if n > MAX_AGENTS:
        raise ctx.fail("agents", f"{n:,} agents, more than the limit of {MAX_AGENTS}; "
                       "split the team into several scenarios")


def check_landmarks(ctx: Ctx, path: str, n: int, before: int, fix: str) -> None:
    """``n`` more landmarks (from the field ``path``) after ``before`` stay within
    :data:`MAX_LANDMARKS`; else a one-line error ending with ``fix``."""
    if n > MAX_LANDMARKS - before:
        also = f" ({before:,} before them)" if before else ""
        raise ctx.fail(path, f"gives {n:,} landmarks{also}, more than the limit of "
                       f"{MAX_LANDMARKS:,} in a scenario; {fix}")


def check_scenario_size(source: str, size: int) -> None:
    """Refuse a scenario of ``size`` bytes (or characters) over :data:`MAX_SCENARIO_BYTES`."""
    if size > MAX_SCENARIO_BYTES:
        raise Ctx(source).fail("", f"larger than the limit of {MAX_SCENARIO_BYTES // 2**20} MiB "
                             "for a scenario file; is this a TOML scenario file?")


def mesh_estimate_error(source: str, spacing: float, area: float, before: int) -> str | None:
    """The one-line error for a mesh whose sampled landmarks would exceed the limits
    (``area`` [m²] kept by the filters, ``before`` landmarks not on the mesh), else None."""
    estimate = area / spacing**2
    room = min(MAX_MESH_LANDMARKS, MAX_LANDMARKS - before)
    if estimate <= room:
        return None
    least = (area / max(room, 1)) ** 0.5
    return (f"{source}: structure.spacing: {spacing:g} m on {area:,.4g} m² of surface gives "
            f"about {estimate:,.0f} landmarks (area / spacing²), more than the limit of "
            f"{room:,}; use spacing >= {least:.3g} m or a region of interest")


def voxel_error(source: str, margin: float, extent: Sequence[float]) -> str | None:
    """The one-line error for a structure of bounding-box ``extent`` (3,) [m] whose voxels
    of edge ``margin`` / 2 would exceed :data:`MAX_VOXELS`, else None."""
    def cells(m: float) -> int:
        return math.prod(math.ceil(e / (m / 2.0)) + 1 for e in extent)

    n = cells(margin)
    if n <= MAX_VOXELS:
        return None
    lo, hi = margin, 2.0 * max(extent) + margin  # cells(hi) is 8 at most
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if cells(mid) > MAX_VOXELS else (lo, mid)
    size = " × ".join(f"{e:.3g}" for e in extent)
    return (f"{source}: structure.margin: {margin:g} m on a structure of {size} m needs "
            f"{n:,} voxels of margin / 2 (viewpoint keep-out, routes), more than the limit "
            f"of {MAX_VOXELS:,}; use margin >= {hi:.3g} m")


def listed(items: Sequence[object]) -> str:
    """``[1, 2, 3]``, or the first :data:`SHOWN` items then ``...`` and how many in all."""
    if len(items) <= SHOWN:
        return str(list(items))
    return f"[{', '.join(map(str, items[:SHOWN]))}, ... ({len(items):,} in all)]"
