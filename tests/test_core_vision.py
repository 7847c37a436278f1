"""Vision function (thesis eq. 3.1-3.10) and its gradients (eq. 3.15-3.16).

Every expected value comes from tests/reference.py (eq. 3.1 written with plain loops) or from
central finite differences of the vision itself; nothing here is tuned to agent/ output.
"""

from __future__ import annotations

import math
from functools import partial

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from agent.core.vision import (
    DistanceTerm,
    ExpDistance,
    GenericDistance,
    Landmarks,
    coverage_score,
    gradients,
    per_landmark,
    per_landmark_cols,
    vision,
)
from tests.reference import Array, f_exp, random_unit, rodrigues, vis_naive, vis_one

Distance = float | DistanceTerm  #: d_opt, or a distance term (f and its derivative)

SETTINGS = settings(
    derandomize=True,
    deadline=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
)


def random_config(rng: np.random.Generator, m: int, spread: float = 4.0
                  ) -> tuple[Array, Array, Array, Array]:
    """Camera (p, v) and m landmarks (q, u), normals biased towards the camera half the time."""
    p = rng.uniform(-2.0, 2.0, 3)
    v = random_unit(rng)
    q = p + rng.uniform(-spread, spread, (m, 3))
    u = random_unit(rng, m)
    flip = rng.random(m) < 0.5
    # Half of the normals face the camera (⟨p − q, u⟩ > 0) so many landmarks are visible.
    facing = np.einsum("ij,ij->i", p - q, u) < 0
    u[flip & facing] *= -1.0
    return p, v, q, u


def _f_exp_array(r: Array, d: float) -> Array:
    """Eq. 3.6 on an array of distances: f(r) = (r/d)·exp(1 − r/d)."""
    return (r / d) * np.exp(1.0 - r / d)


def _df_exp_array(r: Array, d: float) -> Array:
    """Derivative of eq. 3.6: f'(r) = (1/d)·(1 − r/d)·exp(1 − r/d)."""
    return (1.0 / d) * (1.0 - r / d) * np.exp(1.0 - r / d)


def _f_sq(r: float, d: float) -> float:
    """Another f: (r/d)²·e^{2(1 − r/d)} (smooth, f(0) = 0, max 1 at d)."""
    return (r / d) ** 2 * math.exp(2 * (1 - r / d))


def _f_sq_array(r: Array, d: float) -> Array:
    """:func:`_f_sq` on an array of distances."""
    return (r / d) ** 2 * np.exp(2.0 * (1.0 - r / d))


def _df_sq_array(r: Array, d: float) -> Array:
    """Derivative of :func:`_f_sq_array`."""
    return (2.0 * r / d**2) * (1.0 - r / d) * np.exp(2.0 * (1.0 - r / d))


# --------------------------------------------------------------------------------------------
# Eq. 3.1 / 3.4 / 3.6
# --------------------------------------------------------------------------------------------


def test_per_landmark_matches_naive_eq_3_1() -> None:
    rng = np.random.default_rng(20240601)
    for trial in range(3000):
        m = int(rng.integers(1, 9))
        d_opt = float(rng.uniform(0.5, 5.0))
        p, v, q, u = random_config(rng, m)
        if trial % 10 == 0:
            q[0] = p  # a landmark at the camera position: f(0) = 0
        got = per_landmark(p, v, q, u, d_opt)
        want = np.array([vis_one(p, v, q[j], u[j], partial(f_exp, d_opt=d_opt))
                         for j in range(m)])
        np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-15)
        cols = per_landmark_cols(p, v, Landmarks.of(q, u), d_opt)
        np.testing.assert_allclose(cols, want, rtol=1e-12, atol=1e-15)
        assert vision(p, v, q, u, d_opt) == pytest.approx(float(want.sum()), rel=1e-12, abs=1e-15)


def test_vision_is_sum_of_per_landmark_and_in_unit_interval() -> None:
    rng = np.random.default_rng(7)
    for _ in range(2000):
        m = int(rng.integers(1, 30))
        d_opt = float(rng.uniform(0.3, 6.0))
        p, v, q, u = random_config(rng, m, spread=8.0)
        per = per_landmark(p, v, q, u, d_opt)
        assert per.shape == (m,)
        # Eq. 3.6 has max 1 and both cosines are ≤ 1: every landmark contributes in [0, 1].
        assert np.all(per >= 0.0)
        assert np.all(per <= 1.0 + 1e-15)
        total = vision(p, v, q, u, d_opt)
        assert total == pytest.approx(float(per.sum()), rel=1e-13, abs=1e-15)
        assert 0.0 <= total <= m + 1e-12


def test_invisible_cases_are_zero() -> None:
    """Behind the camera, or on the back of the surface, or both (figure 3.1c): vis = 0."""
    p = np.zeros(3)
    q = np.array([[2.0, 0.0, 0.0]])
    # In front, surface facing the camera: visible.
    assert vision(p, np.array([1.0, 0.0, 0.0]), q, np.array([[-1.0, 0.0, 0.0]]), 2.0) > 0
    # Behind the camera.
    assert vision(p, np.array([-1.0, 0.0, 0.0]), q, np.array([[-1.0, 0.0, 0.0]]), 2.0) == 0.0
    # Surface facing away.
    assert vision(p, np.array([1.0, 0.0, 0.0]), q, np.array([[1.0, 0.0, 0.0]]), 2.0) == 0.0
    # Both negative: the product of the raw cosines is positive, the positive parts are not.
    assert vision(p, np.array([-1.0, 0.0, 0.0]), q, np.array([[1.0, 0.0, 0.0]]), 2.0) == 0.0
    # Grazing: exactly perpendicular view or surface.
    assert vision(p, np.array([0.0, 1.0, 0.0]), q, np.array([[-1.0, 0.0, 0.0]]), 2.0) == 0.0
    assert vision(p, np.array([1.0, 0.0, 0.0]), q, np.array([[0.0, 1.0, 0.0]]), 2.0) == 0.0


def test_maximum_one_at_d_opt_head_on() -> None:
    rng = np.random.default_rng(3)
    for _ in range(500):
        d_opt = float(rng.uniform(0.2, 10.0))
        q = rng.uniform(-5, 5, (1, 3))
        u = random_unit(rng, 1)
        p = q[0] + d_opt * u[0]
        v = -u[0]
        assert vision(p, v, q, u, d_opt) == pytest.approx(1.0, abs=1e-13)
        # Moving along the normal (nearer or farther) or tilting the view strictly lowers it.
        for s in (0.5, 0.9, 1.1, 2.0):
            assert vision(q[0] + s * d_opt * u[0], v, q, u, d_opt) < 1.0 - 1e-6
        tilt = rodrigues(random_unit(rng), 0.05) @ v
        assert vision(p, tilt, q, u, d_opt) < 1.0 - 1e-6


def test_generic_distance_with_eq_3_6_equals_exp_distance() -> None:
    rng = np.random.default_rng(11)
    for _ in range(1000):
        d_opt = float(rng.uniform(0.5, 5.0))
        generic = GenericDistance(
            f=partial(_f_exp_array, d=d_opt),
            df=partial(_df_exp_array, d=d_opt),
        )
        p, v, q, u = random_config(rng, int(rng.integers(1, 10)))
        np.testing.assert_allclose(
            per_landmark(p, v, q, u, generic), per_landmark(p, v, q, u, ExpDistance(d_opt)),
            rtol=1e-12, atol=1e-15,
        )
        gp_g, gv_g = gradients(p, v, q, u, generic)
        gp_e, gv_e = gradients(p, v, q, u, d_opt)
        scale = 1e-12 * (1.0 + np.abs(gp_e).max() + np.abs(gv_e).max())
        np.testing.assert_allclose(gp_g, gp_e, rtol=1e-10, atol=scale)
        np.testing.assert_allclose(gv_g, gv_e, rtol=1e-10, atol=scale)


def test_exp_distance_rejects_bad_d_opt() -> None:
    for bad in (0.0, -1.0, math.inf, math.nan):
        with pytest.raises(ValueError):
            ExpDistance(bad)


def test_coverage_score_is_sum_over_agents() -> None:
    rng = np.random.default_rng(5)
    for _ in range(300):
        n = int(rng.integers(1, 5))
        m = int(rng.integers(0, 25))
        d_opt = float(rng.uniform(0.5, 4.0))
        poses_p = rng.uniform(-3, 3, (n, 3))
        poses_v = random_unit(rng, n)
        q = rng.uniform(-4, 4, (m, 3))
        u = random_unit(rng, m) if m else np.zeros((0, 3))
        owner = rng.integers(0, n, m).astype(np.intp)
        want = 0.0
        for i in range(n):
            for j in range(m):
                if owner[j] == i:
                    want += vis_one(poses_p[i], poses_v[i], q[j], u[j],
                                    partial(f_exp, d_opt=d_opt))
        got = coverage_score(poses_p, poses_v, q, u, owner, d_opt)
        assert got == pytest.approx(want, rel=1e-12, abs=1e-15)


# --------------------------------------------------------------------------------------------
# Gradients (eq. 3.15, 3.16) against central finite differences
# --------------------------------------------------------------------------------------------


def kink_distances(p: Array, v: Array, q: Array, u: Array) -> tuple[Array, Array]:
    """Distance (in p, metres; in v, radians) from each landmark's visibility kink.

    ⟨q − p, v⟩ changes at unit rate per metre of p and at most ‖q − p‖ per radian of v;
    ⟨p − q, u⟩ changes at unit rate per metre of p and not at all with v.
    """
    d = q - p
    dv = d @ v
    du = np.einsum("ij,ij->i", d, u)
    r = np.linalg.norm(d, axis=1)
    in_p = np.minimum(np.abs(dv), np.abs(du))
    in_v = np.abs(dv) / r
    return in_p, in_v


def fd_grad_p(p: Array, v: Array, q: Array, u: Array, f: Distance, h: float) -> Array:
    g = np.zeros(3)
    for k in range(3):
        e = np.zeros(3)
        e[k] = h
        g[k] = (vision(p + e, v, q, u, f) - vision(p - e, v, q, u, f)) / (2 * h)
    return g


def fd_grad_v(p: Array, v: Array, q: Array, u: Array, f: Distance, h: float) -> Array:
    """(∇_v)_k = d/dε vis(p, R(ε e_k) v) at ε = 0, central differences."""
    g = np.zeros(3)
    for k in range(3):
        axis = np.eye(3)[k]
        plus = rodrigues(axis, h) @ v
        minus = rodrigues(axis, -h) @ v
        g[k] = (vision(p, plus, q, u, f) - vision(p, minus, q, u, f)) / (2 * h)
    return g


def check_gradients(p: Array, v: Array, q: Array, u: Array, f: Distance, *,
                    min_kink: float = 1e-6) -> None:
    """Compare gradients() with central FD; landmarks within ``min_kink`` of a kink are dropped.

    The FD step is a quarter of the smallest kink distance (capped at 1e-5), so every stencil
    point sees the same visible set and the function is smooth (C^∞) along the stencil.
    Error budget: truncation h²·|f'''|/6 ≪ 1e-9 for landmarks ≥ 0.3 m away, round-off
    ≈ 2ε·Σ|vis_j|/h ≤ 4e-16·m / 2.5e-7 < 2e-8.
    """
    kp, kv = kink_distances(p, v, q, u)
    keep = (kp >= min_kink) & (kv >= min_kink)
    q, u = q[keep], u[keep]
    if len(q) == 0:
        return
    kp, kv = kink_distances(p, v, q, u)
    hp = min(1e-5, 0.25 * float(kp.min()))
    hv = min(1e-5, 0.25 * float(kv.min()))
    gp, gv = gradients(p, v, q, u, f)
    fp = fd_grad_p(p, v, q, u, f, hp)
    fv = fd_grad_v(p, v, q, u, f, hv)
    tol_p = 2e-8 + 1e-6 * float(np.linalg.norm(fp)) + 2e-15 * len(q) / hp
    tol_v = 2e-8 + 1e-6 * float(np.linalg.norm(fv)) + 2e-15 * len(q) / hv
    assert np.linalg.norm(gp - fp) <= tol_p, (gp, fp)
    assert np.linalg.norm(gv - fv) <= tol_v, (gv, fv)
    # ∇_v is an angular-rate gradient: orthogonal to v (section 4.2).
    assert abs(float(gv @ v)) <= 1e-12 * (1.0 + float(np.linalg.norm(gv)))


unit_triple = st.tuples(*(st.floats(-1.0, 1.0, allow_nan=False) for _ in range(3)))


def as_unit(t: tuple[float, ...], fallback: tuple[float, float, float] = (0.0, 0.0, 1.0)
            ) -> Array:
    x = np.array(t, dtype=np.float64)
    n = float(np.linalg.norm(x))
    return x / n if n > 0.1 else np.array(fallback, dtype=np.float64)


@st.composite
def configurations(draw: st.DrawFn, max_m: int = 8
                   ) -> tuple[Array, Array, Array, Array, float]:
    """Camera and m landmarks 0.3-8 m away; directions from raw float triples."""
    m = draw(st.integers(1, max_m))
    p = np.array(draw(st.tuples(*(st.floats(-3.0, 3.0) for _ in range(3)))))
    v = as_unit(draw(unit_triple))
    q = np.zeros((m, 3))
    u = np.zeros((m, 3))
    for j in range(m):
        dirn = as_unit(draw(unit_triple), fallback=(1.0, 0.0, 0.0))
        r = draw(st.floats(0.3, 8.0))
        q[j] = p + r * dirn
        # Bias the normal towards the camera half the time so landmarks are visible.
        uj = as_unit(draw(unit_triple), fallback=(-1.0, 0.0, 0.0))
        if draw(st.booleans()) and float(uj @ dirn) > 0:
            uj = -uj
        u[j] = uj
    d_opt = draw(st.floats(0.5, 5.0))
    return p, v, q, u, d_opt


@settings(SETTINGS, max_examples=700)
@given(configurations())
def test_gradients_match_finite_differences(cfg: tuple[Array, Array, Array, Array, float]
                                            ) -> None:
    p, v, q, u, d_opt = cfg
    check_gradients(p, v, q, u, d_opt)


@settings(SETTINGS, max_examples=1500)
@given(st.integers(0, 2**32 - 1))
def test_gradients_match_finite_differences_random_seeds(seed: int) -> None:
    """Same property on numpy-generated configurations (no 'simple' hypothesis floats)."""
    rng = np.random.default_rng(seed)
    p, v, q, u = random_config(rng, int(rng.integers(1, 12)))
    near = np.linalg.norm(q - p, axis=1) < 0.3
    if near.any():
        q[near] = p + 0.3 * random_unit(rng, int(near.sum()))
    check_gradients(p, v, q, u, float(rng.uniform(0.5, 5.0)))


def near_boundary_config(rng: np.random.Generator, which: str, eps: float
                         ) -> tuple[Array, Array, Array, Array]:
    """One landmark at (signed) distance eps·r (view) or eps (surface) from its visibility kink,
    plus a few ordinary landmarks."""
    p, v, q, u = random_config(rng, int(rng.integers(0, 4)))
    r = float(rng.uniform(1.0, 6.0))
    t = np.cross(v, random_unit(rng))
    t /= np.linalg.norm(t)
    if which == "view":
        # ⟨q − p, v⟩ = eps·r: the landmark is at the edge of the camera's half-space.
        d = r * (eps * v + math.sqrt(1 - eps * eps) * t)
        un = -d / r + 0.3 * random_unit(rng)  # surface roughly facing the camera
        un /= np.linalg.norm(un)
        if un @ d > 0:
            un = -un
    else:
        # ⟨p − q, u⟩ = eps: the camera is almost in the landmark's tangent plane.
        d = r * (0.6 * v + 0.8 * t)  # comfortably in front of the camera
        n_perp = np.cross(d, random_unit(rng))
        n_perp /= np.linalg.norm(n_perp)
        # u = a·(−d/r) + b·n_perp with ⟨−d, u⟩ = a·r = eps.
        a = eps / r
        un = a * (-d / r) + math.sqrt(1 - a * a) * n_perp
    q = np.vstack([q, p + d])
    u = np.vstack([u, un])
    return p, v, q, u


@pytest.mark.parametrize("which", ["view", "surface"])
def test_gradients_near_visibility_boundary(which: str) -> None:
    """At the kink the vision is only Lipschitz (x⁺ has a corner), so the FD step must be smaller
    than the distance to the kink; eps ∈ ±[1e-5, 1e-2] covers just inside and just outside."""
    rng = np.random.default_rng(99 if which == "view" else 98)
    for _ in range(400):
        eps = float(10 ** rng.uniform(-5, -2)) * (1 if rng.random() < 0.5 else -1)
        p, v, q, u = near_boundary_config(rng, which, eps)
        d_opt = float(rng.uniform(0.5, 5.0))
        kp, kv = kink_distances(p, v, q, u)
        # The constructed landmark is kept by check_gradients (its kink distance ≥ 1e-6) and
        # sets the FD step.
        assert kp[-1] >= 1e-6 and kv[-1] >= 1e-6
        check_gradients(p, v, q, u, d_opt)


def test_gradient_v_matches_rotation_rate() -> None:
    """⟨∇_v, ω⟩ = d/dt vis along v̇ = ω × v, for random ω (not only coordinate axes)."""
    rng = np.random.default_rng(17)
    for _ in range(500):
        p, v, q, u = random_config(rng, int(rng.integers(1, 9)))
        d_opt = float(rng.uniform(0.5, 5.0))
        _, kv = kink_distances(p, v, q, u)
        if kv.min() < 1e-5:
            continue
        h = min(1e-5, 0.25 * float(kv.min()))
        omega = rng.normal(size=3)
        angle = float(np.linalg.norm(omega))
        plus = rodrigues(omega, h * angle) @ v
        minus = rodrigues(omega, -h * angle) @ v
        fd = (vision(p, plus, q, u, d_opt) - vision(p, minus, q, u, d_opt)) / (2 * h)
        _, gv = gradients(p, v, q, u, d_opt)
        assert float(gv @ omega) == pytest.approx(fd, abs=1e-7 + 2e-15 * len(q) * angle / h,
                                                  rel=1e-6)


def test_gradients_zero_when_nothing_visible() -> None:
    p = np.zeros(3)
    q = np.array([[1.0, 0.0, 0.0], [0.0, 2.0, 0.0]])
    u = np.array([[1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
    gp, gv = gradients(p, np.array([0.0, 0.0, 1.0]), q, u, 2.0)  # both at 90°: not visible
    assert np.all(gp == 0.0) and np.all(gv == 0.0)


def test_generic_distance_other_f_against_fd() -> None:
    """GenericDistance with f(r) = (r/d)²·e^{2(1 − r/d)} (smooth, f(0) = 0, max 1 at d)."""
    rng = np.random.default_rng(23)
    for _ in range(600):
        d = float(rng.uniform(0.5, 5.0))
        term = GenericDistance(
            f=partial(_f_sq_array, d=d),
            df=partial(_df_sq_array, d=d),
        )
        p, v, q, u = random_config(rng, int(rng.integers(1, 9)))
        near = np.linalg.norm(q - p, axis=1) < 0.3
        if near.any():
            continue
        # Values against the naive eq. 3.1 with this f.
        want = vis_naive(p, v, q, u, partial(_f_sq, d=d))
        assert vision(p, v, q, u, term) == pytest.approx(want, rel=1e-12, abs=1e-15)
        check_gradients(p, v, q, u, term)
