"""The motion planner of chapter 4 (figure 4.1b): optimal velocity, collision avoidance,
magnitude control, and the integrator of eq. 5.1.

One call of :func:`plan_step` is one iteration of pose optimisation for one agent:

1. Q^V and the gradients (eq. 3.15, 3.16); directions of steepest ascent (eq. 4.5).
2. Collision avoidance: the safe linear direction (problem 4.7 or 4.11, plus λ_dir of 5.2).
3. Backtracking line search (Algorithm 6, gradient-form Armijo) for |ṗ| then |ω|.

The linear step is searched first; the angular step is then accepted against the vision at
the new position (the thesis computes both from the same state, which does not by itself
guarantee that the combined step increases the vision). Together with the lower-bound
evaluation in :mod:`agent.core.linesearch` this makes Proposition 3 hold for every step.
Steps are truncated where they would meet a wall or another agent's safety sphere, so the
constraints p ∈ Ω and ‖p_i − p_j‖ ≥ R_s hold along the whole path, not only instantaneously.

A structure (a mesh, handled outside the core) enters as plain data computed by the caller:
``unoccluded``, a mask of the landmarks whose line of sight the structure does not cross
(Q^V, the gradients and the line search are then taken over the unoccluded set only);
``obstacles``, extra rows (ŵ, d) of section 4.3 (closest points on the mesh); and ``reach``,
the longest safe step along a direction (the structure's clearance, and the distance over
which the unoccluded mask is trusted), which truncates the linear step like a wall does.

A gimbal's pitch range enters as ``tilt`` (:class:`~agent.core.tilt.TiltLimits`): the angular
step is then a projected-gradient step that never leaves the range (none: the thesis).
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from agent.core.avoidance import (
    AvoidanceMode,
    MissionSpace,
    active_constraints,
    max_step_to_boundary,
    safe_direction,
)
from agent.core.linesearch import (
    AngularStep,
    LinearStep,
    angular_search,
    candidate_steps,
    linear_search,
)
from agent.core.tilt import TiltLimits
from agent.core.vision import (
    DistanceTerm,
    Landmarks,
    as_distance_term,
    cross,
    gradients_of,
    unit,
    visible_terms,
)

Array = NDArray[np.float64]
Mask = NDArray[np.bool_]
#: reach(p, direction, limit): the largest safe step α ∈ [0, limit] [m] from p (3,) [m; world
#: ENU] along the unit direction (3,); computed by the caller (e.g. a structure's clearance).
ReachFn = Callable[[Array, Array, float], float]
_XY = np.array([1.0, 1.0, 0.0])
_Z = np.array([0.0, 0.0, 1.0])

__all__ = [
    "MissionSpace",
    "PlanStep",
    "PlannerParams",
    "TiltLimits",
    "integrate",
    "plan_step",
    "safe_direction",
]


@dataclass(frozen=True)
class PlannerParams:
    """Constants of chapters 4-5. Units: s, m, m/s, rad/s."""

    dt: float = 0.1  #: sampling time Δt [s]
    p_lim: float = 0.3  #: ṗ_lim, largest linear speed [m/s]
    p_min: float = 0.01  #: ṗ_min, smallest linear speed worth commanding [m/s]
    w_lim: float = np.pi / 4  #: ω_lim [rad/s]
    w_min: float = np.pi / 180  #: ω_min [rad/s]
    tau: float = 0.9  #: backtracking factor τ ∈ (0, 1)
    beta: float = 0.5  #: Armijo fraction β ∈ (0, 1)
    avoidance: AvoidanceMode = "smooth"
    r_s: float = 1.0  #: safety radius R_s [m]
    d_w: float = 0.5  #: worry distance D_w [m] (smooth mode)
    lambda_dir: float | None = None  #: direction-change limit λ_dir of section 5.2
    planar: bool = False  #: 2-D mode of chapter 5: positions in the xy-plane, yaw only

    @functools.cached_property
    def _steps(self) -> tuple[Array, Array]:
        lin = candidate_steps(self.p_lim * self.dt, self.p_min * self.dt, self.tau)
        ang = candidate_steps(self.w_lim * self.dt, self.w_min * self.dt, self.tau)
        lin.flags.writeable = False
        ang.flags.writeable = False
        return lin, ang

    def linear_steps(self) -> Array:
        """Algorithm 6 candidate distances α_k [m] from ṗ_lim·Δt down to ṗ_min·Δt (read-only)."""
        return self._steps[0]

    def angular_steps(self) -> Array:
        """Algorithm 6 candidate angles [rad] from ω_lim·Δt down to ω_min·Δt (read-only)."""
        return self._steps[1]


@dataclass(frozen=True)
class PlanStep:
    """Output of one planner iteration: commanded ṗ* [m/s], ω* [rad/s; world] and bookkeeping."""

    p_dot: Array
    omega: Array
    p_dir: Array  #: linear direction followed (unit, or zero)
    vision: float  #: vision before the step
    vision_next: float  #: guaranteed lower bound of the vision after the step
    grad_p: Array
    grad_v: Array
    v_next: Array  #: camera direction after the step (eq. 5.1, re-normalised)

    @property
    def converged(self) -> bool:
        """Section 4.4: both magnitudes fell below their minimum (no accepted step)."""
        return not (np.any(self.p_dot) or np.any(self.omega))


def plan_step(
    p: Array,
    v: Array,
    q: Array | Landmarks,
    u: Array | None,
    d_opt: float | DistanceTerm,
    params: PlannerParams,
    space: MissionSpace | None = None,
    others: Array | None = None,
    prev_dir: Array | None = None,
    *,
    unoccluded: Mask | None = None,
    obstacles: tuple[Array, Array] | None = None,
    reach: ReachFn | None = None,
    tilt: TiltLimits | None = None,
) -> PlanStep:
    """One pose-optimisation iteration (sections 4.2-4.4) for camera (p, v) over its set (q, u).

    ``q``, ``u`` are (m, 3) arrays, or ``q`` is a prepared :class:`Landmarks` and ``u`` None.

    ``others`` (n, 3) are the other agents' positions [m]; ``prev_dir`` the previous linear
    direction (for λ_dir; ignored when the previous step did not move).

    Structure (all optional, computed by the caller): ``unoccluded`` (m,) keeps only the
    landmarks not hidden by the structure (section 4.2 restricted to them, so eq. 3.15-3.16
    and the line search of Algorithm 6 use the unoccluded set); ``obstacles`` = (ŵ (k, 3),
    d (k,) [m]) are extra section-4.3 obstacles; ``reach`` bounds the linear step [m].
    ``tilt`` bounds the camera tilt θ (eq. 2.3): the angular direction is the projected
    gradient and its step stops at the limit (:mod:`agent.core.tilt`).
    """
    term = as_distance_term(d_opt)
    space = space or MissionSpace.unbounded()
    others = np.zeros((0, 3)) if others is None else others
    if isinstance(q, Landmarks):
        lm = q
    elif u is not None:
        lm = Landmarks.of(q, u)
    else:
        raise ValueError("u (the landmarks' normals) is required when q is an array")
    if unoccluded is not None:
        if unoccluded.shape != (lm.m,):
            raise ValueError(f"unoccluded must be a mask of shape ({lm.m},), one per landmark, "
                             f"got {unoccluded.shape}")
        keep = np.flatnonzero(unoccluded)
        if keep.size != lm.m:
            lm = Landmarks(lm.qT[:, keep], lm.uT[:, keep])
    t = visible_terms(p, v, lm, term)
    vision_now = t.value
    grad_p, grad_v = gradients_of(t, v, term)
    if params.planar:
        grad_p = grad_p * _XY
        grad_v = grad_v * _Z

    # Sections 4.2-4.3: direction of the linear velocity.
    p_opt = unit(grad_p)
    p_dir = np.zeros(3)
    if np.any(p_opt):
        cons = active_constraints(
            p, space, others, mode=params.avoidance, r_s=params.r_s, d_w=params.d_w,
            planar=params.planar, extra=obstacles,
        )
        if params.lambda_dir is not None and prev_dir is not None and np.any(prev_dir):
            cons = cons.with_direction_limit(prev_dir, params.lambda_dir)
        p_dir = safe_direction(p_opt, cons.w, cons.lam, planar=params.planar)

    # Section 4.4: magnitudes; linear steps truncated at the first obstacle boundary.
    lin = LinearStep(0.0, vision_now, t.fb * t.pu, t.dv)
    if np.any(p_dir):
        limit = max_step_to_boundary(p, p_dir, space, others, params.r_s)
        steps = params.linear_steps()
        if reach is not None and steps.size:
            limit = min(limit, reach(p, p_dir, float(min(limit, steps[0]))))
        if steps.size and limit < steps[0]:  # truncated: one candidate at the boundary
            steps = np.concatenate([[limit], steps[steps < limit]])
        lin = linear_search(t, v, p_dir, grad_p, steps, term, params.beta)
    if lin.alpha == 0.0:
        p_dir = np.zeros(3)
    omega_dir = unit(grad_v if tilt is None else tilt.project(v, grad_v))
    ang = AngularStep(0.0, lin.value, v)
    if np.any(omega_dir):
        steps = params.angular_steps()
        if tilt is not None and steps.size:  # cut at the tilt limit, as at a wall
            limit = tilt.max_step(v, cross(omega_dir, v))
            if limit < steps[0]:
                steps = np.concatenate([[limit], steps[steps < limit]])
        ang = angular_search(t, v, lin, lin.alpha * p_dir, omega_dir, grad_v, steps, params.beta)
    return PlanStep(
        p_dot=lin.alpha * p_dir / params.dt,
        omega=ang.alpha * omega_dir / params.dt,
        p_dir=p_dir,
        vision=vision_now,
        vision_next=ang.value,
        grad_p=grad_p,
        grad_v=grad_v,
        v_next=ang.v_next,
    )


def integrate(p: Array, v: Array, p_dot: Array, omega: Array, dt: float) -> tuple[Array, Array]:
    """Eq. 5.1 with re-normalisation: p + ṗ·Δt, (v + (ω × v)·Δt)/‖·‖."""
    v_new = v + cross(omega, v) * dt
    return p + p_dot * dt, v_new / np.linalg.norm(v_new)
