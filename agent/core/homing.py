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

Local avoidance alone also dithers against a long face of the structure when the target lies
beyond it (the virtual agent slides with the nearest point, so every step is blocked the
same way). :func:`detour_waypoints` therefore plans the way round first: the shortest
horizontal path from the start to the target over the corners of the structure's box
inflated by a clearance (a visibility graph of at most six nodes); the drone flies it
waypoint by waypoint with :func:`homing_velocity`.

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
#: How far into the kept layer round the structure a drone may be and still be routed round
#: it [m] (the avoidance lets a step cut s²/(2 R_s) into it).
LAYER_TOL = 0.05


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


def _segment_crosses_rect(a: Array, b: Array, lo: Array, hi: Array) -> bool:
    """Whether the 2-D segment a → b [m] passes through the open rectangle (lo, hi) [m]
    (Liang-Barsky clipping; touching the boundary does not count)."""
    d = b - a
    t0, t1 = 0.0, 1.0
    for k in range(2):  # the two axes
        if abs(d[k]) < 1e-12:
            if not lo[k] < a[k] < hi[k]:
                return False
            continue
        ta, tb = (lo[k] - a[k]) / d[k], (hi[k] - a[k]) / d[k]
        t0, t1 = max(t0, min(ta, tb)), min(t1, max(ta, tb))
    return t1 - t0 > 1e-9


def detour_waypoints(p: Array, target: Array, box: tuple[Array, Array], keep: float,
                     corner: float) -> Array:
    """Waypoints (k, 3) [m; world ENU] at p's height from p round the box (lo, hi) [m] to
    ``target`` (its own height, last): the shortest path over the corners of the box
    inflated horizontally by ``corner`` [m] that never enters the box inflated by ``keep``
    [m] (< ``corner``; a drone pressed against that layer, up to :data:`LAYER_TOL` into it,
    is outside). Just ``target`` when the straight way clears it, or when p or the target
    is inside it (no way round to prefer; local avoidance takes over)."""
    lo, hi = box[0][:2] - keep + LAYER_TOL, box[1][:2] + keep - LAYER_TOL
    a, b = p[:2], target[:2]
    inside = [bool(np.all(x > lo) and np.all(x < hi)) for x in (a, b)]
    if any(inside) or not _segment_crosses_rect(a, b, lo, hi):
        return np.asarray(target, dtype=np.float64)[None, :].copy()
    c_lo, c_hi = box[0][:2] - corner, box[1][:2] + corner
    corners = np.array([[c_lo[0], c_lo[1]], [c_hi[0], c_lo[1]], [c_hi[0], c_hi[1]],
                        [c_lo[0], c_hi[1]]])
    nodes = np.vstack([a, corners, b])  # 0 start, 1-4 corners, 5 target
    n = nodes.shape[0]
    dist = np.full((n, n), np.inf)
    for i in range(n):  # a visibility graph of six nodes
        for j in range(i + 1, n):
            if not _segment_crosses_rect(nodes[i], nodes[j], lo, hi):
                dist[i, j] = dist[j, i] = float(np.linalg.norm(nodes[i] - nodes[j]))
    best = np.full(n, np.inf)
    prev = np.full(n, -1)
    best[0] = 0.0
    todo = set(range(n))
    while todo:  # Dijkstra over the six nodes
        i = min(todo, key=lambda k: best[k])
        todo.remove(i)
        relax = best[i] + dist[i] < best
        best[relax], prev[relax] = (best[i] + dist[i])[relax], i
    path = []
    k = n - 1
    while k > 0:
        path.append(k)
        k = int(prev[k])
    path.reverse()
    out = [[*nodes[k], p[2]] for k in path[:-1]] + [list(target)]
    return np.asarray(out, dtype=np.float64).reshape(-1, 3)
