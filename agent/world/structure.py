"""A scenario's ``[structure]`` made concrete: the mesh read and placed, landmarks sampled on
it and given to the nearest agents, and the per-agent inputs of the planner.

:mod:`agent.config` validates the table but may not import :mod:`agent.structure` (same
rank), so the mesh is read here, above both: :func:`resolve_structure` turns a scenario whose
structure is not yet sampled into one whose landmark arrays include the mesh landmarks
(ids after the others; each owned at the start by the agent nearest to it), then, in a
multi-view inspection, each landmark by its view landmarks (:mod:`agent.world.views`). Mesh
problems are reported as one-line :class:`~agent.config.validation.ScenarioError` naming the
field.

:class:`StructureInputs` is what one agent passes to :func:`agent.core.planner.plan_step`
each step: the unoccluded mask (visibility = "occlusion"), the structure's obstacle rows and
the safe-step bound (always: the structure is an obstacle under either visibility model).
"""

from __future__ import annotations

import dataclasses
import functools
from typing import TYPE_CHECKING, TypedDict

import numpy as np
from numpy.typing import NDArray

from agent.config.limits import mesh_estimate_error, voxel_error
from agent.config.structure import StructureSpec
from agent.config.validation import ScenarioError
from agent.core.planner import ReachFn
from agent.core.vision import Landmarks, per_landmark
from agent.strategy.registry import strategy_of
from agent.structure.mesh import load_structure
from agent.structure.model import OcclusionTracker, StructureModel
from agent.structure.sampling import sample_landmarks, sampled_area
from agent.world.views import expand_views

if TYPE_CHECKING:
    from agent.config.scenario import Scenario

Array = NDArray[np.float64]
Mask = NDArray[np.bool_]


def structure_model(spec: StructureSpec) -> StructureModel:
    """The placed mesh of ``spec`` with its ray caster and clearance (cached per placement)."""
    return _placed(str(spec.mesh), spec.position, spec.yaw, spec.scale, spec.margin)


@functools.lru_cache(maxsize=8)
def _placed(path: str, position: tuple[float, float, float], yaw: float, scale: float,
            margin: float) -> StructureModel:
    """Read and place one mesh [m; world ENU]; a file problem is one ScenarioError line."""
    try:
        mesh = load_structure(path, position, yaw, scale=scale)
    except ValueError as exc:
        raise ScenarioError(f"structure.mesh: {exc}") from None
    return StructureModel(mesh, margin)


def resolve_structure(sc: Scenario) -> Scenario:
    """``sc`` with its mesh landmarks sampled and assigned, then with ``inspection.views``
    > 1 each landmark replaced by its view landmarks (:func:`agent.world.views.expand_views`);
    unchanged without a structure and views, or when resolved already."""
    return expand_views(_sample_structure(sc))


def _sample_structure(sc: Scenario) -> Scenario:
    """``sc`` with its mesh landmarks sampled and assigned (unchanged without a structure)."""
    spec = sc.structure
    if spec is None or spec.sampled:
        return sc

    def fail(field: str, what: str) -> ScenarioError:
        return ScenarioError(f"{sc.source}: {field}: {what}")

    try:
        model = structure_model(spec)
    except ScenarioError as exc:
        raise ScenarioError(f"{sc.source}: {exc}") from None
    dist = model.distance(np.array([a.p0 for a in sc.agents]))
    for i, d in enumerate(dist):
        if d < spec.margin:
            where = "is inside the structure" if d < 0 else \
                f"is {d:.3g} m from the structure, closer than structure.margin = {spec.margin:g} m"
            raise fail(f"agents[{i}].position", f"{where}; move the agent away from it")
    voxels = strategy_of(sc.strategy).coverage_moves or sc.inspection is not None  # voxelised then
    if voxels and (err := voxel_error(sc.source, spec.margin, model.mesh.extents.tolist())):
        raise ScenarioError(err)
    area = sampled_area(model.mesh, z_min=spec.z_min, region=spec.region,
                        min_normal_z=spec.min_normal_z)  # bounded before sampling
    if err := mesh_estimate_error(sc.source, spec.spacing, area, sc.q.shape[0]):
        raise ScenarioError(err)
    q, u = sample_landmarks(model.mesh, spec.spacing, seed=sc.seed, z_min=spec.z_min,
                            region=spec.region, min_normal_z=spec.min_normal_z)
    if q.shape[0] == 0:
        raise fail("structure", "no landmarks left on the mesh after the filters (z_min, "
                   "min_normal_z, region, mission space); relax them")
    nearest = _nearest_agent(q, np.array([a.p0 for a in sc.agents]))
    start = max(sc.landmark_ids, default=0) + 1
    base = sc.q.shape[0]
    agents = [
        dataclasses.replace(a, landmarks=np.concatenate(
            [a.landmarks, base + np.flatnonzero(nearest == i)]).astype(np.intp))
        for i, a in enumerate(sc.agents)
    ]
    return dataclasses.replace(
        sc, q=np.vstack([sc.q, q]), u=np.vstack([sc.u, u]),
        landmark_ids=list(sc.landmark_ids) + list(range(start, start + q.shape[0])),
        agents=agents, structure=dataclasses.replace(spec, sampled=True),
    )


def _nearest_agent(q: Array, p0: Array) -> NDArray[np.intp]:
    """For each landmark q (m, 3) [m] the index of the nearest agent start p0 (n, 3), the
    first on ties; one agent at a time (O(m) memory, not O(m·n))."""
    best = np.full(q.shape[0], np.inf)
    nearest = np.zeros(q.shape[0], dtype=np.intp)
    for i in range(p0.shape[0]):
        d2 = ((q - p0[i]) ** 2).sum(axis=1)
        closer = d2 < best
        best[closer], nearest[closer] = d2[closer], i
    return nearest


class PlannerInputs(TypedDict, total=False):
    """The structure's keyword arguments of :func:`agent.core.planner.plan_step`."""

    unoccluded: Mask
    obstacles: tuple[Array, Array]
    reach: ReachFn


class StructureInputs:
    """One agent's structure inputs to :func:`agent.core.planner.plan_step` (none when the
    scenario has no structure, so the call is exactly the one without a mesh)."""

    def __init__(self, spec: StructureSpec | None, occlusion: bool, d_w: float) -> None:
        self.model = None if spec is None else structure_model(spec)
        self.d_w = d_w
        self.tracker = None if self.model is None or not occlusion or spec is None \
            else OcclusionTracker(self.model, spec.refresh)

    @staticmethod
    def of(sc: Scenario) -> StructureInputs:
        """The inputs for one agent of ``sc``."""
        return StructureInputs(sc.structure, sc.visibility == "occlusion", sc.params.d_w)

    def planner_inputs(self, p: Array, lm: Landmarks) -> PlannerInputs:
        """For camera p [m] over the set ``lm``: the unoccluded mask (visibility
        "occlusion", recast after ``refresh`` m), the structure's section-4.3 rows (ŵ, d)
        and the safe-step bound; empty without a structure."""
        if self.model is None:
            return {}
        out: PlannerInputs = {"obstacles": self.model.obstacles(p, self.d_w),
                              "reach": self.reach}
        if self.tracker is not None:
            out["unoccluded"] = self.tracker.mask(p, lm.qT.T, lm.uT.T)
        return out

    def seen_vision(self, each: Array, p: Array, lm: Landmarks) -> Array:
        """Per-landmark vision ``each`` (m,) of the set ``lm`` from camera p [m; world ENU]
        with the landmarks the structure hides set to 0 (visibility "occlusion", the
        planner's cached mask); ``each`` unchanged under the facing model."""
        if self.tracker is None or lm.m == 0:
            return each
        return np.where(self.tracker.mask(p, lm.qT.T, lm.uT.T), each, 0.0)

    def reach(self, p: Array, direction: Array, limit: float) -> float:
        """Largest safe linear step [m] (clearance, and the occlusion refresh ball)."""
        if self.tracker is not None:
            return self.tracker.reach(p, direction, limit)
        return limit if self.model is None else self.model.reach(p, direction, limit)


def trade_sight_lines(model: StructureModel | None, p_a: Array, p_b: Array, q: Array, u: Array
                      ) -> tuple[Mask | None, Mask | None]:
    """Algorithm 7's occlusion masks: whether each landmark (q, u (m, 3) [m; world ENU]) has a
    clear line of sight from camera p_a, from camera p_b [m] (fresh casts); (None, None)
    under the facing model (no mesh given). The simulator and the agents both use this."""
    if model is None:
        return None, None
    return model.unoccluded(p_a, q, u), model.unoccluded(p_b, q, u)


def coverage_by_model(model: StructureModel, positions: Array, directions: Array, q: Array,
                      u: Array, owner: NDArray[np.intp], d_opt: float) -> tuple[float, float]:
    """Eq. 3.10 under both visibility models, (facing, occlusion): agents at ``positions``,
    ``directions`` (n, 3) [m; world ENU]; ``owner[j]`` the agent of landmark j. The occlusion
    score keeps a landmark only if the segment from its camera crosses no triangle (fresh
    casts, not the agents' cached masks)."""
    facing = occluded = 0.0
    for i in range(positions.shape[0]):  # loop over agents; landmarks are vectorised
        mine = np.flatnonzero(owner == i)
        if mine.size == 0:
            continue
        each = per_landmark(positions[i], directions[i], q[mine], u[mine], d_opt)
        facing += float(each.sum())
        seen = each > 0.0
        if seen.any():
            clear = model.unoccluded(positions[i], q[mine[seen]], u[mine[seen]])
            occluded += float(each[seen][clear].sum())
    return facing, occluded
