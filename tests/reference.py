"""Independent reference implementations used only by the core tests.

Everything here is written straight from the thesis (chapters 2-4) with plain loops or generic
scipy optimisers, deliberately *not* sharing code or algebraic shortcuts with ``agent/``:

* eq. 3.1/3.4/3.6 vision, one landmark at a time, with unit vectors and positive parts;
* Rodrigues rotations (for directional derivatives of the vision in the orientation);
* Fibonacci sampling of the unit sphere (for Algorithm 1);
* problems 4.7/4.11 solved by SLSQP from many starts (3-D) or by a dense angle grid plus
  bisection (2-D);
* the vision map v(p) = max_v vis(p, v) of section 5.1 maximised with Nelder-Mead.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import minimize

Array = NDArray[np.float64]
Vec3 = Sequence[float] | Array  #: a 3-vector, python floats or a numpy array

# --------------------------------------------------------------------------------------------
# Vision (eq. 3.1, 3.4, 3.6)
# --------------------------------------------------------------------------------------------


def f_exp(r: float, d_opt: float) -> float:
    """Eq. 3.6: f(r) = (r/d_opt)·exp(1 − r/d_opt)."""
    return (r / d_opt) * math.exp(1.0 - r / d_opt)


def vis_one(
    p: Vec3, v: Vec3, q: Vec3, u: Vec3, f: Callable[[float], float],
) -> float:
    """Eq. 3.1 for one landmark, with python floats: f(‖q−p‖)·⟨r̂, v⟩⁺·⟨−r̂, u⟩⁺."""
    dx = [float(q[i]) - float(p[i]) for i in range(3)]
    r = math.sqrt(dx[0] * dx[0] + dx[1] * dx[1] + dx[2] * dx[2])
    if r == 0.0:
        return 0.0  # f(0) = 0 (property 4)
    rhat = [c / r for c in dx]
    cos_a = sum(rhat[i] * float(v[i]) for i in range(3))
    cos_b = sum(-rhat[i] * float(u[i]) for i in range(3))
    return f(r) * max(cos_a, 0.0) * max(cos_b, 0.0)


def vis_naive(
    p: Vec3, v: Vec3, q: Array, u: Array, f: Callable[[float], float],
) -> float:
    """Eq. 3.4: sum of eq. 3.1 over the landmarks (plain loop)."""
    return sum(vis_one(p, v, q[j], u[j], f) for j in range(len(q)))


def vis_vec(p: Array, v: Array, q: Array, u: Array, d_opt: float) -> Array:
    """Eq. 3.1 with eq. 3.6 written from the cosines, vectorised over a batch of cameras.

    ``p`` (n, 3), ``v`` (n, 3): returns (n,) visions over (q, u). Used where thousands of
    evaluations are needed (vision maps, sphere sampling); checked against :func:`vis_naive`.
    """
    p = np.atleast_2d(p)
    v = np.atleast_2d(v)
    d = q[None, :, :] - p[:, None, :]  # (n, m, 3)
    r = np.linalg.norm(d, axis=2)
    safe = np.where(r > 0.0, r, 1.0)
    rhat = d / safe[:, :, None]
    cos_a = np.einsum("nmk,nk->nm", rhat, v)
    cos_b = -np.einsum("nmk,mk->nm", rhat, u)
    f = (r / d_opt) * np.exp(1.0 - r / d_opt)
    val = f * np.maximum(cos_a, 0.0) * np.maximum(cos_b, 0.0)
    return np.asarray(np.where(r > 0.0, val, 0.0).sum(axis=1), dtype=np.float64)


# --------------------------------------------------------------------------------------------
# Geometry helpers
# --------------------------------------------------------------------------------------------


def rodrigues(axis: Array, angle: float) -> Array:
    """Rotation matrix by ``angle`` [rad] about the unit ``axis`` (Rodrigues' formula)."""
    k = np.asarray(axis, dtype=np.float64)
    k = k / np.linalg.norm(k)
    kx = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]], dtype=np.float64)
    return np.eye(3) + math.sin(angle) * kx + (1.0 - math.cos(angle)) * (kx @ kx)


def fibonacci_sphere(n: int) -> Array:
    """n nearly uniform unit vectors (golden-angle spiral), shape (n, 3)."""
    i = np.arange(n, dtype=np.float64) + 0.5
    z = 1.0 - 2.0 * i / n
    rho = np.sqrt(np.maximum(1.0 - z * z, 0.0))
    phi = math.pi * (3.0 - math.sqrt(5.0)) * i
    return np.stack([rho * np.cos(phi), rho * np.sin(phi), z], axis=1)


def random_unit(rng: np.random.Generator, n: int | None = None, planar: bool = False) -> Array:
    """Uniform random unit vector(s) in R³ (or in the xy-plane when ``planar``)."""
    shape = (1 if n is None else n, 3)
    while True:
        x = rng.normal(size=shape)
        if planar:
            x[:, 2] = 0.0
        nrm = np.linalg.norm(x, axis=1)
        if np.all(nrm > 1e-6):
            break
    unit = np.asarray(x / nrm[:, None], dtype=np.float64)
    return unit[0, :] if n is None else unit


# --------------------------------------------------------------------------------------------
# Problems 4.7 / 4.11 (safe direction)
# --------------------------------------------------------------------------------------------

#: Fibonacci directions screened before SLSQP (start points and a certified lower bound).
_SCREEN = fibonacci_sphere(4000)


def slack(x: Array, p_opt: Array, w: Array, lam: Array) -> Array:
    """Smallest constraint slack of problem 4.11 for each row of x (≥ 0 means feasible)."""
    x = np.atleast_2d(x)
    s = x @ p_opt
    if len(w):
        s = np.minimum(s, (x @ w.T - lam[None, :]).min(axis=1))
    return s


def safe_direction_reference_3d(
    p_opt: Array, w: Array, lam: Array, rng: np.random.Generator,
    extra_starts: Sequence[Array] = (), n_random: int = 1, n_best: int = 1,
    feas_tol: float = 1e-7,
) -> tuple[Array | None, float]:
    """Best feasible unit x for problem 4.11 found by SLSQP from many starts.

    Starts: the ``n_best`` best feasible and the ``n_best`` least infeasible of 4,000 Fibonacci
    directions (spacing ≈ 0.03 rad), ``n_random`` random unit vectors, and ``extra_starts``.
    Each SLSQP result is re-normalised and accepted when every constraint holds within
    ``feas_tol``; the feasible screened directions count too. Returns (None, −inf) if no
    feasible point was found.
    """
    grid_slack = slack(_SCREEN, p_opt, w, lam)
    obj = _SCREEN @ p_opt
    feas = grid_slack >= 0.0
    starts: list[Array] = []
    if feas.any():
        order = np.argsort(-np.where(feas, obj, -np.inf))[:n_best]
        starts.extend(_SCREEN[order])
    starts.extend(_SCREEN[np.argsort(-grid_slack)[:n_best]])
    starts.extend(random_unit(rng, n_random))
    starts.extend(np.asarray(s, dtype=np.float64) for s in extra_starts)

    cons = [
        {"type": "eq", "fun": lambda x: np.array([x @ x - 1.0]),
         "jac": lambda x: 2.0 * x[None, :]},
        {"type": "ineq", "fun": lambda x: np.concatenate([[x @ p_opt], w @ x - lam]),
         "jac": lambda x: np.vstack([p_opt[None, :], w])},
    ]
    best_x: Array | None = None
    best = -math.inf
    for x0 in starts:
        if not np.all(np.isfinite(x0)) or np.linalg.norm(x0) == 0.0:
            continue
        res = minimize(
            lambda x: -(x @ p_opt), x0 / np.linalg.norm(x0), jac=lambda x: -p_opt,
            method="SLSQP", constraints=cons, options={"maxiter": 200, "ftol": 1e-14},
        )
        x = res.x / np.linalg.norm(res.x)
        if abs(np.linalg.norm(res.x) - 1.0) > 1e-6:
            continue
        if slack(x, p_opt, w, lam)[0] >= -feas_tol and x @ p_opt > best:
            best, best_x = float(x @ p_opt), x
    # The screened grid itself is an exact-feasibility lower bound.
    if feas.any() and obj[feas].max() > best:
        i = int(np.flatnonzero(feas)[np.argmax(obj[feas])])
        best, best_x = float(obj[i]), _SCREEN[i].copy()
    return best_x, best


def safe_direction_reference_2d(
    phi_p: float, w_ang: Array, lam: Array, n_grid: int = 20_000,
) -> tuple[float | None, float]:
    """Problem 4.11 in the plane, solved over the angle θ of x = (cos θ, sin θ).

    Constraints cos(θ − φ_p) ≥ 0 and cos(θ − α_i) ≥ λ_i. A dense grid of ``n_grid`` angles finds
    the feasible grid point closest (in angle) to φ_p, then bisection towards φ_p moves it to the
    boundary of its feasible arc (or to φ_p itself). Returns (θ, cos(θ − φ_p)) or (None, −inf).
    """

    def feasible(t: Array) -> NDArray[np.bool_]:
        ok = np.cos(t - phi_p) >= 0.0
        for a, lm in zip(w_ang, lam, strict=True):
            ok &= np.cos(t - a) >= lm
        return ok

    # Grid in the offset δ = θ − φ_p ∈ [−π, π).
    delta = -math.pi + 2.0 * math.pi * np.arange(n_grid) / n_grid
    ok = feasible(phi_p + delta)
    if not ok.any():
        return None, -math.inf
    if feasible(np.array([phi_p]))[0]:
        return phi_p, 1.0
    best_t, best_val = None, -math.inf
    # The best grid point on each side of φ_p, refined by bisection towards φ_p.
    for side in (1.0, -1.0):
        cand = ok & (np.sign(delta) == side)
        if not cand.any():
            continue
        d0 = delta[cand][np.argmin(np.abs(delta[cand]))]
        lo, hi = abs(d0), 0.0  # lo feasible, hi = φ_p infeasible
        for _ in range(200):
            mid = 0.5 * (lo + hi)
            if feasible(np.array([phi_p + side * mid]))[0]:
                lo = mid
            else:
                hi = mid
            if abs(lo - hi) < 1e-15:
                break
        t = phi_p + side * lo
        if math.cos(lo) > best_val:
            best_t, best_val = t, math.cos(lo)
    return best_t, best_val


# --------------------------------------------------------------------------------------------
# Section 5.1 vision map
# --------------------------------------------------------------------------------------------


def vision_map_max(
    q: Array, u: Array, d_opt: float, starts: Sequence[Sequence[float]],
) -> tuple[Array, float, float]:
    """Maximum over planar poses (x, y, ψ) of eq. 3.4, by Nelder-Mead from several starts.

    Returns (p*, ψ*, vis*). The vision is evaluated with :func:`vis_naive` (eq. 3.1 loops).
    """

    def neg(z: Array) -> float:
        p = (z[0], z[1], 0.0)
        v = (math.cos(z[2]), math.sin(z[2]), 0.0)
        return -vis_naive(p, v, q, u, lambda r: f_exp(r, d_opt))

    best = None
    for s in starts:
        res = minimize(
            neg, np.asarray(s, dtype=np.float64), method="Nelder-Mead",
            options={"xatol": 1e-10, "fatol": 1e-14, "maxiter": 20_000, "maxfev": 40_000},
        )
        # Restart once from the result (Nelder-Mead can stall on a shrunken simplex).
        res = minimize(
            neg, res.x, method="Nelder-Mead",
            options={"xatol": 1e-12, "fatol": 1e-15, "maxiter": 20_000, "maxfev": 40_000},
        )
        if best is None or res.fun < best.fun:
            best = res
    assert best is not None
    return np.array([best.x[0], best.x[1], 0.0]), float(best.x[2]), float(-best.fun)
