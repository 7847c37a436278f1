"""Optimal orientation (section 3.4, Algorithm 1) and latitude/longitude angles (section 2.3)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from agent.core.orientation import (
    MAX_BRUTE_FORCE_LANDMARKS,
    angle_rates,
    angles_from_direction,
    direction_from_angles,
    optimal_orientation,
)
from agent.core.vision import ExpDistance, gradients, vision
from tests.reference import Array, fibonacci_sphere, random_unit, rodrigues, vis_vec

SPHERE = fibonacci_sphere(200_000)


def test_fibonacci_reference_is_unit_and_dense() -> None:
    np.testing.assert_allclose(np.linalg.norm(SPHERE, axis=1), 1.0, atol=1e-12)
    rng = np.random.default_rng(0)
    probe = random_unit(rng, 200)
    worst = max(math.acos(min(1.0, float((SPHERE @ x).max()))) for x in probe)
    assert worst < 0.01


def test_algorithm_1_against_dense_sphere_sampling() -> None:
    """vis at Algorithm 1's v ≥ max over 200k sphere directions (it is the exact maximiser), and
    the samples get within the covering-radius bound of it: with a* = Σ over v_opt's visible set,
    vis(s) ≥ ⟨a*, s⟩ = vis(v_opt)·cos δ for the sample s nearest to v_opt (angle δ)."""
    rng = np.random.default_rng(123)
    n_nonzero = 0
    for _ in range(25):
        m = int(rng.integers(1, 9))
        d_opt = float(rng.uniform(1.0, 4.0))
        p = rng.uniform(-2, 2, 3)
        q = p + rng.uniform(-4, 4, (m, 3))
        u = random_unit(rng, m)
        facing = np.einsum("ij,ij->i", p - q, u) < 0
        u[facing & (rng.random(m) < 0.7)] *= -1.0
        v = optimal_orientation(p, q, u, d_opt)
        samples = vis_vec_many(p, q, u, d_opt)
        best = float(samples.max())
        if not np.any(v):
            # Zero only when no orientation sees anything.
            assert best == 0.0
            continue
        n_nonzero += 1
        assert np.linalg.norm(v) == pytest.approx(1.0, abs=1e-12)
        got = float(vis_vec(p, v, q, u, d_opt)[0])
        assert got >= best - 1e-12
        delta = math.acos(min(1.0, float((SPHERE @ v).max())))
        assert best >= got * math.cos(delta) - 1e-12
    assert n_nonzero > 15


def vis_vec_many(p: Array, q: Array, u: Array, d_opt: float, chunk: int = 50_000) -> Array:
    out = np.empty(len(SPHERE))
    for s in range(0, len(SPHERE), chunk):
        v = SPHERE[s:s + chunk]
        out[s:s + chunk] = vis_vec(np.repeat(p[None, :], len(v), 0), v, q, u, d_opt)
    return out


def test_algorithm_1_is_stationary_and_beats_random_orientations() -> None:
    """Eq. 3.18: ∇_v vis = 0 at v_opt; and no random orientation is better."""
    rng = np.random.default_rng(5)
    for _ in range(300):
        m = int(rng.integers(1, 12))
        p = rng.uniform(-2, 2, 3)
        q = p + rng.uniform(-4, 4, (m, 3))
        u = random_unit(rng, m)
        v = optimal_orientation(p, q, u, 2.0)
        if not np.any(v):
            continue
        best = vision(p, v, q, u, 2.0)
        _, gv = gradients(p, v, q, u, 2.0)
        assert np.linalg.norm(gv) <= 1e-12 * (1 + best)
        others = random_unit(rng, 200)
        assert vis_vec(np.repeat(p[None, :], 200, 0), others, q, u, 2.0).max() <= best + 1e-12


def test_algorithm_1_degenerate_inputs() -> None:
    p = np.zeros(3)
    # Every landmark's surface faces away from p: nothing can ever be seen.
    q = np.array([[1.0, 0.0, 0.0], [0.0, 2.0, 0.0]])
    u = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    assert np.all(optimal_orientation(p, q, u, 2.0) == 0.0)
    assert np.all(optimal_orientation(p, np.zeros((0, 3)), np.zeros((0, 3)), 2.0) == 0.0)
    # A single landmark: look straight at it.
    q = np.array([[0.0, 3.0, 4.0]])
    u = np.array([[0.0, 0.0, -1.0]])
    np.testing.assert_allclose(optimal_orientation(p, q, u, ExpDistance(2.0)), [0, 0.6, 0.8],
                               atol=1e-15)
    # Too many candidates for the brute force: refused.
    n = MAX_BRUTE_FORCE_LANDMARKS + 1
    rng = np.random.default_rng(0)
    q = rng.uniform(1, 2, (n, 3))
    u = -q / np.linalg.norm(q, axis=1, keepdims=True)
    with pytest.raises(ValueError):
        optimal_orientation(p, q, u, 2.0)


def test_angles_round_trip_eq_2_3() -> None:
    rng = np.random.default_rng(9)
    for _ in range(2000):
        lat = float(rng.uniform(-math.pi / 2 + 1e-6, math.pi / 2 - 1e-6))
        lon = float(rng.uniform(-math.pi, math.pi))
        v = direction_from_angles(lat, lon)
        # Eq. 2.3 written out.
        np.testing.assert_allclose(v, [math.cos(lat) * math.cos(lon),
                                       math.cos(lat) * math.sin(lon), math.sin(lat)], atol=1e-15)
        assert np.linalg.norm(v) == pytest.approx(1.0, abs=1e-15)
        lat2, lon2 = angles_from_direction(v)
        assert lat2 == pytest.approx(lat, abs=1e-12)
        # Longitude equal modulo 2π (ψ ∈ (−π, π]).
        assert abs(math.remainder(lon2 - lon, 2 * math.pi)) <= 1e-12
        x = random_unit(rng)
        np.testing.assert_allclose(direction_from_angles(*angles_from_direction(x)), x,
                                   atol=1e-14)
    # Poles: ψ undefined, reported as 0; the direction is still reproduced.
    for z in (1.0, -1.0):
        lat, lon = angles_from_direction(np.array([0.0, 0.0, z]))
        assert lat == pytest.approx(z * math.pi / 2) and lon == 0.0
        np.testing.assert_allclose(direction_from_angles(lat, lon), [0, 0, z], atol=1e-15)


def fd_angle_rates(v: Array, omega: Array, h: float = 1e-6) -> tuple[float, float]:
    """(θ̇, ψ̇) by central differences of the angles of v(t) = exp(t·[ω]×)·v."""
    w = float(np.linalg.norm(omega))
    th_p, ps_p = angles_from_direction(rodrigues(omega, h * w) @ v)
    th_m, ps_m = angles_from_direction(rodrigues(omega, -h * w) @ v)
    return (th_p - th_m) / (2 * h), math.remainder(ps_p - ps_m, 2 * math.pi) / (2 * h)


def test_angle_rates_thesis_decomposition() -> None:
    """Eq. 2.4-2.5 hold for the angular velocities of figure 2.3b: ω = ψ̇·ẑ + θ̇·(sin ψ, −cos ψ, 0)
    (yaw about ẑ plus pitch about the horizontal axis ⟂ v), and for any ω when θ = 0."""
    rng = np.random.default_rng(4)
    for _ in range(1000):
        lat = float(rng.uniform(-1.4, 1.4))
        lon = float(rng.uniform(-math.pi, math.pi))
        v = direction_from_angles(lat, lon)
        lat_rate, lon_rate = rng.normal(size=2)
        omega = lon_rate * np.array([0.0, 0.0, 1.0]) + lat_rate * np.array(
            [math.sin(lon), -math.cos(lon), 0.0])
        th, ps = angle_rates(omega, lat, lon)
        fth, fps = fd_angle_rates(v, omega)
        assert th == pytest.approx(fth, abs=1e-6) and ps == pytest.approx(fps, abs=1e-6)
        assert th == pytest.approx(lat_rate, abs=1e-12) and ps == pytest.approx(lon_rate, abs=1e-12)
        # Planar camera (θ = 0), any ω.
        v0 = direction_from_angles(0.0, lon)
        w_any = rng.normal(size=3)
        th, ps = angle_rates(w_any, 0.0, lon)
        fth, fps = fd_angle_rates(v0, w_any)
        assert th == pytest.approx(fth, abs=1e-6) and ps == pytest.approx(fps, abs=1e-6)


def test_angle_rates_match_finite_differences_for_planner_omega() -> None:
    """The planner commands ω ⟂ v (ω ∝ ∇_v = v × a, section 4.2). Rates of the angles of v(t)
    with v̇ = ω × v must match angle_rates.

    Eq. 2.4 (ψ̇ = ω₃) is only true when ω has no component along the horizontal heading
    (cos ψ, sin ψ, 0), e.g. θ = 0; in general ψ̇ = ω₃ − tan θ·(ω₁ cos ψ + ω₂ sin ψ). Minimal
    case: θ = π/4, ψ = 0, v = (1, 0, 1)/√2, ω = (−1, 0, 1)/√2 ⟂ v gives v̇ = (0, 1, 0), so
    ψ̇ = √2, where eq. 2.4 would say 1/√2. Then random ω ⟂ v at random (θ, ψ).
    """
    s = 1 / math.sqrt(2)
    v = np.array([s, 0.0, s])
    omega = np.array([-s, 0.0, s])
    np.testing.assert_allclose(np.cross(omega, v), [0.0, 1.0, 0.0], atol=1e-15)
    fth, fps = fd_angle_rates(v, omega)
    assert fps == pytest.approx(math.sqrt(2), abs=1e-6)
    th, ps = angle_rates(omega, math.pi / 4, 0.0)
    assert th == pytest.approx(fth, abs=1e-6)
    assert ps == pytest.approx(fps, abs=1e-6), f"ψ̇: angle_rates {ps}, finite differences {fps}"
    rng = np.random.default_rng(5)
    for _ in range(1000):
        lat = float(rng.uniform(-1.3, 1.3))
        lon = float(rng.uniform(-math.pi, math.pi))
        v = direction_from_angles(lat, lon)
        omega = np.cross(v, rng.normal(size=3))  # ⟂ v, like the planner's ω
        th, ps = angle_rates(omega, lat, lon)
        fth, fps = fd_angle_rates(v, omega)
        assert th == pytest.approx(fth, abs=1e-5) and ps == pytest.approx(fps, abs=1e-5)
