"""Collision avoidance (thesis section 4.3): problems 4.7 / 4.11 and the obstacle geometry.

safe_direction is checked against independent optimisers from tests/reference.py: SLSQP from
many starts in 3-D, a 20,000-angle grid plus bisection in 2-D.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from agent.core.avoidance import (
    MissionSpace,
    active_constraints,
    max_step_to_boundary,
    obstacle_distances,
    safe_direction,
)
from tests.reference import (
    Array,
    random_unit,
    safe_direction_reference_2d,
    safe_direction_reference_3d,
    slack,
)

FEAS = 1e-9  #: feasibility required of safe_direction's answer
OPT = 1e-6  #: allowed shortfall of ⟨p_opt, x⟩ against the reference optimum


def random_problem(rng: np.random.Generator, i: int, planar: bool
                   ) -> tuple[Array, Array, Array]:
    """p_opt, w, λ: a quarter abrupt (λ = 0), an eighth with a λ_dir-like extra constraint
    λ ∈ (0, 1), some λ = −1 entries, the rest λ ∈ [−1, 0]."""
    k = int(rng.integers(1, 11))
    p = random_unit(rng, planar=planar)
    w = random_unit(rng, k, planar=planar)
    lam = -rng.uniform(0.0, 1.0, k)
    kind = i % 8
    if kind in (0, 1):
        lam[:] = 0.0  # problem 4.7
    elif kind == 2:
        w = np.vstack([w, random_unit(rng, planar=planar)])  # λ_dir of section 5.2
        lam = np.append(lam, rng.uniform(0.0, 1.0))
    elif kind == 3:
        lam[rng.random(k) < 0.3] = -1.0
    elif kind == 4:
        # Mostly obstacles the optimal direction runs into (p_opt infeasible).
        w = w - 1.2 * p[None, :] * rng.random((k, 1))
        if planar:
            w[:, 2] = 0.0
        w /= np.linalg.norm(w, axis=1, keepdims=True)
    return p, w, lam


def assert_answer_ok(x: Array, p: Array, w: Array, lam: Array, ref_val: float, ref_found: bool,
                     planar: bool = False) -> None:
    if not np.any(x):
        assert not ref_found, f"safe_direction found nothing, reference found ⟨p,x⟩={ref_val}"
        return
    assert abs(float(np.linalg.norm(x)) - 1.0) <= 1e-12
    assert slack(x, p, w, lam)[0] >= -FEAS
    assert float(x @ p) >= ref_val - OPT
    if planar:
        assert abs(float(x[2])) <= 1e-15


def test_safe_direction_3d_against_slsqp() -> None:
    """600 random 3-D problems (k ∈ [1, 10]); reference = best feasible SLSQP point started
    from the returned candidate, the best feasible and the least infeasible of 4,000 Fibonacci
    directions (spacing ≈ 0.03 rad, a global screen) and one random direction; the feasible
    screened directions themselves also count. When safe_direction returns p_opt it is
    optimal by Cauchy-Schwarz (⟨p_opt, x⟩ ≤ 1) and only feasibility is checked."""
    rng = np.random.default_rng(4711)
    n_zero = n_popt = n_cons = 0
    for i in range(600):
        p, w, lam = random_problem(rng, i, planar=False)
        x = safe_direction(p, w, lam)
        if np.any(x) and float(x @ p) >= 1.0 - 1e-15:
            n_popt += 1
            assert slack(x, p, w, lam)[0] >= -FEAS
            continue
        bx, bv = safe_direction_reference_3d(
            p, w, lam, rng, extra_starts=[x] if np.any(x) else [])
        assert_answer_ok(x, p, w, lam, bv, bx is not None)
        if np.any(x):
            n_cons += 1
        else:
            n_zero += 1
    # The sample exercises all three outcomes.
    assert n_zero > 15 and n_popt > 30 and n_cons > 150, (n_zero, n_popt, n_cons)


def test_safe_direction_2d_against_angle_grid() -> None:
    """600 random planar problems; the answer must stay in the xy-plane."""
    rng = np.random.default_rng(815)
    counts = {"zero": 0, "popt": 0, "cons": 0}
    for i in range(600):
        p, w, lam = random_problem(rng, i, planar=True)
        x = safe_direction(p, w, lam, planar=True)
        phi = math.atan2(p[1], p[0])
        alphas = np.arctan2(w[:, 1], w[:, 0])
        t, val = safe_direction_reference_2d(phi, alphas, lam)
        assert_answer_ok(x, p, w, lam, val, t is not None, planar=True)
        if not np.any(x):
            counts["zero"] += 1
        elif float(x @ p) >= 1.0 - 1e-15:
            counts["popt"] += 1
        else:
            counts["cons"] += 1
            # The 2-D reference is exact (up to bisection accuracy): nothing can beat it.
            assert float(x @ p) <= val + OPT
    assert min(counts.values()) > 15, counts


def test_figure_4_5_two_obstacles_answer_orthogonal_to_p_opt() -> None:
    """Figure 4.5: each single-plane projection of p_opt is excluded by the other obstacle; the
    only acceptable directions are ±e_z, orthogonal to p_opt (objective 0)."""
    p = np.array([1.0, 0.0, 0.0])
    w = np.array([[-1.0, 1.0, 0.0], [-1.0, -1.0, 0.0]]) / math.sqrt(2.0)
    lam = np.zeros(2)
    # The premise of the figure: both projections are infeasible for the other constraint.
    for i, j in ((0, 1), (1, 0)):
        proj = p - (w[i] @ p) * w[i]
        proj /= np.linalg.norm(proj)
        assert w[j] @ proj < 0
    x = safe_direction(p, w, lam)
    assert np.linalg.norm(x) == pytest.approx(1.0)
    assert abs(x @ p) <= 1e-12
    assert slack(x, p, w, lam)[0] >= -FEAS
    assert abs(abs(x[2]) - 1.0) <= 1e-12
    # The same in a rotated frame (no axis-aligned luck).
    rng = np.random.default_rng(45)
    for _ in range(50):
        a, _ = np.linalg.qr(rng.normal(size=(3, 3)))
        pr, wr = a @ p, w @ a.T
        xr = safe_direction(pr, wr, lam)
        assert abs(xr @ pr) <= 1e-9
        assert slack(xr, pr, wr, lam)[0] >= -FEAS
        assert abs(abs(xr @ (a @ np.array([0.0, 0.0, 1.0]))) - 1.0) <= 1e-9


def test_conjecture_1_counterexample_w_equals_minus_p_opt() -> None:
    """Counterexample to Conjecture 1 / Algorithm 3 as written: with one obstacle w = −p_opt,
    λ = 0, the projection of p_opt on the plane ⟂ w is the zero vector and there is no pair of
    planes, so the thesis' candidate set is empty (Algorithm 3 returns 0), yet every unit x ⟂
    p_opt is acceptable. safe_direction must return one of them."""
    rng = np.random.default_rng(1)
    for _ in range(100):
        p = random_unit(rng)
        for planar in (False, True):
            if planar:
                p = random_unit(rng, planar=True)
            x = safe_direction(p, -p[None, :], np.zeros(1), planar=planar)
            assert np.linalg.norm(x) == pytest.approx(1.0)
            assert abs(x @ p) <= 1e-12
            if planar:
                assert x[2] == 0.0


def test_degenerate_cases() -> None:
    rng = np.random.default_rng(2)
    for _ in range(15):
        p = random_unit(rng)
        # w = −p_opt with λ < 0: the best is the whole circle ⟨p_opt, x⟩ = −λ.
        lam0 = -float(rng.uniform(0.05, 0.95))
        x = safe_direction(p, -p[None, :], np.array([lam0]))
        assert x @ p == pytest.approx(-lam0, abs=1e-12)
        # ... plus another obstacle that removes most of that circle.
        w2 = random_unit(rng)
        w = np.vstack([-p, w2])
        lam = np.array([lam0, 0.0])
        x = safe_direction(p, w, lam)
        bx, bv = safe_direction_reference_3d(p, w, lam, rng, extra_starts=[x] if np.any(x) else [])
        assert_answer_ok(x, p, w, lam, bv, bx is not None)
        # Duplicated normal (same and different λ).
        wk = random_unit(rng)
        for lam_pair in ([0.0, 0.0], [-0.3, 0.0], [-0.5, -0.2]):
            w = np.vstack([wk, wk, random_unit(rng)])
            lam = np.array([*lam_pair, -0.1])
            x = safe_direction(p, w, lam)
            bx, bv = safe_direction_reference_3d(
                p, w, lam, rng, extra_starts=[x] if np.any(x) else [])
            assert_answer_ok(x, p, w, lam, bv, bx is not None)
        # λ = −1: the constraint allows everything, the answer is p_opt.
        w = random_unit(rng, 4)
        x = safe_direction(p, w, -np.ones(4))
        np.testing.assert_allclose(x, p, atol=1e-15)
        # w = p_opt with λ ∈ (0, 1]: p_opt itself is acceptable.
        x = safe_direction(p, p[None, :], np.array([float(rng.uniform(0.0, 1.0))]))
        np.testing.assert_allclose(x, p, atol=1e-15)
        # Opposite obstacles ⟨w, x⟩ ≥ 0 and ⟨−w, x⟩ ≥ 0: only the great circle ⟂ w.
        wk = random_unit(rng)
        x = safe_direction(p, np.vstack([wk, -wk]), np.zeros(2))
        assert abs(x @ wk) <= 1e-12
        expect = math.sqrt(max(0.0, 1.0 - float(p @ wk) ** 2))
        assert x @ p == pytest.approx(expect, abs=1e-9)


def test_infeasible_returns_zero() -> None:
    p = np.array([1.0, 0.0, 0.0])
    # ⟨e_x, x⟩ ≥ 0.5 contradicts nothing, but ⟨−e_x, x⟩ ≥ 0 and ⟨p, x⟩ ≥ 0 leave x ⟂ e_x and
    # then ⟨e_y, x⟩ ≥ 0.5, ⟨−e_y, x⟩ ≥ 0.5 are contradictory.
    w = np.array([[0.0, 1.0, 0.0], [0.0, -1.0, 0.0]])
    x = safe_direction(p, w, np.array([0.5, 0.5]))
    assert np.all(x == 0.0)
    x = safe_direction(p, w, np.array([0.5, 0.5]), planar=True)
    assert np.all(x == 0.0)
    # Zero p_opt.
    assert np.all(safe_direction(np.zeros(3), np.zeros((0, 3)), np.zeros(0)) == 0.0)


def test_planar_with_out_of_plane_normals() -> None:
    """planar=True restricts x to the xy-plane: the problem is still ⟨w_i, x⟩ ≥ λ_i for the
    *given* w_i. For w = (0.6, 0, 0.8) and x in the plane this reads 0.6·x₁ ≥ λ, i.e.
    x₁ ≥ λ/0.6. BUG: safe_direction normalises the planar part of w without rescaling λ, so it
    enforces x₁ ≥ λ instead: with λ = 0.3 it returns x = (0.3, 0.954, 0), whose constraint value
    is 0.18 < 0.3 (infeasible); with λ < 0 it is needlessly conservative (suboptimal). The
    planner never passes out-of-plane normals, but the function's contract allows them."""
    w = np.array([[0.6, 0.0, 0.8]])
    p = np.array([0.0, 1.0, 0.0])
    x = safe_direction(p, w, np.array([0.3]), planar=True)
    assert x[2] == 0.0
    assert w[0] @ x >= 0.3 - FEAS, f"infeasible planar answer {x}: ⟨w, x⟩ = {w[0] @ x}"
    # Optimum: x₁ = 0.5, x₂ = √0.75.
    assert x @ p == pytest.approx(math.sqrt(0.75), abs=1e-9)


# --------------------------------------------------------------------------------------------
# Obstacle geometry: walls, other agents, active constraints, step truncation
# --------------------------------------------------------------------------------------------


def box() -> MissionSpace:
    return MissionSpace(np.array([0.0, 0.0, 0.0]), np.array([10.0, 8.0, 6.0]))


def test_mission_space() -> None:
    s = box()
    assert s.contains(np.array([5.0, 4.0, 3.0]))
    assert s.contains(np.array([0.0, 8.0, 6.0]))
    assert not s.contains(np.array([-1e-6, 4.0, 3.0]))
    assert s.contains(np.array([-1e-6, 4.0, 3.0]), tol=1e-5)
    np.testing.assert_array_equal(s.clip(np.array([-1.0, 9.0, 3.0])), [0.0, 8.0, 3.0])
    u = MissionSpace.unbounded()
    assert u.contains(np.array([1e12, -1e12, 0.0]))


def test_obstacle_distances_and_active_constraints() -> None:
    s = box()
    p = np.array([0.2, 7.9, 3.0])
    others = np.array([[1.5, 7.9, 3.0], [9.0, 1.0, 1.0]])
    r_s = 1.0
    w, d = obstacle_distances(p, s, others, r_s, planar=False)
    # Every normal is unit and points away from its obstacle; every d is the true distance.
    np.testing.assert_allclose(np.linalg.norm(w, axis=1), 1.0)
    assert len(d) == 6 + 2
    expected = sorted([0.2, 7.9, 3.0, 9.8, 0.1, 3.0,
                       1.3 - r_s, float(np.linalg.norm(p - others[1])) - r_s])
    np.testing.assert_allclose(sorted(d), expected, atol=1e-12)
    for i, wi in enumerate(w):
        # Moving by δ along ŵ_i increases obstacle i's distance by δ (to first order).
        _, d2 = obstacle_distances(p + 1e-6 * wi, s, others, r_s, planar=False)
        assert d2[i] - d[i] == pytest.approx(1e-6, rel=1e-4)

    c = active_constraints(p, s, others, mode="smooth", r_s=r_s, d_w=0.5, planar=False)
    assert np.all(c.dist < 0.5)
    np.testing.assert_allclose(c.lam, -c.dist / 0.5)
    assert len(c.lam) == 3  # the x-wall at 0.2 m, the y-wall at 0.1 m, the agent at 0.3 m
    c = active_constraints(p, s, others, mode="abrupt", r_s=r_s, d_w=0.5, planar=False)
    assert len(c.lam) == 0
    touching = np.array([0.0, 4.0, 3.0])
    c = active_constraints(touching, s, others, mode="abrupt", r_s=r_s, d_w=0.5, planar=False)
    assert len(c.lam) == 1 and np.all(c.lam == 0.0)
    np.testing.assert_allclose(c.w[0], [1.0, 0.0, 0.0])
    c = active_constraints(touching, s, others, mode="none", r_s=r_s, d_w=0.5, planar=False)
    assert len(c.lam) == 0
    # Planar: only x/y walls, agents' normals in the plane.
    w, d = obstacle_distances(p, s, others + np.array([0.0, 0.0, 2.0]), r_s, planar=True)
    assert len(d) == 4 + 2
    assert np.all(w[:, 2] == 0.0)


def test_max_step_to_boundary_is_exact() -> None:
    """The segment p + s·dir, s ∈ [0, α], stays in Ω and ≥ R_s from others; beyond α it does not
    (checked by dense sampling of the segment and a point just past α)."""
    rng = np.random.default_rng(31)
    s = box()
    r_s = 1.0
    n_checked = 0
    for _ in range(1500):
        p = rng.uniform(s.lo + 0.01, s.hi - 0.01)
        others = rng.uniform(s.lo, s.hi, (int(rng.integers(0, 4)), 3))
        others = others[np.linalg.norm(others - p, axis=1) > r_s + 1e-3]
        dirn = random_unit(rng)
        a = max_step_to_boundary(p, dirn, s, others, r_s)
        assert a >= 0.0
        ts = np.linspace(0.0, a, 200)
        pts = p + ts[:, None] * dirn
        assert np.all(pts >= s.lo - 1e-9) and np.all(pts <= s.hi + 1e-9)
        if len(others):
            dist = np.linalg.norm(pts[:, None, :] - others[None, :, :], axis=2)
            assert dist.min() >= r_s - 1e-9
        beyond = p + (a + 1e-6) * dirn
        outside = not s.contains(beyond)
        near = len(others) and np.linalg.norm(others - beyond, axis=1).min() < r_s
        assert outside or near
        n_checked += 1
    assert n_checked > 1000
    # Unbounded and alone: infinite reach.
    assert max_step_to_boundary(np.zeros(3), np.array([1.0, 0, 0]), MissionSpace.unbounded(),
                                np.zeros((0, 3)), 1.0) == math.inf


def test_max_step_at_contact_does_not_block_acceptable_directions() -> None:
    """At contact with another agent (‖p − p_j‖ = R_s, as left by a truncated step), every
    direction acceptable for problem 4.7 (⟨ŵ, x⟩ ≥ 0) moves away from, or tangentially past,
    the safety sphere: ‖p + s·x − p_j‖² = R_s² + 2s·R_s⟨ŵ, x⟩ + s² ≥ R_s² for all s ≥ 0. So the
    reach along safe_direction's answer must not collapse to 0 (it is +∞ here: no walls).

    BUG: in about a quarter of random contacts the reach is 0 or ~1e-17, because the tangent
    direction has ⟨e, x⟩ = −1e-17 by round-off (or p is 1 ulp inside the sphere) and
    max_step_to_boundary counts any b < 0 with a non-negative discriminant as a hit. The planner
    then stalls at the contact (see test_core_planner.py::test_abrupt_contact_livelock).
    """
    rng = np.random.default_rng(0)
    blocked = []
    for _ in range(500):
        r_s = float(rng.uniform(0.5, 1.5))
        p = rng.uniform(-3, 3, 3)
        other = p - r_s * random_unit(rng)
        w = (p - other) / np.linalg.norm(p - other)
        p_opt = random_unit(rng)
        if p_opt @ w > 0:
            p_opt = -p_opt  # the optimal direction runs into the other agent
        x = safe_direction(p_opt, w[None, :], np.zeros(1))
        assert w @ x >= -1e-12
        reach = max_step_to_boundary(p, x, MissionSpace.unbounded(), other[None, :], r_s)
        if reach < 1e-3:  # shorter than the planner's smallest step ṗ_min·Δt
            blocked.append((p, other, r_s, x, reach))
    assert not blocked, f"{len(blocked)}/500 contacts blocked, e.g. {blocked[0]}"
