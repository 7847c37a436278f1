"""Motion planner (thesis chapter 4): Proposition 3, the velocity limits, the constraints
p ∈ Ω and ‖p_i − p_j‖ ≥ R_s, convergence to a local maximum, and the section 5.1 example.

The vision is always recomputed from scratch with the reference eq. 3.1 (tests/reference.py),
never taken from the planner's own bookkeeping.
"""

from __future__ import annotations

import functools
import math
from dataclasses import replace

import numpy as np
import pytest

from agent.core import planner
from agent.core.avoidance import AvoidanceMode, MissionSpace, active_constraints
from agent.core.linesearch import candidate_steps, linear_search, linear_vision_bounds
from agent.core.planner import PlannerParams, PlanStep, integrate, plan_step
from agent.core.vision import (
    ExpDistance,
    GenericDistance,
    Landmarks,
    VisibleTerms,
    gradients_of,
    unit,
    visible_terms,
)
from tests.reference import Array, random_unit, rodrigues, vis_vec, vision_map_max

#: What random_setup draws: params, space, others, q, u, p, v, d_opt.
Setup = tuple[PlannerParams, MissionSpace, Array, Array, Array, Array, Array, float]


def true_vis(p: Array, v: Array, q: Array, u: Array, d_opt: float) -> float:
    return float(vis_vec(p, v, q, u, d_opt)[0])


def landmarks_on_cube(
    rng: np.random.Generator, m: int, half: float = 1.0,
) -> tuple[Array, Array]:
    """m landmarks on the faces of the cube [−half, half]³ with outward normals."""
    face = rng.integers(0, 6, m)
    q = rng.uniform(-half, half, (m, 3))
    u = np.zeros((m, 3))
    axis, sign = face // 2, np.where(face % 2 == 0, 1.0, -1.0)
    q[np.arange(m), axis] = sign * half
    u[np.arange(m), axis] = sign
    return q, u


def random_setup(rng: np.random.Generator, i: int, with_others: bool = False) -> Setup:
    """A random planner situation: mode, dimension, walls, other agents, landmarks, pose."""
    mode: AvoidanceMode = ("none", "abrupt", "smooth")[i % 3]
    planar = (i // 3) % 2 == 1
    bounded = mode != "none" and rng.random() < 0.8
    n_others = int(rng.integers(1, 4)) if with_others and mode != "none" else 0
    params = PlannerParams(
        avoidance=mode, planar=planar, r_s=float(rng.uniform(0.5, 1.5)),
        d_w=float(rng.uniform(0.2, 1.0)),
        lambda_dir=float(rng.uniform(-0.5, 0.9)) if rng.random() < 0.3 else None,
    )
    if bounded:
        lo = -rng.uniform(2.0, 6.0, 3)
        hi = rng.uniform(2.0, 6.0, 3)
        space = MissionSpace(lo, hi)
    else:
        space = MissionSpace.unbounded()
    m = int(rng.integers(1, 16))
    if rng.random() < 0.5:
        q, u = landmarks_on_cube(rng, m, half=float(rng.uniform(0.3, 1.5)))
    else:
        q = rng.uniform(-4, 4, (m, 3))
        u = random_unit(rng, m)
    if planar:
        q[:, 2] = 0.0
        u[:, 2] = 0.0
        bad = np.linalg.norm(u, axis=1) < 1e-3
        u[bad] = [1.0, 0.0, 0.0]
        u /= np.linalg.norm(u, axis=1, keepdims=True)
    box_lo = np.where(np.isfinite(space.lo), space.lo, -6.0)
    box_hi = np.where(np.isfinite(space.hi), space.hi, 6.0)
    while True:
        p = rng.uniform(box_lo, box_hi)
        if planar:
            p[2] = 0.0
        if bounded and rng.random() < 0.3:
            k = int(rng.integers(0, 2 if planar else 3))
            p[k] = space.lo[k] if rng.random() < 0.5 else space.hi[k]  # touching a wall
        others = rng.uniform(box_lo, box_hi, (n_others, 3))
        if planar:
            others[:, 2] = 0.0
        if n_others and rng.random() < 0.6:
            # An agent exactly at distance R_s (contact, problem 4.7).
            others[0] = p + params.r_s * random_unit(rng, planar=planar)
        dist = np.linalg.norm(others - p, axis=1)
        if np.all(dist >= params.r_s * (1 - 1e-12)) and space.contains(p):
            break
    v = random_unit(rng, planar=planar)
    if rng.random() < 0.5:
        # Look roughly at the landmarks so that something is visible.
        v = np.mean(q, axis=0) - p + 0.5 * random_unit(rng, planar=planar)
        if planar:
            v[2] = 0.0
        v /= np.linalg.norm(v)
    d_opt = float(rng.uniform(1.0, 4.0))
    return params, space, others, q, u, p, v, d_opt


def check_step(
    params: PlannerParams, space: MissionSpace, others: Array, q: Array, u: Array,
    d_opt: float, p: Array, v: Array, prev_dir: Array | None, stats: dict[str, int],
) -> tuple[Array, Array, Array | None]:
    """One plan_step + integrate; assert Proposition 3 and the constraints; return new pose."""
    before = true_vis(p, v, q, u, d_opt)
    feasible_start = space.contains(p, tol=1e-9) and (
        len(others) == 0 or np.linalg.norm(others - p, axis=1).min() >= params.r_s - 1e-9)
    step = plan_step(p, v, q, u, d_opt, params, space, others, prev_dir)
    p2, v2 = integrate(p, v, step.p_dot, step.omega, params.dt)
    after = true_vis(p2, v2, q, u, d_opt)
    moved = bool(np.any(step.p_dot) or np.any(step.omega))
    assert step.converged == (not moved)
    assert step.vision == pytest.approx(before, rel=1e-12, abs=1e-15)
    if moved:
        # Proposition 3: strict increase of the true vision.
        assert after > before, (before, after, step)
        # The planner's guaranteed lower bound is a lower bound of the true vision.
        assert after >= step.vision_next - 1e-12 * (1.0 + after)
        stats["moved"] += 1
    else:
        np.testing.assert_array_equal(p2, p)
        np.testing.assert_allclose(v2, v, atol=1e-15)
        stats["converged"] += 1
    # Limits of section 4.4.
    assert np.linalg.norm(step.p_dot) <= params.p_lim + 1e-12
    assert np.linalg.norm(step.omega) <= params.w_lim + 1e-12
    # Non-decreasing directions (eq. 4.3).
    assert float(step.p_dot @ step.grad_p) >= -1e-12 * np.linalg.norm(step.grad_p)
    assert float(step.omega @ step.grad_v) >= 0.0
    # Unit camera direction; planar mode keeps everything in the xy-plane.
    assert abs(np.linalg.norm(v2) - 1.0) <= 1e-12
    if params.planar:
        assert p2[2] == p[2]
        assert abs(v2[2]) <= 1e-15
    # Constraints of chapter 4, for the whole segment p → p2 (sampled) and at p2.
    if feasible_start:
        seg = p + np.linspace(0.0, 1.0, 11)[:, None] * (p2 - p)[None, :]
        assert np.all(seg >= space.lo - 1e-9) and np.all(seg <= space.hi + 1e-9)
        if len(others):
            dist = np.linalg.norm(seg[:, None, :] - others[None, :, :], axis=2)
            assert dist.min() >= params.r_s - 1e-9, dist.min()
    if np.any(step.p_dot) and params.avoidance != "none":
        # The followed direction satisfies the avoidance constraints active at p.
        cons = active_constraints(p, space, others, mode=params.avoidance, r_s=params.r_s,
                                  d_w=params.d_w, planar=params.planar)
        if len(cons.lam):
            assert np.all(cons.w @ step.p_dir >= cons.lam - 1e-9)
    if step.vision > 0:
        stats["visible"] += 1
    return p2, v2, (step.p_dir if np.any(step.p_dir) else prev_dir)


@pytest.mark.parametrize("with_others", [False, True], ids=["walls_only", "other_agents"])
def test_proposition_3_random_steps(with_others: bool) -> None:
    """100 random situations × 25 consecutive steps (all three avoidance modes, planar and 3-D,
    with and without walls / λ_dir; the second variant adds 1-3 other agents, the first of them
    exactly at distance R_s in 60 % of the situations): the true vision strictly increases at
    every non-zero step and never decreases; |ṗ| ≤ ṗ_lim, |ω| ≤ ω_lim; p stays in Ω and ≥ R_s
    from the others."""
    rng = np.random.default_rng(2718 + with_others)
    stats = {"moved": 0, "converged": 0, "visible": 0}
    for i in range(100):
        params, space, others, q, u, p, v, d_opt = random_setup(rng, i, with_others)
        prev = None
        for _ in range(25):
            p, v, prev = check_step(params, space, others, q, u, d_opt, p, v, prev, stats)
    assert stats["moved"] > 1200 and stats["converged"] > 300, stats


def test_proposition_3_starting_on_walls_and_contacts_abrupt() -> None:
    """Abrupt mode starting exactly on walls / at distance R_s from agents, in corners."""
    rng = np.random.default_rng(99)
    stats = {"moved": 0, "converged": 0, "visible": 0}
    space = MissionSpace(np.array([-3.0, -3.0, -3.0]), np.array([3.0, 3.0, 3.0]))
    for i in range(100):
        planar = i % 2 == 1
        params = PlannerParams(avoidance="abrupt", planar=planar, r_s=1.0)
        q, u = landmarks_on_cube(rng, int(rng.integers(1, 12)), half=0.5)
        if planar:
            q[:, 2] = 0.0
            u[:, 2] = 0.0
            keep = np.linalg.norm(u, axis=1) > 0
            q, u = q[keep], u[keep]
            if len(q) == 0:
                continue
        # Corner or edge of the box.
        p = np.where(rng.random(3) < 0.5, space.lo, space.hi)
        if planar:
            p[2] = 0.0
        others = (p + 1.0 * random_unit(rng, 1, planar=planar))
        if not space.contains(others[0]):
            others = np.zeros((0, 3))
        v = random_unit(rng, planar=planar)
        prev = None
        for _ in range(30):
            p, v, prev = check_step(params, space, others, q, u, 2.0, p, v, prev, stats)
    assert stats["moved"] > 500, stats


def local_max_check(
    params: PlannerParams, space: MissionSpace, others: Array, q: Array, u: Array,
    d_opt: float, p: Array, v: Array,
) -> None:
    """At a converged pose no small feasible perturbation increases the vision beyond the bound
    implied by the stopping rule.

    Position: the line search failed for every α ≥ α_min = ṗ_min·Δt along p_dir, which maximises
    ⟨∇_p, x⟩ over the feasible directions. With M ≥ |d²vis/ds²| near p, Armijo's failure at
    α_min gives ⟨∇_p, p_dir⟩ ≤ M·α_min/(2(1 − β)), so a feasible displacement δ < α_min raises
    the vision by at most ⟨∇_p, p_dir⟩·δ + M·δ²/2. M is measured by second differences (step
    1e-3) along the axes and diagonals and doubled.

    Orientation: vis(v) ≥ vis·cos φ + ‖∇_v‖·sin φ along the search arc, so Armijo's failure at
    the smallest angle α = ω_min·Δt gives ‖∇_v‖ ≤ vis·(1 − cos φ)/(sin φ − β·α), φ = atan α;
    a rotation by δ raises ⟨a, v⟩ by at most ‖∇_v‖·sin δ.
    """
    alpha_p = params.p_min * params.dt
    alpha_w = params.w_min * params.dt
    base = true_vis(p, v, q, u, d_opt)
    dirs = [np.eye(3)[k] for k in range(3)]
    dirs += [x / np.linalg.norm(x) for x in (np.array([1.0, 1, 0]), np.array([1.0, -1, 0]),
                                              np.array([1.0, 1, 1]), np.array([1.0, 0, -1]),
                                              np.array([0.0, 1, 1]))]
    if params.planar:
        dirs = [d for d in dirs if d[2] == 0.0]
    h = 1e-3
    curv = max(abs(true_vis(p + h * d, v, q, u, d_opt) - 2 * base
                   + true_vis(p - h * d, v, q, u, d_opt)) / h**2 for d in dirs)
    M = 2.0 * curv + 1e-9
    g_bound = M * alpha_p / (2.0 * (1.0 - params.beta))
    delta = 0.5 * alpha_p
    bound_p = g_bound * delta + 0.5 * M * delta**2 + 1e-13
    for d in dirs:
        for sgn in (1.0, -1.0):
            x = p + sgn * delta * d
            if not space.contains(x):
                continue
            if len(others) and np.linalg.norm(others - x, axis=1).min() < params.r_s:
                continue
            gain = true_vis(x, v, q, u, d_opt) - base
            assert gain <= bound_p, ("position", d * sgn, gain, bound_p)
    phi = math.atan(alpha_w)
    gv_bound = base * (1 - math.cos(phi)) / (math.sin(phi) - params.beta * alpha_w)
    delta_w = 0.5 * alpha_w
    bound_w = gv_bound * math.sin(delta_w) + 1e-13
    axes = [np.array([0.0, 0.0, 1.0])] if params.planar else [np.eye(3)[k] for k in range(3)]
    for ax in axes:
        for sgn in (1.0, -1.0):
            gain = true_vis(p, rodrigues(ax, sgn * delta_w) @ v, q, u, d_opt) - base
            assert gain <= bound_w, ("rotation", ax * sgn, gain, bound_w)


def optimise(
    params: PlannerParams, space: MissionSpace, others: Array, q: Array, u: Array,
    d_opt: float, p: Array, v: Array, max_steps: int = 3000,
) -> tuple[Array, Array, list[float], bool]:
    """Loop plan_step/integrate until converged; assert monotone true vision along the run."""
    vis = [true_vis(p, v, q, u, d_opt)]
    prev = None
    for _ in range(max_steps):
        step = plan_step(p, v, q, u, d_opt, params, space, others, prev)
        if step.converged:
            return p, v, vis, True
        p, v = integrate(p, v, step.p_dot, step.omega, params.dt)
        prev = step.p_dir if np.any(step.p_dir) else prev
        vis.append(true_vis(p, v, q, u, d_opt))
        assert vis[-1] > vis[-2]
        assert space.contains(p, tol=1e-9)
        if len(others):
            assert np.linalg.norm(others - p, axis=1).min() >= params.r_s - 1e-9
    return p, v, vis, False


@pytest.mark.parametrize("mode", ["none", "abrupt"])
@pytest.mark.parametrize("planar", [False, True])
def test_pose_optimisation_reaches_local_maximum(mode: AvoidanceMode, planar: bool) -> None:
    """Whole pose optimisations for landmarks on a cube: the run converges within 3,000 steps
    with monotone vision, and the final pose is a local maximum (see local_max_check).

    Smooth mode is excluded from the local-maximum check on purpose: its cones forbid moving
    towards a wall nearer than D_w, so it may legitimately stop short of the wall where a
    feasible perturbation towards the wall still improves the vision.
    """
    rng = np.random.default_rng({"none": 1, "abrupt": 2}[mode] + (10 if planar else 0))
    n_runs = 0
    while n_runs < 6:
        q, u = landmarks_on_cube(rng, int(rng.integers(2, 12)))
        if planar:
            q[:, 2] = 0.0
            u[:, 2] = 0.0
            keep = np.linalg.norm(u, axis=1) > 0
            q, u = q[keep], u[keep]
        if mode == "none":
            space, others = MissionSpace.unbounded(), np.zeros((0, 3))
        else:
            space = MissionSpace(np.full(3, -3.0), np.full(3, 3.0))
            others = np.array([[0.0, 0.0, 2.5]]) if not planar else np.array([[0.0, 2.4, 0.0]])
        params = PlannerParams(avoidance=mode, planar=planar, r_s=1.0)
        p = rng.uniform(-2.9, 2.9, 3)
        p[np.argmax(np.abs(p))] = 2.9 * np.sign(p[np.argmax(np.abs(p))])
        if planar:
            p[2] = 0.0
        if len(others) and np.linalg.norm(others - p, axis=1).min() < 1.0:
            continue
        v = random_unit(rng, planar=planar)
        d_opt = float(rng.uniform(1.5, 3.0))
        if true_vis(p, v, q, u, d_opt) == 0.0:
            v = -p / np.linalg.norm(p)  # look at the cube
            if true_vis(p, v, q, u, d_opt) == 0.0:
                continue  # nothing to optimise from here
        p, v, vis, converged = optimise(params, space, others, q, u, d_opt, p, v)
        assert converged, f"not converged after 3000 steps (vision {vis[-1]})"
        assert np.all(np.diff(vis) > 0)
        local_max_check(params, space, others, q, u, d_opt, p, v)
        n_runs += 1


def test_smooth_mode_runs_are_monotone_and_safe() -> None:
    rng = np.random.default_rng(5)
    for planar in (False, True):
        for _ in range(4):
            q, u = landmarks_on_cube(rng, int(rng.integers(2, 10)))
            if planar:
                q[:, 2] = 0.0
                u[:, 2] = 0.0
                keep = np.linalg.norm(u, axis=1) > 0
                q, u = q[keep], u[keep]
            space = MissionSpace(np.full(3, -2.5), np.full(3, 2.5))
            others = np.array([[2.0, 0.0, 0.0]])
            params = PlannerParams(avoidance="smooth", planar=planar, lambda_dir=0.5)
            p = np.array([-2.4, 1.8, 0.0 if planar else 1.0])
            v = -p / np.linalg.norm(p)
            p, v, vis, converged = optimise(params, space, others, q, u, 2.0, p, v)
            assert converged
            assert np.all(np.diff(vis) > 0)


def test_candidate_steps_algorithm_6() -> None:
    """α_k = α_0·τ^k, from α_0 down to the last one ≥ α_min (the next one would be < α_min)."""
    for a0, amin, tau in ((0.03, 0.001, 0.9), (math.pi / 40, math.pi / 1800, 0.9),
                          (1.0, 0.1, 0.5), (0.5, 0.5, 0.9)):
        s = candidate_steps(a0, amin, tau)
        assert s[0] == a0
        np.testing.assert_allclose(s[1:] / s[:-1], tau)
        assert s[-1] >= amin * (1 - 1e-12)
        assert s[-1] * tau < amin
    assert candidate_steps(0.001, 0.01, 0.9).size == 0


def test_section_5_1_single_camera_reaches_vision_map_maximum() -> None:
    """Section 5.1: landmarks eq. 5.2, p0 = (−1, 5), ψ0 = π/3, d_opt = 3, unbounded, planar.

    The reference maximum of v(p) = max_v vis(p, v) is found by Nelder-Mead over (x, y, ψ)
    on the naive eq. 3.1 from several starts. Tolerance: the planner stops when a step of
    ṗ_min·Δt (resp. ω_min·Δt) no longer passes Armijo, i.e. when ‖∇‖ ≲ ‖H‖·α_min,p + vis·α_min,ω
    (see local_max_check); near the maximum the distance is ≤ ‖∇‖/|λ_min(H)|, H being the
    Hessian of vis in (x, y, ψ) at the optimum (measured by finite differences). That bound
    is ≈ 4 cm here; we assert it, and check it is at most 5 cm.
    """
    ang = (-2 * math.pi / 3, -math.pi / 2, -math.pi / 4)
    q = np.array([[1.0, 4.5, 0.0], [2.0, 4.1, 0.0], [2.5, 4.3, 0.0]])
    u = np.array([[math.cos(a), math.sin(a), 0.0] for a in ang])
    p = np.array([-1.0, 5.0, 0.0])
    v = np.array([math.cos(math.pi / 3), math.sin(math.pi / 3), 0.0])
    params = PlannerParams(avoidance="none", planar=True)
    p, v, vis, converged = optimise(params, MissionSpace.unbounded(), np.zeros((0, 3)),
                                    q, u, 3.0, p, v)
    assert converged
    assert np.all(np.diff(vis) > 0)
    starts = [(p[0], p[1], math.atan2(v[1], v[0])), (2.0, 1.0, 1.5), (0.0, 0.0, 1.0),
              (4.0, 2.0, 2.0), (1.5, 2.5, 1.6)]
    p_star, psi_star, vis_star = vision_map_max(q, u, 3.0, starts)

    def F(z: Array) -> float:
        return true_vis(np.array([z[0], z[1], 0.0]),
                        np.array([math.cos(z[2]), math.sin(z[2]), 0.0]), q, u, 3.0)

    z0, h, H = np.array([p_star[0], p_star[1], psi_star]), 1e-3, np.zeros((3, 3))
    for i in range(3):
        for j in range(3):
            ei, ej = np.eye(3)[i] * h, np.eye(3)[j] * h
            H[i, j] = (F(z0 + ei + ej) - F(z0 + ei - ej) - F(z0 - ei + ej)
                       + F(z0 - ei - ej)) / (4 * h * h)
    ev = np.linalg.eigvalsh(H)
    assert ev.max() < 0  # a strict local maximum
    grad_bound = abs(ev).max() * params.p_min * params.dt + vis_star * params.w_min * params.dt
    tol = grad_bound / abs(ev).min()
    assert tol <= 0.05
    assert np.linalg.norm(p - p_star) <= tol
    assert vis[-1] == pytest.approx(vis_star, abs=1e-3)
    assert vis[-1] <= vis_star + 1e-9  # the reference is the maximum
    # The final orientation is (close to) optimal for the final position.
    assert abs(math.atan2(v[1], v[0]) - psi_star) <= 0.05


def test_params_are_respected_for_other_limits() -> None:
    """Different ṗ_lim / ω_lim / Δt: the commanded magnitudes stay within the limits."""
    rng = np.random.default_rng(8)
    stats = {"moved": 0, "converged": 0, "visible": 0}
    for i in range(100):
        params, space, others, q, u, p, v, d_opt = random_setup(rng, i)
        params = replace(params, dt=float(rng.uniform(0.02, 0.5)),
                         p_lim=float(rng.uniform(0.1, 2.0)), w_lim=float(rng.uniform(0.2, 2.0)))
        prev = None
        for _ in range(10):
            p, v, prev = check_step(params, space, others, q, u, d_opt, p, v, prev, stats)
    assert stats["moved"] > 300


def test_abrupt_contact_livelock() -> None:
    """Planar, abrupt, one other agent at exactly R_s (state reached by a random run of
    test_proposition_3_random_steps). A tangential move of 1 mm along the safe direction keeps
    the distance ≥ R_s and raises the vision by ≈ 9e-5, so the planner must either move (and
    strictly increase the vision, Proposition 3) or converge.

    BUG: max_step_to_boundary returns a reach of 2.8e-17 m along the tangent direction (see
    test_core_avoidance.py::test_max_step_at_contact_does_not_block_acceptable_directions);
    the line search then "accepts" that step on a 1-ulp round-off increase of its lower bound,
    so plan_step commands ṗ ≈ 1e-16 m/s forever: the vision never changes and the optimisation
    never converges (livelock).
    """
    q2 = [[-0.7133092521007799, 0.7349482596922362], [0.7349482596922362, -0.19827672764136683],
          [0.5659918126673514, -0.7349482596922362], [0.7349482596922362, -0.6994278180805001],
          [0.2851777370184053, 0.7349482596922362], [0.33933073854643825, 0.7349482596922362],
          [-0.2856405935213888, 0.6977436818482478], [-0.7349482596922362, -0.25316445713274716],
          [-0.6915551549295129, 0.7210993438638046], [0.7349482596922362, -0.14026381386645548],
          [0.5140305323354198, 0.7349482596922362], [0.7349482596922362, -0.6654124695401277]]
    u2 = [[0, 1], [1, 0], [0, -1], [1, 0], [0, 1], [0, 1], [1, 0], [-1, 0], [1, 0], [1, 0],
          [0, 1], [1, 0]]
    q = np.array([[a, b, 0.0] for a, b in q2])
    u = np.array([[a, b, 0.0] for a, b in u2], dtype=np.float64)
    d_opt = 2.0417024715904466
    params = PlannerParams(avoidance="abrupt", planar=True, r_s=0.5698310346309245)
    others = np.array([[-5.242279394751292, -0.8015970647784038, 0.0]])
    p = np.array([-5.7419799326891425, -0.5277234070214505, 0.0])
    v = np.array([0.9984864830929169, 0.05499766432075317, 0.0])
    space = MissionSpace.unbounded()
    assert abs(np.linalg.norm(p - others[0]) - params.r_s) <= 1e-15  # contact
    # The premise: a feasible 1 mm tangential move improves the vision.
    w = (p - others[0]) / np.linalg.norm(p - others[0])
    t = np.array([w[1], -w[0], 0.0])  # tangent to the safety circle
    best_gain = max(true_vis(p + s * 1e-3 * t, v, q, u, d_opt) for s in (1.0, -1.0))
    best_gain -= true_vis(p, v, q, u, d_opt)
    assert best_gain > 5e-5
    start = true_vis(p, v, q, u, d_opt)
    _, _, vis, converged = optimise(params, space, others, q, u, d_opt, p, v,
                                    max_steps=200)
    assert converged or vis[-1] > start + 1e-6, (converged, vis[-1] - start)


# --- structure inputs (occlusion mask, extra obstacles, reach) ---------------------------


def _steps_equal(a: PlanStep, b: PlanStep) -> None:
    for name in ("p_dot", "omega", "p_dir", "grad_p", "grad_v", "v_next"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)
    assert a.vision == b.vision and a.vision_next == b.vision_next


@pytest.mark.parametrize("i", range(12))
def test_unoccluded_mask_is_planning_over_the_unoccluded_subset(i: int) -> None:
    """plan_step with a mask is plan_step over the masked landmarks only (Q^V, eq. 3.15-3.16
    and the line search over the unoccluded set); an all-true mask changes nothing."""
    rng = np.random.default_rng(300 + i)
    params, space, others, q, u, p, v, d_opt = random_setup(rng, i, with_others=True)
    mask = rng.random(len(q)) < 0.6
    _steps_equal(plan_step(p, v, q, u, d_opt, params, space, others, unoccluded=mask),
                 plan_step(p, v, q[mask], u[mask], d_opt, params, space, others))
    _steps_equal(plan_step(p, v, q, u, d_opt, params, space, others,
                           unoccluded=np.ones(q.shape[0], dtype=bool)),
                 plan_step(p, v, q, u, d_opt, params, space, others))


def test_extra_obstacle_rows_deflect_like_a_wall() -> None:
    """An obstacle row (ŵ, d) passed by the caller acts exactly like the same wall of Ω."""
    params = PlannerParams(avoidance="smooth", d_w=0.5)
    q, u = np.array([[3.0, 0.0, 0.0]]), np.array([[-1.0, 0.0, 0.0]])
    p, v = np.array([0.0, 0.2, 0.0]), np.array([1.0, 0.0, 0.0])
    # A wall x ≤ 0.3 seen 0.3 m ahead: as Ω, and as an extra row ŵ = −x, d = 0.3.
    wall = MissionSpace(np.full(3, -np.inf), np.array([0.3, np.inf, np.inf]))
    as_space = plan_step(p, v, q, u, 2.0, params, wall)
    as_row = plan_step(p, v, q, u, 2.0, params, None,
                       obstacles=(np.array([[-1.0, 0.0, 0.0]]), np.array([0.3])),
                       reach=lambda p0, d, limit: min(limit, 0.3 / max(d[0], 1e-12)))
    np.testing.assert_allclose(as_row.p_dir, as_space.p_dir, atol=1e-12)
    np.testing.assert_allclose(as_row.p_dot, as_space.p_dot, atol=1e-12)
    free = plan_step(p, v, q, u, 2.0, params, None)
    assert not np.allclose(free.p_dir, as_row.p_dir)  # the row did deflect


def test_reach_truncates_the_linear_step() -> None:
    """reach(p, dir, limit) bounds the linear step: one candidate at the bound, then the
    smaller ones (as at a wall); reach 0 stops the linear motion."""
    params = PlannerParams()
    q, u = np.array([[3.0, 0.0, 0.0]]), np.array([[-1.0, 0.0, 0.0]])
    p, v = np.array([0.0, 0.0, 0.0]), np.array([1.0, 0.0, 0.0])
    calls: list[float] = []

    def reach(p0: Array, d: Array, limit: float) -> float:
        calls.append(limit)
        return 0.01

    step = plan_step(p, v, q, u, 1.0, params, None, reach=reach)
    assert calls == [pytest.approx(params.p_lim * params.dt)]
    assert np.linalg.norm(step.p_dot) * params.dt == pytest.approx(0.01)
    stop = plan_step(p, v, q, u, 1.0, params, None, reach=lambda p0, d, limit: 0.0)
    assert not np.any(stop.p_dot)


def test_unoccluded_mask_must_match_the_landmarks() -> None:
    q, u = np.array([[3.0, 0.0, 0.0]]), np.array([[-1.0, 0.0, 0.0]])
    with pytest.raises(ValueError, match=r"^unoccluded must be a mask of shape \(1,\)"):
        plan_step(np.zeros(3), np.array([1.0, 0.0, 0.0]), q, u, 1.0, PlannerParams(),
                  unoccluded=np.ones(2, dtype=bool))


# --------------------------------------------------------------------------------------------
# Certified decisions of the linear line search (agent/core/linesearch.py) change nothing
# --------------------------------------------------------------------------------------------


def _line_search_situation(
    rng: np.random.Generator,
) -> tuple[VisibleTerms, Array, Array, Array, Array, ExpDistance, float]:
    """Random Q^V terms, a unit direction, Algorithm 6 steps (sometimes truncated at an
    obstacle) and β; a quarter of the landmarks right at the camera in a third of the cases
    (inside 2·α_max and crossing the edges of Q^V)."""
    m = int(rng.integers(1, 300))
    q = rng.uniform(-3.0, 3.0, (m, 3))
    u = random_unit(rng, m)
    p, v = rng.uniform(-3.0, 3.0, 3), random_unit(rng)
    if rng.random() < 0.3:
        q[: m // 4] = p + rng.normal(scale=0.05, size=(m // 4, 3))
    term = ExpDistance(float(rng.uniform(0.3, 4.0)))
    t = visible_terms(p, v, Landmarks.of(q, u), term)
    grad_p = gradients_of(t, v, term)[0]
    direction = unit(grad_p) if rng.random() < 0.5 else random_unit(rng)
    a0 = float(rng.uniform(0.005, 0.2))
    steps = candidate_steps(a0, a0 / float(rng.uniform(2.0, 60.0)), float(rng.uniform(0.5, 0.95)))
    if rng.random() < 0.2:
        limit = steps[0] * float(rng.uniform(0.2, 1.0))
        steps = np.concatenate([[limit], steps[steps < limit]])
    return t, v, direction, grad_p, steps, term, float(rng.uniform(0.1, 0.9))


def _reference_vision_along(
    t: VisibleTerms, v: Array, direction: Array, steps: Array, d_opt: float,
) -> np.ndarray:
    """Eq. 3.1 (tests/reference.py) over the landmarks of Q^V at p + α·dir, each α of steps."""
    p = np.zeros(3)  # t.dT = q − p: place the camera at the origin
    q, u = t.dT.T, t.uT.T
    return np.array([vis_vec(p + a * direction, v, q, u, d_opt)[0] for a in steps])


def test_certified_line_search_decides_as_the_plain_search() -> None:
    """3000 random situations: the certified search (bounds decide most candidates without
    evaluating them) returns exactly, bit for bit, what evaluating every candidate returns.
    A third are forced near-ties (the Armijo threshold within a few ulp of, or 1e-12/1e-9
    relative from, a candidate's evaluated vision), a sixth have a rescaled or reversed
    gradient. The bounds also bracket the reference vision at every candidate."""
    rng = np.random.default_rng(4412)
    decided = total = 0
    for i in range(3000):
        t, v, direction, grad_p, steps, term, beta = _line_search_situation(rng)
        if t.r.size == 0:
            continue
        if i % 3 == 1:  # threshold at candidate j's own evaluated vision, give or take
            j = int(rng.integers(0, steps.size))
            at_j = linear_search(t, v, direction, -1e6 * direction, steps[j:j + 1], term, beta,
                                 certify=False).value
            nudge = float(rng.choice([0.0, 1e-15, -1e-15, 1e-12, -1e-12, 1e-9]))
            grad_p = (at_j - t.value) / steps[j] * (1.0 + nudge) / beta * direction
        elif i % 6 == 2:
            grad_p = grad_p * float(rng.uniform(-1.0, 3.0))
        fast = linear_search(t, v, direction, grad_p, steps, term, beta)
        plain = linear_search(t, v, direction, grad_p, steps, term, beta, certify=False)
        assert (fast.alpha, fast.value) == (plain.alpha, plain.value), i
        np.testing.assert_array_equal(fast.weight, plain.weight)
        np.testing.assert_array_equal(fast.dv, plain.dv)
        bounds = linear_vision_bounds(t, v, direction, steps, term)
        assert bounds is not None
        if i % 10 == 0:
            ref = _reference_vision_along(t, v, direction, steps, term.d_opt)
            tol = 1e-9 * (np.abs(ref) + 1e-12)
            assert np.all(bounds.lower - tol <= ref) and np.all(ref <= bounds.upper + tol), i
        threshold = t.value + steps * (beta * float(grad_p @ direction))
        slack = bounds.margin + 1e-11 * np.abs(threshold)
        decided += int(np.sum((bounds.upper < threshold - slack)
                              | (bounds.lower > threshold + slack)))
        total += steps.size
    assert decided > 0.6 * total, (decided, total)  # the shortcut is exercised, not bypassed
    generic = GenericDistance(lambda r: r * np.exp(-r), lambda r: (1.0 - r) * np.exp(-r))
    assert linear_vision_bounds(t, v, direction, steps, generic) is None


def test_vision_bounds_bracket_one_landmark_on_long_steps() -> None:
    """The bounds' third-order remainder where it matters most: one landmark at 0.05-3 m,
    steps up to half its distance, any d_opt. The reference eq. 3.1 vision at every candidate
    lies within [lower, upper] (and the remainder is not vacuously large)."""
    rng = np.random.default_rng(77)
    worst = 0.0
    for _ in range(2000):
        r = float(rng.uniform(0.05, 3.0))
        q, u = r * random_unit(rng, 1), random_unit(rng, 1)
        v, direction = random_unit(rng), random_unit(rng)
        term = ExpDistance(float(rng.uniform(0.1, 4.0)))
        t = visible_terms(np.zeros(3), v, Landmarks.of(q, u), term)
        a0 = r * float(rng.uniform(0.05, 0.5))
        steps = candidate_steps(a0, a0 / 10, 0.7)
        bounds = linear_vision_bounds(t, v, direction, steps, term)
        if t.r.size == 0 or bounds is None or bounds.upper[0] == bounds.lower[0]:
            continue  # not visible, or crossing an edge of Q^V (evaluated, not bounded)
        ref = _reference_vision_along(t, v, direction, steps, term.d_opt)
        mid, half = 0.5 * (bounds.upper + bounds.lower), 0.5 * (bounds.upper - bounds.lower)
        worst = max(worst, float(np.max(np.abs(ref - mid) / half)))
    assert 0.1 < worst <= 1.0, worst  # |ref − Taylor| / remainder; measured 0.21


def _wall(rng: np.random.Generator, m: int) -> tuple[np.ndarray, np.ndarray]:
    """m landmarks on the wall x = 4, normals about −x (the planner benchmark's scene)."""
    q = np.column_stack([np.full(m, 4.0), rng.uniform(0.5, 4.5, m), rng.uniform(0.2, 2.8, m)])
    u = np.array([-1.0, 0.0, 0.0]) + 0.3 * rng.normal(size=(m, 3))
    return q, u / np.linalg.norm(u, axis=1)[:, None]


@pytest.mark.parametrize("agents", ["open", "crowded"])
def test_planner_steps_unchanged_by_certified_line_search(
    agents: str, monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Whole pose optimisations in the benchmark's room (3000 landmarks, 4 other agents off
    or in the camera's way) until converged, and 40 random situations × 10 steps: every
    planner step equals, bit for bit, the step with every candidate evaluated."""
    plain_search = functools.partial(linear_search, certify=False)

    def both(
        p: Array, v: Array, q: Array, u: Array, d_opt: float, params: PlannerParams,
        space: MissionSpace, others: Array, prev_dir: Array | None = None,
    ) -> PlanStep:
        args = (p, v, q, u, d_opt, params, space, others, prev_dir)
        fast = plan_step(*args)
        with monkeypatch.context() as mp:
            mp.setattr(planner, "linear_search", plain_search)
            plain = plan_step(*args)
        _steps_equal(fast, plain)
        return fast

    rng = np.random.default_rng(5 if agents == "open" else 6)
    q, u = _wall(rng, 3000)
    others = {"open": [[0.6, 0.6, 2.4], [0.6, 4.4, 0.6], [3.0, 4.4, 2.6], [3.0, 0.6, 0.4]],
              "crowded": [[1.6, 3.6, 1.5], [2.2, 1.2, 1.2], [3.0, 4.2, 2.5], [3.0, 0.8, 0.5]]}
    params = PlannerParams(avoidance="smooth", r_s=1.0, d_w=0.5)
    space = MissionSpace(np.zeros(3), np.array([5.0, 5.0, 3.0]))
    p, v = np.array([0.4, 2.5, 1.5]), np.array([0.8, 0.6, 0.0])
    n = 0
    while not (step := both(p, v, q, u, 2.0, params, space, np.array(others[agents]))).converged:
        p, v = integrate(p, v, step.p_dot, step.omega, params.dt)
        n += 1
        assert n < 3000
    assert n > 20
    for _ in range(3):  # at the optimum, nudged: converged again or a tiny accepted step
        both(p + rng.normal(scale=1e-4, size=3), v, q, u, 2.0, params, space,
             np.array(others[agents]))
    for i in range(40):
        params, space, others_i, q, u, p, v, d_opt = random_setup(rng, i, with_others=True)
        prev = None
        for _ in range(10):
            step = both(p, v, q, u, d_opt, params, space, others_i, prev)
            p, v = integrate(p, v, step.p_dot, step.omega, params.dt)
            prev = step.p_dir if np.any(step.p_dir) else prev
