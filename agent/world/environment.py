"""Where a drone may be and how it gets there: the candidate-viewpoint environment of a
scenario over its placed mesh, one Δt of a transit (straight, with the avoidance of problem
4.11), and the owner of each landmark at the start. Shared by the simulator (:mod:`agent.sim`)
and the agents (:mod:`agent.runtime`), so both move with the same constants. Pure: the mesh is
read by :mod:`agent.world.structure` (``environment_of(sc)`` there reads it and calls
:func:`environment_for`)."""

from __future__ import annotations

import dataclasses
import functools
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from agent.core.avoidance import active_constraints, max_step_to_boundary, safe_direction
from agent.core.viewpoints import Environment
from agent.structure.sight_lines import sight_lines
from agent.world.inputs import StructureInputs

if TYPE_CHECKING:
    from agent.config.scenario import Scenario
    from agent.core.avoidance import MissionSpace
    from agent.core.planner import PlannerParams
    from agent.core.sight import SightFn
    from agent.structure.model import StructureModel

Array = NDArray[np.float64]

CLEARANCE = 0.3  #: default least distance of a viewpoint from the structure's box [m]
#: Ticks without getting :data:`PROGRESS_M` closer to a transit's goal (nor turning the
#: camera) before the transit is given up (a drone creeping along another's safety radius
#: next to its goal would never arrive); inspection flights use the same.
STALL_TICKS = 30
PROGRESS_M = 0.01  #: [m]
#: A turn towards the goal's direction counts as progress while the angle left shrinks by
#: this much [rad] (a kinematic turn shrinks it by ω_lim·Δt every tick; a flown camera, whose
#: measured direction never settles to a milliradian, stops progressing and the transit ends)
TURN_PROGRESS_RAD = 1e-3
#: The camera counts as turned to a goal's direction within this angle [rad].
ALIGNED_RAD = 1e-3


@dataclasses.dataclass
class TransitProgress:
    """How one flight towards a goal is doing, the same rule for the simulator and the agents:
    progress is getting :data:`PROGRESS_M` closer than ever, or, still turning, the angle left
    to the goal's direction shrinking by :data:`TURN_PROGRESS_RAD`; more than
    :data:`STALL_TICKS` ticks without progress and the flight is given up."""

    best_m: float = float("inf")  #: the closest it came to the goal [m]
    best_rad: float = float("inf")  #: the smallest angle left to the goal's direction [rad]
    stall: int = 0  #: ticks without progress

    def update(self, dist_m: float, left_rad: float = 0.0) -> None:
        """One tick ended ``dist_m`` [m] from the goal, ``left_rad`` [rad] off its direction
        (0: no direction to turn to)."""
        if dist_m < self.best_m - PROGRESS_M:
            self.best_m, self.stall = dist_m, 0
        elif left_rad > ALIGNED_RAD and left_rad < self.best_rad - TURN_PROGRESS_RAD:
            self.stall = 0
        else:
            self.stall += 1
        self.best_rad = min(self.best_rad, left_rad)

    @property
    def stalled(self) -> bool:
        """No progress for more than :data:`STALL_TICKS` ticks: give the flight up."""
        return self.stall > STALL_TICKS


def environment_for(sc: Scenario, model: StructureModel | None) -> Environment:
    """Where a viewpoint may be: the mission space outside the scenario's ``keepout`` boxes,
    else outside the structure (the placed mesh ``model``'s filled voxels,
    :meth:`~agent.structure.model.StructureModel.keepout_boxes`; without a mesh the
    landmarks' bounding box) [m], ``structure.margin`` (or 0.3 m) away; with visibility
    "occlusion" the mesh's line-of-sight test (:func:`sight_for`)."""
    env = _environment(sc, model)
    sight = sight_for(sc, model)
    return env if sight is None else dataclasses.replace(env, sight=sight)


def sight_for(sc: Scenario, model: StructureModel | None) -> SightFn | None:
    """The line-of-sight test of an occlusion scenario's placed mesh ``model`` (one batched
    segment cast per call, :func:`agent.structure.sight_lines.sight_lines`); None under the
    facing model."""
    if sc.visibility != "occlusion" or model is None:
        return None
    return functools.partial(sight_lines, model)


def _environment(sc: Scenario, model: StructureModel | None) -> Environment:
    if sc.keepout is not None:
        margin = CLEARANCE if sc.structure is None else float(sc.structure.margin)
        return Environment(sc.space.lo.copy(), sc.space.hi.copy(),
                           np.asarray(sc.keepout, dtype=np.float64).reshape(-1, 2, 3), margin,
                           sc.params.r_s)
    if sc.structure is not None and model is not None:  # the solid mesh as voxel columns,
        boxes = model.keepout_boxes()  # not its bounding box
        return Environment(sc.space.lo.copy(), sc.space.hi.copy(), boxes,
                           float(sc.structure.margin), sc.params.r_s)
    box = np.array([sc.q.min(axis=0), sc.q.max(axis=0)], dtype=np.float64)[None, :, :]
    return Environment(sc.space.lo.copy(), sc.space.hi.copy(), box, CLEARANCE, sc.params.r_s)


def transit_displacement(p: Array, goal: Array, prm: PlannerParams, space: MissionSpace,
                         others: Array, inputs: StructureInputs) -> Array:
    """One Δt of a transit from p towards ``goal`` [m; world ENU]: straight at ≤ ṗ_lim with
    the collision avoidance of problem 4.11 (walls, R_s from ``others`` (k, 3) [m], the
    structure's mesh as section-4.3 rows) and the step cut at the first boundary; zero when
    no safe direction exists."""
    d = goal - p
    dist = float(np.linalg.norm(d))
    if dist <= 1e-6:
        return np.zeros(3)
    mesh = inputs.model  # the structure: section 4.3 rows and a safe step
    cons = active_constraints(p, space, others, mode=prm.avoidance, r_s=prm.r_s, d_w=prm.d_w,
                              planar=prm.planar,
                              extra=None if mesh is None else mesh.obstacles(p, prm.d_w))
    direction = safe_direction(d / dist, cons.w, cons.lam, planar=prm.planar)
    if not np.any(direction):
        return np.zeros(3)
    reach = inputs.reach(p, direction, max_step_to_boundary(p, direction, space, others,
                                                            prm.r_s))
    return np.asarray(min(prm.p_lim * prm.dt, dist, reach) * direction, dtype=np.float64)


def initial_owner(sc: Scenario) -> NDArray[np.intp]:
    """Owning agent index of each landmark row, from the agents' initial sets (row indices)."""
    owner = np.full(len(sc.landmark_ids), -1, dtype=np.intp)
    for i, a in enumerate(sc.agents):
        owner[a.landmarks] = i
    return owner
