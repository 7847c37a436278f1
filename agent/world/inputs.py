"""What the placed structure gives the planner and Algorithm 7, once the mesh is read
(:func:`agent.world.structure.structure_model`): :class:`StructureInputs`, what one agent passes
to :func:`agent.core.planner.plan_step` each step (the unoccluded mask under visibility
"occlusion", the structure's obstacle rows and the safe-step bound: the structure is an
obstacle under either visibility model), and the occlusion masks of a trade. Pure: no file is
read here.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import TypedDict

import numpy as np
from numpy.typing import NDArray

from agent.core.inspection import CaptureTable
from agent.core.planner import ReachFn
from agent.core.viewpoints import Environment
from agent.core.vision import Landmarks, per_landmark
from agent.structure.model import OcclusionTracker, StructureModel
from agent.structure.routes import RouteGrid

Array = NDArray[np.float64]
Mask = NDArray[np.bool_]

__all__ = ["PlannerInputs", "StructureInputs", "World", "coverage_by_model",
           "trade_sight_lines"]


@dataclass(frozen=True)
class World:
    """What a mission's structure gives an agent core, prepared outside it
    (:func:`agent.world.prepare.prepare_world`: the mesh read and placed, an inspection's
    tables built), so that the core reads no file: the placed mesh ``model`` [m; world ENU]
    (None without a structure), an inspection's capture table and route grid (None for a
    coverage mission), and the candidate-viewpoint environment, computed from the mesh on
    first use (:func:`agent.world.environment.environment_for`)."""

    model: StructureModel | None
    tables: tuple[CaptureTable, RouteGrid | None] | None
    environment: Callable[[], Environment]


class PlannerInputs(TypedDict, total=False):
    """The structure's keyword arguments of :func:`agent.core.planner.plan_step`."""

    unoccluded: Mask
    obstacles: tuple[Array, Array]
    reach: ReachFn


class StructureInputs:
    """One agent's structure inputs to :func:`agent.core.planner.plan_step` (none when the
    scenario has no structure, so the call is exactly the one without a mesh)."""

    def __init__(self, model: StructureModel | None, occlusion: bool, refresh: float,
                 d_w: float) -> None:
        self.model = model
        self.d_w = d_w
        self.tracker = None if model is None or not occlusion \
            else OcclusionTracker(model, refresh)

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
