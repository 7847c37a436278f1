"""A scenario's ``[structure]`` made concrete: the mesh read and placed, landmarks sampled on
it and given to the nearest agents, and the per-agent inputs of the planner.

:mod:`agent.config` validates the table but may not import :mod:`agent.structure` (same
rank), so the mesh is read here, above both: :func:`resolve_structure` turns a scenario whose
structure is not yet sampled into one whose landmark arrays include the mesh landmarks
(ids after the others; each owned at the start by the agent nearest to it), then, in a
multi-view inspection, each landmark by its view landmarks (:mod:`agent.world.views`). Mesh
problems are reported as one-line :class:`~agent.config.validation.ScenarioError` naming the
field.

:func:`structure_inputs` gives one agent its planner inputs
(:class:`~agent.world.inputs.StructureInputs`) over the placed mesh.
"""

from __future__ import annotations

import dataclasses
import functools
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from agent.config.limits import mesh_estimate_error, voxel_error
from agent.config.structure import StructureSpec
from agent.config.validation import ScenarioError
from agent.strategy.registry import strategy_of
from agent.structure.mesh import load_structure
from agent.structure.model import StructureModel
from agent.structure.sampling import sampled_area
from agent.world.environment import environment_for
from agent.world.inputs import (
    PlannerInputs,
    StructureInputs,
    coverage_by_model,
    trade_sight_lines,
)
from agent.world.samples import mesh_landmarks
from agent.world.views import expand_views

__all__ = [
    "PlannerInputs",
    "StructureInputs",
    "coverage_by_model",
    "environment_of",
    "resolve_structure",
    "structure_inputs",
    "structure_model",
    "trade_sight_lines",
]

if TYPE_CHECKING:
    from agent.config.scenario import Scenario
    from agent.core.viewpoints import Environment

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
    q, u = mesh_landmarks(model.mesh, spec, sc.seed)  # or a prepared file's, the same
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


def structure_inputs(sc: Scenario, occlusion: bool | None = None) -> StructureInputs:
    """One agent's planner inputs over ``sc``'s placed mesh (none without a structure);
    ``occlusion`` defaults to the scenario's visibility model."""
    occ = sc.visibility == "occlusion" if occlusion is None else occlusion
    spec = sc.structure
    model = None if spec is None else structure_model(spec)
    return StructureInputs(model, occ, 0.5 if spec is None else spec.refresh, sc.params.d_w)


def environment_of(sc: Scenario) -> Environment:
    """:func:`~agent.world.environment.environment_for` over ``sc``'s placed mesh (read here,
    cached)."""
    return environment_for(sc, None if sc.structure is None else structure_model(sc.structure))
