"""Scenario files: the landmarks, agents, mission space and planner constants of one run.

(Over 400 lines, not split further: about a hundred of them are this docstring, the file
format's reference; the schema is in :mod:`agent.config.scenario_schema`, the error
messages in :mod:`agent.config.validation`.)

A scenario is a TOML file, parsed with :mod:`tomllib`, checked against a msgspec schema
(unknown fields are refused) and then checked semantically. Every problem raises
:class:`ScenarioError` with a one-line message naming the file, the field path and the fix,
e.g. ``scenarios/x.toml: agents[1].position: expected 2 numbers for a 2-D scenario
(dims = 2), got 3``.

Units: metres, seconds, radians; world frame ENU (x east, y north, z up).

File format
-----------

.. code-block:: toml

    name = "hexagon_5_3"   # optional; default: the file name without .toml
    dims = 2               # 2 (planar mode of chapter 5: z = 0, yaw only) or 3
    seed = 0               # optional, default 0 (recorded in the result)
    trading = true         # optional; false = pose optimisation only (figure 5.7)
    strategy = "thesis"    # optional; "thesis" (chapter 5 exactly) or "potential" (coverage
                           # moves beyond the thesis: simulator, kinematic and flying agents)
    lost_after = 60.0      # optional; an agent gone this long [s] before completing is lost:
                           # the team fences it out and adopts its landmarks (0: never)
    d_opt = 1.0            # optimal viewing distance [m], eq. 3.6
    duration = 60.0        # longest simulated time [s]

    [space]                # optional: omitted = unbounded mission space (section 5.1)
    lo = [-3.0, -3.0]      # dims numbers [m]; -inf / inf allowed per axis
    hi = [3.0, 3.0]

    [planner]              # every key optional; defaults from agent.core.planner.PlannerParams
    dt = 0.1               # sampling time Δt [s]
    p_lim = 0.3            # largest linear speed [m/s]
    p_min = 0.01           # smallest linear speed [m/s], 0 < p_min ≤ p_lim
    w_lim = 0.7853981633974483   # largest angular speed [rad/s] (π/4)
    w_min = 0.017453292519943295 # smallest angular speed [rad/s] (π/180), ≤ w_lim
    tau = 0.9              # backtracking factor, in (0, 1)
    beta = 0.5             # Armijo fraction, in (0, 1)
    avoidance = "smooth"   # "none" | "abrupt" (problem 4.7) | "smooth" (problem 4.11)
    r_s = 1.0              # safety radius R_s [m]
    d_w = 0.5              # worry distance D_w [m]
    lambda_dir = 0.95      # optional direction-change limit of section 5.2, in [0, 1]

    [[landmarks]]          # explicit landmarks, in order
    id = 1                 # optional; default: one more than the largest id so far (from 1)
    position = [1.0, 4.5]  # dims numbers [m]
    normal = [-0.5, -0.866]  # dims numbers, normalised on load;
                             # or normal_angle = -2.094 [rad] (2-D only)

    [[generators]]         # appended after the explicit landmarks; ids continue
    kind = "polygon"       # one landmark at the centre of each edge, outward normals
    sides = 6
    side = 0.5             # edge length [m]
    center = [0.0, 0.0]    # optional, dims numbers [m]
    phase = 0.5235987755982988  # angle of the first landmark's normal [rad] (optional, 0)

    [[generators]]
    kind = "box"           # 3-D only: landmarks on the faces of an axis-aligned box
    center = [0.0, 0.0, 1.0]
    size = 0.5             # edge [m], or [sx, sy, sz]
    faces = ["+x", "-x", "+y", "-y", "+z"]   # optional, default all six, in this order
    count = 3              # optional: a row of 3 through each face centre (along y on ±x,
                           # x on ±y and ±z); or grid = [n1, n2]; default one at the centre

    [[generators]]
    kind = "cylinder"      # 3-D only: lateral surface, outward radial normals
    center = [0.0, 0.0, 0.0]   # centre of the bottom disc [m]
    radius = 0.5
    height = 2.0
    around = 8             # landmarks per ring
    rows = 2               # rings (optional, 1)
    phase = 0.0            # optional [rad]

    [[agents]]
    id = "A"               # [A-Za-z0-9_-]{1,32}, unique
    position = [-2.0, 2.0] # dims numbers [m], inside [space]
    yaw = 0.0              # longitude ψ [rad]; pitch = latitude θ [rad] (3-D, optional);
                           # or direction = [x, y(, z)] (normalised); default yaw = 0
    landmarks = [3, 6]     # ids owned at the start; every landmark has exactly one owner

    visibility = "facing"  # or "occlusion" (needs [structure]); see agent.config.structure
    [inspection]           # optional: an inspection mission (agent.config.inspection)
    quality = 0.3
    [camera]               # optional, with [inspection]: its camera (agent.config.inspection)
    [structure]            # optional: landmarks sampled on a mesh, which is also an obstacle
    mesh = "meshes/l_building.stl"   # and the fields documented in agent.config.structure
    spacing = 2.0

Limits (:mod:`agent.config.limits`, checked before allocating): a file of at most 16 MiB,
at most 256 agents, at most 1,000,000 landmarks in all (generator counts computed first),
explicit ids at most 2^53 - 1, a mesh's area / ``structure.spacing``² at most 200,000 (and
the mesh file's and ``structure.margin``'s bounds listed there).

Generated landmark order: polygon edge by edge counter-clockwise from ``phase``; box face by
face in the order of ``faces``, and within a face along the first axis first; cylinder ring
by ring from the bottom, counter-clockwise from ``phase``.
"""

from __future__ import annotations

import math
import re
import tomllib
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from agent.config.inspection import parse_camera, parse_inspection
from agent.config.limits import (
    MAX_LANDMARK_ID,
    MAX_SCENARIO_BYTES,
    check_agents,
    check_landmarks,
    check_scenario_size,
    listed,
)
from agent.config.scenario import AgentSpec, Scenario
from agent.config.scenario_schema import (
    CHILDREN,
    GENERATORS,
    AgentTable,
    BoxTable,
    CylinderTable,
    LandmarkTable,
    PlannerTable,
    PolygonTable,
    ScenarioFile,
    SpaceTable,
)
from agent.config.structure import parse_structure, parse_visibility
from agent.config.validation import (
    Ctx,
    ScenarioError,
    check_keys,
    convert,
    finite,
    nonzero_unit,
    open_unit,
    parse_strategy,
    positive,
    suggest,
    vector,
)
from agent.core.avoidance import MissionSpace
from agent.core.landmarks import BOX_FACES, box_faces, cylinder, regular_polygon
from agent.core.orientation import direction_from_angles
from agent.core.planner import PlannerParams

Array = NDArray[np.float64]

__all__ = ["load_scenario", "parse_scenario"]

AGENT_ID_RE = re.compile(r"[A-Za-z0-9_-]{1,32}")
AVOIDANCE_MODES = ("none", "abrupt", "smooth")


def _check_unknown(ctx: Ctx, raw: dict[str, Any]) -> None:
    """Unknown fields anywhere in the file (before msgspec, for better messages)."""
    check_keys(ctx, raw, ScenarioFile, "")
    for key, (t, many) in CHILDREN.items():
        sub = raw.get(key)
        if many and isinstance(sub, list):
            for i, item in enumerate(sub):
                check_keys(ctx, item, t, f"{key}[{i}]")
        elif not many:
            check_keys(ctx, sub, t, key)


def _params(ctx: Ctx, pl: PlannerTable, planar: bool) -> PlannerParams:
    p = "planner."
    dt = positive(ctx, p + "dt", pl.dt, " of seconds")
    p_lim = positive(ctx, p + "p_lim", pl.p_lim, " [m/s]")
    p_min = positive(ctx, p + "p_min", pl.p_min, " [m/s]")
    if p_min > p_lim:
        raise ctx.fail(p + "p_min", f"must not exceed planner.p_lim = {p_lim:g}, got {p_min:g}")
    w_lim = positive(ctx, p + "w_lim", pl.w_lim, " [rad/s]")
    w_min = positive(ctx, p + "w_min", pl.w_min, " [rad/s]")
    if w_min > w_lim:
        raise ctx.fail(p + "w_min", f"must not exceed planner.w_lim = {w_lim:g}, got {w_min:g}")
    tau = open_unit(ctx, p + "tau", pl.tau)
    beta = open_unit(ctx, p + "beta", pl.beta)
    if pl.avoidance not in AVOIDANCE_MODES:
        raise ctx.fail(p + "avoidance", f"unknown mode {pl.avoidance!r}"
                       + suggest(pl.avoidance, AVOIDANCE_MODES).replace("known", "use one of"))
    r_s = positive(ctx, p + "r_s", pl.r_s, " of metres")
    d_w = positive(ctx, p + "d_w", pl.d_w, " of metres")
    lam = pl.lambda_dir
    if lam is not None and not (0.0 <= lam <= 1.0):
        raise ctx.fail(p + "lambda_dir", f"must lie in [0, 1] (close to 1), got {lam}")
    return PlannerParams(
        dt=dt, p_lim=p_lim, p_min=p_min, w_lim=w_lim, w_min=w_min, tau=tau, beta=beta,
        avoidance=pl.avoidance,  # type: ignore[arg-type]
        r_s=r_s, d_w=d_w, lambda_dir=lam, planar=planar,
    )


def _space(ctx: Ctx, sp: SpaceTable | None, dims: int) -> MissionSpace:
    if sp is None:
        return MissionSpace.unbounded()
    lo = vector(ctx, "space.lo", sp.lo, dims, finite=False)
    hi = vector(ctx, "space.hi", sp.hi, dims, finite=False)
    if dims == 2:
        lo[2], hi[2] = -np.inf, np.inf
    bad = np.flatnonzero(~(lo < hi))
    if bad.size:
        k = int(bad[0])
        raise ctx.fail("space.hi", f"must be greater than space.lo on every axis; axis "
                       f"{'xyz'[k]} has lo = {lo[k]:g}, hi = {hi[k]:g}")
    return MissionSpace(lo, hi)


def _explicit_landmarks(ctx: Ctx, lms: list[LandmarkTable], dims: int
                        ) -> tuple[list[Array], list[Array], list[int | None]]:
    qs, us, ids = [], [], []
    for i, lm in enumerate(lms):
        at = f"landmarks[{i}]"
        qs.append(vector(ctx, at + ".position", lm.position, dims))
        if (lm.normal is None) == (lm.normal_angle is None):
            raise ctx.fail(at, "give exactly one of `normal = [...]` or `normal_angle = ...`")
        if lm.normal_angle is not None:
            if dims != 2:
                raise ctx.fail(at + ".normal_angle",
                               "is only allowed in 2-D scenarios; use normal = [x, y, z]")
            a = finite(ctx, at + ".normal_angle", lm.normal_angle)
            us.append(np.array([math.cos(a), math.sin(a), 0.0]))
        else:
            assert lm.normal is not None
            us.append(nonzero_unit(ctx, at + ".normal",
                                    vector(ctx, at + ".normal", lm.normal, dims)))
        ids.append(lm.id)
    return qs, us, ids


def _generator(ctx: Ctx, raw: Any, i: int, dims: int, before: int) -> tuple[Array, Array]:
    """Generator ``i``'s landmarks; ``before`` landmarks precede it (for the limit)."""
    at = f"generators[{i}]"
    if not isinstance(raw, dict):
        raise ctx.fail(at, f"expected a table, got {type(raw).__name__}")
    if "kind" not in raw:
        raise ctx.fail(at + ".kind", f"required field is missing; use one of "
                       f"{', '.join(GENERATORS)}")
    kind = raw["kind"]
    if not isinstance(kind, str) or kind not in GENERATORS:
        hint = suggest(str(kind), list(GENERATORS))
        raise ctx.fail(at + ".kind", f"unknown generator {kind!r}{hint}")
    t = GENERATORS[kind]
    check_keys(ctx, raw, t, at, extra=("kind",))
    spec = convert(ctx, {k: v for k, v in raw.items() if k != "kind"}, t, at)
    if isinstance(spec, PolygonTable):
        if spec.sides < 3:
            raise ctx.fail(at + ".sides", f"a polygon needs at least 3 sides, got {spec.sides}")
        check_landmarks(ctx, at + ".sides", spec.sides, before, "use fewer sides")
        side = positive(ctx, at + ".side", spec.side, " of metres")
        center = np.zeros(3) if spec.center is None else vector(
            ctx, at + ".center", spec.center, dims)
        return regular_polygon(spec.sides, side, center, finite(ctx, at + ".phase", spec.phase))
    if dims != 3:
        raise ctx.fail(at + ".kind", f"{kind!r} generators need a 3-D scenario (dims = 3)")
    if isinstance(spec, BoxTable):
        center = vector(ctx, at + ".center", spec.center, 3)
        if isinstance(spec.size, float):
            size = np.full(3, positive(ctx, at + ".size", spec.size, " of metres"))
        else:
            size = vector(ctx, at + ".size", spec.size, 3, n=3)
            if np.any(size <= 0):
                raise ctx.fail(at + ".size", f"must be positive lengths, got {spec.size}")
        for f in spec.faces:
            if f not in BOX_FACES:
                raise ctx.fail(at + ".faces", f"unknown face {f!r}{suggest(f, BOX_FACES)}")
        if len(set(spec.faces)) != len(spec.faces):
            raise ctx.fail(at + ".faces", f"lists a face twice: {spec.faces}")
        if spec.count is not None and spec.grid is not None:
            raise ctx.fail(at, "give either `count` (a row) or `grid = [n1, n2]`, not both")
        grid = (1, 1)
        if spec.count is not None:
            if spec.count < 1:
                raise ctx.fail(at + ".count", f"must be at least 1, got {spec.count}")
            grid = (spec.count, 1)
        elif spec.grid is not None:
            if len(spec.grid) != 2 or min(spec.grid) < 1:
                raise ctx.fail(at + ".grid", f"expected 2 positive integers, got {spec.grid}")
            grid = (spec.grid[0], spec.grid[1])
        check_landmarks(ctx, at + (".grid" if spec.grid is not None else ".count"),
                        len(spec.faces) * grid[0] * grid[1], before,
                        f"use a smaller {'grid' if spec.grid is not None else 'count'} or "
                        "fewer faces")
        return box_faces(center, size, spec.faces, grid)
    assert isinstance(spec, CylinderTable)
    center = vector(ctx, at + ".center", spec.center, 3)
    radius = positive(ctx, at + ".radius", spec.radius, " of metres")
    height = positive(ctx, at + ".height", spec.height, " of metres")
    if spec.around < 1:
        raise ctx.fail(at + ".around", f"must be at least 1, got {spec.around}")
    if spec.rows < 1:
        raise ctx.fail(at + ".rows", f"must be at least 1, got {spec.rows}")
    check_landmarks(ctx, at + ".around", spec.around * spec.rows, before,
                    "use fewer around or rows")
    return cylinder(center, radius, height, spec.around, spec.rows,
                    finite(ctx, at + ".phase", spec.phase))


def _assign_ids(ctx: Ctx, explicit: list[int | None], n_generated: int) -> list[int]:
    """The id of every landmark: explicit ones as given (non-negative, at most 2^53 − 1,
    unique), a missing one one more than the largest so far (from 1), generated ones after
    the largest. One pass, O(1) per landmark (the largest id so far kept as it goes)."""
    ids: list[int] = []
    seen: dict[int, int] = {}
    top = 0  # the largest id so far (0: none yet)
    for i, lid in enumerate(explicit):
        if lid is None:
            lid = top + 1
        elif lid < 0:
            raise ctx.fail(f"landmarks[{i}].id", f"must be a non-negative integer, got {lid}")
        elif lid > MAX_LANDMARK_ID:
            raise ctx.fail(f"landmarks[{i}].id", f"must be at most 2^53 - 1 = "
                           f"{MAX_LANDMARK_ID}, got {lid}")
        if lid in seen:
            raise ctx.fail(f"landmarks[{i}].id", f"id {lid} is already used by "
                           f"landmarks[{seen[lid]}]; ids must be unique")
        seen[lid] = i
        ids.append(lid)
        top = max(top, lid)
    return ids + list(range(top + 1, top + 1 + n_generated))


def _direction(ctx: Ctx, ag: AgentTable, at: str, dims: int) -> Array:
    if ag.direction is not None:
        if ag.yaw is not None or ag.pitch is not None:
            raise ctx.fail(at, "give either `direction` or `yaw`/`pitch`, not both")
        return nonzero_unit(ctx, at + ".direction",
                             vector(ctx, at + ".direction", ag.direction, dims))
    if ag.pitch is not None and dims == 2:
        raise ctx.fail(at + ".pitch", "is only allowed in 3-D scenarios (dims = 3)")
    yaw = 0.0 if ag.yaw is None else finite(ctx, at + ".yaw", ag.yaw)
    pitch = 0.0 if ag.pitch is None else finite(ctx, at + ".pitch", ag.pitch)
    return direction_from_angles(pitch, yaw)


def _agents(ctx: Ctx, raw: list[AgentTable], dims: int, ids: list[int], space: MissionSpace,
            r_s: float) -> list[AgentSpec]:
    if not raw:
        raise ctx.fail("agents", "no agents; add at least one [[agents]] table")
    check_agents(ctx, len(raw))
    id_arr = np.asarray(ids, dtype=np.int64)  # unique (checked by _assign_ids)
    by_id = np.argsort(id_arr, kind="stable")
    owner = np.full(id_arr.size, -1, dtype=np.intp)  #: the agent owning each landmark row
    names: dict[str, int] = {}
    out: list[AgentSpec] = []
    for i, ag in enumerate(raw):
        at = f"agents[{i}]"
        if not AGENT_ID_RE.fullmatch(ag.id):
            raise ctx.fail(at + ".id", f"{ag.id!r} is not a valid id; use 1-32 characters "
                           "from A-Z, a-z, 0-9, '_' and '-'")
        if ag.id in names:
            raise ctx.fail(at + ".id", f"duplicate agent id {ag.id!r} "
                           f"(also agents[{names[ag.id]}].id)")
        names[ag.id] = i
        p0 = vector(ctx, at + ".position", ag.position, dims)
        if not space.contains(p0):
            lo = [None if not np.isfinite(x) else float(x) for x in space.lo[:dims]]
            hi = [None if not np.isfinite(x) else float(x) for x in space.hi[:dims]]
            raise ctx.fail(at + ".position", f"{ag.position} is outside the mission space "
                           f"(space.lo = {lo}, space.hi = {hi}); move the agent inside")
        v0 = _direction(ctx, ag, at, dims)
        idx, bad, prev = _rows_of(id_arr, by_id, owner, ag.landmarks)
        if bad is not None:  # the first listed landmark that is unknown or owned already
            lid = ag.landmarks[bad]
            if prev is None:
                raise ctx.fail(f"{at}.landmarks[{bad}]", f"unknown landmark id {lid}; known "
                               f"ids are {_id_ranges(ids)}")
            other = f"agent {raw[prev].id!r}" if prev >= 0 else "this agent already"
            raise ctx.fail(f"{at}.landmarks[{bad}]", f"landmark {lid} is assigned twice "
                           f"({other} owns it); each landmark needs exactly one owner")
        owner[idx] = i
        out.append(AgentSpec(ag.id, p0, v0, idx))
    orphans = id_arr[owner < 0].tolist()
    if orphans:
        raise ctx.fail("agents", f"landmark(s) {listed(orphans)} are assigned to no agent; "
                       "add them to an agent's `landmarks` list")
    i, j, d = _closest_pair(np.array([a.p0 for a in out]))
    if d < r_s:
        raise ctx.fail(f"agents[{j}].position", f"agents {out[i].id!r} and {out[j].id!r} "
                       f"start {d:.3g} m apart, closer than the safety radius "
                       f"planner.r_s = {r_s:g} m; move them apart")
    return out


def _closest_pair(p: Array) -> tuple[int, int, float]:
    """The two closest of the positions ``p`` (n, 3) [m], i < j, and their distance (inf
    for one agent); the first such pair in row order on ties. One row at a time: O(n)
    memory."""
    best = (0, 0, math.inf)
    for i in range(p.shape[0] - 1):
        d = np.linalg.norm(p[i + 1:] - p[i], axis=-1)
        k = int(np.argmin(d))
        if d[k] < best[2]:
            best = (i, i + 1 + k, float(d[k]))
    return best


def _rows_of(id_arr: NDArray[np.int64], by_id: NDArray[np.intp], owner: NDArray[np.intp],
             listed: list[int]) -> tuple[NDArray[np.intp], int | None, int | None]:
    """The landmark rows of the ids one agent ``listed`` (vectorised), and the position of the
    first listed id that is unknown or owned already, if any, with its owner then: None
    (unknown), an earlier agent's index, or -1 (listed twice by this agent)."""
    lids = np.asarray(listed, dtype=np.int64).reshape(-1)
    if id_arr.size == 0:
        return np.zeros(0, dtype=np.intp), (0 if lids.size else None), None
    rows = by_id[np.minimum(np.searchsorted(id_arr[by_id], lids), id_arr.size - 1)]
    known = id_arr[rows] == lids
    again = np.ones(lids.size, dtype=np.bool_)  # a later copy of an id listed before
    again[np.unique(np.where(known, rows, -1 - np.arange(lids.size)), return_index=True)[1]] \
        = False
    taken = known & (owner[rows] >= 0)
    bad = ~known | taken | (known & again)
    if not bad.any():
        return np.asarray(rows, dtype=np.intp), None, None
    k = int(np.argmax(bad))
    prev = None if not known[k] else int(owner[rows[k]]) if taken[k] else -1
    return np.asarray(rows, dtype=np.intp), k, prev


def _id_ranges(ids: list[int]) -> str:
    """Compact description of a list of ids, e.g. ``1-15`` or ``1, 3, 7`` (the first
    :data:`~agent.config.limits.SHOWN` of a long irregular list, then how many)."""
    s = sorted(ids)
    if len(s) > 2 and s[-1] - s[0] + 1 == len(s):  # unique ids: consecutive
        return f"{s[0]}-{s[-1]}"
    return listed(s)[1:-1]


# ---------------------------------------------------------------------------------------
# Public API.
# ---------------------------------------------------------------------------------------


def parse_scenario(text: str, source: str = "<string>") -> Scenario:
    """Parse and validate the TOML ``text`` of a scenario; ``source`` names it in errors."""
    ctx = Ctx(source)
    check_scenario_size(source, len(text))
    try:
        raw = tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise ctx.fail("", f"invalid TOML: {e}") from None
    _check_unknown(ctx, raw)
    f = convert(ctx, raw, ScenarioFile)
    if f.dims not in (2, 3):
        raise ctx.fail("dims", f"must be 2 (planar, chapter 5) or 3, got {f.dims}")
    dims = f.dims
    d_opt = positive(ctx, "d_opt", f.d_opt, " of metres")
    duration = positive(ctx, "duration", f.duration, " of seconds")
    if f.seed < 0:
        raise ctx.fail("seed", f"must be a non-negative integer, got {f.seed}")
    params = _params(ctx, f.planner, planar=dims == 2)
    space = _space(ctx, f.space, dims)
    structure = None if f.structure is None else parse_structure(
        ctx, f.structure, dims, space.lo, space.hi, Path(source).parent)
    if structure is not None and not structure.mesh.is_file():
        raise ctx.fail("structure.mesh", f"no such mesh file {str(structure.mesh)!r}; "
                       "relative paths start at the scenario file's folder")
    visibility = parse_visibility(ctx, f.visibility, structure is not None)
    strategy = parse_strategy(ctx, f.strategy, f.trading)
    if f.camera is not None and f.inspection is None:
        raise ctx.fail("camera", "describes an inspection's camera; add an [inspection] table "
                       "or remove [camera]")
    camera = None if f.camera is None else parse_camera(ctx, f.camera)
    inspection = None if f.inspection is None else parse_inspection(
        ctx, f.inspection, strategy, camera, d_opt)
    if inspection is not None and inspection.views > 1 and dims != 3:
        raise ctx.fail("inspection.views", "view sectors need a 3-D scenario (dims = 3); "
                       "remove inspection.views")
    if not (f.lost_after >= 0.0 and np.isfinite(f.lost_after)):
        raise ctx.fail("lost_after", f"must be a non-negative number of seconds (0: never "
                       f"adopt), got {f.lost_after}")

    qs, us, explicit_ids = _explicit_landmarks(ctx, f.landmarks, dims)
    gen: list[tuple[Array, Array]] = []
    count = len(qs)  # landmarks so far, for the limit
    for i, g in enumerate(f.generators):
        gen.append(_generator(ctx, g, i, dims, count))
        count += gen[-1][0].shape[0]
    q = np.vstack([np.reshape(qs, (-1, 3)), *(g[0] for g in gen)])
    u = np.vstack([np.reshape(us, (-1, 3)), *(g[1] for g in gen)])
    if q.shape[0] == 0 and structure is None:
        raise ctx.fail("landmarks", "no landmarks; add [[landmarks]] or [[generators]] tables")
    ids = _assign_ids(ctx, explicit_ids, q.shape[0] - len(qs))
    if dims == 2:
        q[:, 2] = 0.0
        u[:, 2] = 0.0
    agents = _agents(ctx, f.agents, dims, ids, space, params.r_s)
    name = f.name if f.name is not None else (Path(source).stem or "scenario")
    return Scenario(
        name=name, seed=f.seed, planar=dims == 2, d_opt=d_opt, duration=duration,
        q=q, u=u, landmark_ids=ids, agents=agents, params=params, space=space, source=source,
        trading=f.trading, structure=structure, visibility=visibility, strategy=strategy,
        lost_after=f.lost_after, inspection=inspection,
    )


def load_scenario(path: str | Path) -> Scenario:
    """Read and validate a scenario file (see the module docstring for the format)."""
    p = Path(path)
    try:
        with p.open("rb") as fh:  # one byte over the limit at most
            data = fh.read(MAX_SCENARIO_BYTES + 1)
        check_scenario_size(str(path), len(data))
        text = data.decode("utf-8")
    except FileNotFoundError:
        raise ScenarioError(f"{path}: no such file; check the path") from None
    except IsADirectoryError:
        raise ScenarioError(f"{path}: is a directory, expected a .toml scenario file") from None
    except UnicodeDecodeError:
        raise ScenarioError(f"{path}: not UTF-8 text; is this a TOML scenario file?") from None
    except OSError as e:
        raise ScenarioError(f"{path}: cannot read: {e.strerror or e}") from None
    return parse_scenario(text, source=str(path))
