"""Return to the launch point after the mission, with the collision avoidance of section 4.3.

The thesis ends a mission when every agent has converged; a flown drone must then get back to
the ground without meeting the others. :func:`homing_velocity` replaces the vision gradient of
the planner step by a go-to objective, p_opt = (target − p)/‖target − p‖, and keeps the rest of
figure 4.1b: the safe direction of problem 4.7 (abrupt) or 4.11 (smooth) against the walls and
the other agents' safety spheres, the speed limit ṗ_lim, and steps truncated at the first
obstacle boundary (so ‖p_i − p_j‖ ≥ R_s and p ∈ Ω hold along the path, as in the mission).

The inspected structure is not an obstacle of the mission planner (its landmarks keep the
cameras at d_opt), but on the way home it is: given as an axis-aligned box, it is kept at
R_s/2 (half the separation of two agents: the clearance one agent needs) by treating the
point R_s/2 behind its face, below the point nearest to the agent, like one more agent's
position. The path keeps R_s/2 from the box (up to s²/(2 R_s) for a step s, as the nearest
point moves) and, with the right turn below, goes round it.

Local avoidance alone deadlocks when agents meet head on (every safe direction is blocked
by symmetry). With another agent (or the structure) within R_s + D_w and ahead, the objective
therefore turns right by ``RIGHT_TURN`` in the horizontal plane, like ships keeping to
starboard: agents that meet pass each other on the same side and a crowd at a crossing turns
into a roundabout. Nothing ahead, no turn: a target beside an obstacle is approached straight
(a flown vehicle, whose velocity lags, would otherwise orbit it).

Pure numpy: positions [m; world ENU], velocities [m/s].
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from agent.core.avoidance import (
    MissionSpace,
    active_constraints,
    max_step_to_boundary,
    safe_direction,
)
from agent.core.planner import PlannerParams

Array = NDArray[np.float64]

#: Angle [rad] the go-to objective turns right while an obstacle is within R_s + D_w, ahead.
RIGHT_TURN = np.pi / 4


def homing_velocity(
    p: Array,
    target: Array,
    params: PlannerParams,
    space: MissionSpace | None = None,
    others: Array | None = None,
    structure: tuple[Array, Array] | None = None,
) -> Array:
    """Section 4.3 with a go-to objective: ṗ* [m/s] from p towards ``target`` [m].

    Direction: problem 4.7/4.11 for p_opt = unit(target − p) (xy only when ``params.planar``)
    against the walls of ``space``, the spheres of radius R_s around ``others`` (n, 3), and
    R_s/2 from the ``structure`` box (lo, hi) [m].
    Magnitude: ṗ_lim, cut to the remaining distance and to the first obstacle boundary along
    the direction. Zero when the target is within ṗ_min·Δt or no safe step exists.
    """
    space = space or MissionSpace.unbounded()
    others = np.zeros((0, 3)) if others is None else np.asarray(others, dtype=np.float64)
    if structure is not None:
        nearest = np.clip(p, structure[0], structure[1])
        if params.planar:
            nearest[2] = p[2]
        out = p - nearest
        depth = float(np.linalg.norm(out))
        if depth > 0.0:  # (inside the box there is no way out to prefer)
            virtual = nearest - (0.5 * params.r_s / depth) * out
            others = np.vstack([others.reshape(-1, 3), virtual])
    to = np.asarray(target, dtype=np.float64) - p
    if params.planar:
        to[2] = 0.0
    dist = float(np.linalg.norm(to))
    if dist <= params.p_min * params.dt:
        return np.zeros(3)
    p_opt = to / dist
    if others.shape[0]:
        offsets = others - p
        if params.planar:
            offsets[:, 2] = 0.0
        near = (offsets * offsets).sum(axis=1) < (params.r_s + params.d_w) ** 2
        if (near & (offsets @ p_opt > 0.0)).any():  # something close and ahead
            p_opt = _turned_right(p_opt, RIGHT_TURN)
    cons = active_constraints(p, space, others, mode=params.avoidance, r_s=params.r_s,
                              d_w=params.d_w, planar=params.planar)
    direction = safe_direction(p_opt, cons.w, cons.lam, planar=params.planar)
    if not np.any(direction):
        return np.zeros(3)
    reach = max_step_to_boundary(p, direction, space, others, params.r_s)
    # A step cut short by an obstacle is still taken (up to contact): in abrupt mode the
    # constraint only becomes active there, and stopping short would stall the agent.
    step = min(params.p_lim * params.dt, dist, reach)
    if step <= 0.0:
        return np.zeros(3)
    return step * direction / params.dt


def _turned_right(x: Array, angle: float) -> Array:
    """Unit ``x`` rotated clockwise (seen from above) by ``angle`` [rad] about the world z
    axis; the vertical component is kept."""
    c, s = np.cos(angle), np.sin(angle)
    return np.array([c * x[0] + s * x[1], -s * x[0] + c * x[1], x[2]])
