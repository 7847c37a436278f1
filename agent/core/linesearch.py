"""Magnitude control by backtracking line search (thesis section 4.4, Algorithm 6).

Algorithm 6 writes the sufficient-increase term with p_opt; eq. 4.12 defines it with the
gradient. We use the gradient form, the standard Armijo condition:

    vis(x + α·Δx) > vis(x) + α·β·⟨∇vis(x), Δx⟩      (strict, as section 4.6 requires)

Candidate steps α_k = α_0·τ^k (α_k ≥ α_min) are evaluated as (K, m) array operations, never
one vision sum after another: first the :data:`HEAD` largest candidates in one batch (the
common case, where a large step is accepted), then all remaining ones in a second batch.
The largest candidate satisfying the condition wins, exactly as in Algorithm 6.

The vision at a candidate is evaluated with positive parts over the landmarks visible now
(Q^V): every other landmark contributes ≥ 0, so this is a lower bound of the true vision,
and an accepted step increases the true vision (Proposition 3) even if Q^V changes.

Certified decisions (linear search, eq. 3.6 only). Evaluating one linear candidate costs one
``exp`` and one ``sqrt`` per landmark. Before that, :func:`linear_vision_bounds` brackets the
vision at every candidate by a Taylor polynomial of eq. 3.8 along the line with a rigorous
third-order remainder, O(m) once for all candidates and without any ``exp``. A candidate whose
upper bound is below the Armijo threshold is rejected, and one whose lower bound is above it
accepted, without evaluating it, both with a rounding margin (:data:`ROUNDING`); only the
undecided candidates before the first certainly accepted one (and that one, whose per-landmark
terms are returned) are evaluated, exactly as before. So the accepted step and everything
returned are those of the plain search (tests/test_core_planner.py compares both).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from agent.core.vision import DistanceTerm, ExpDistance, VisibleTerms, cross

Array = NDArray[np.float64]

#: Candidates evaluated in the first batch; the rest only if none of these is accepted.
HEAD = 4
#: Relative margin by which a bound must clear the Armijo threshold to decide a candidate. It
#: covers the rounding of the bounds and of the plain evaluation (each ≲ 1e-13 relative:
#: ≲ 10³ ulp per landmark term, pairwise sums) at least 100 times over.
ROUNDING = 1e-11
#: Landmarks per block when summing the bounds: small blocks stay in cache and reuse memory.
BLOCK = 8192


def candidate_steps(alpha0: float, alpha_min: float, tau: float) -> Array:
    """Algorithm 6: the step sizes α_0·τ^k, k = 0, 1, … while α ≥ α_min."""
    if alpha0 <= 0.0 or alpha0 < alpha_min:
        return np.zeros(0)
    k = int(np.floor(np.log(alpha_min / alpha0) / np.log(tau))) + 1 if alpha_min > 0 else 64
    steps = alpha0 * tau ** np.arange(k, dtype=np.float64)
    return steps[steps >= alpha_min * (1.0 - 1e-12)]


def _staged_search(
    evaluate: Callable[[Array], tuple[Array, ...]], steps: Array, base: float, slope: float,
    order: NDArray[np.intp] | None = None,
) -> tuple[int, tuple[Array, ...]]:
    """Largest accepted candidate: its index (−1 if none) and its row of every evaluated array.

    ``evaluate(batch)`` returns arrays whose first axis runs over the batch; the first one
    holds the vision at each candidate. ``order`` (increasing indices into ``steps``) lists the
    candidates to evaluate, all by default; the others are known to be rejected.
    """
    order = np.arange(steps.size) if order is None else order
    start = 0
    for stop in (min(HEAD, order.size), order.size):
        if stop <= start:
            continue
        batch = steps[order[start:stop]]
        out = evaluate(batch)
        ok = out[0] > base + batch * slope
        if ok.any():
            k = int(np.argmax(ok))
            return int(order[start + k]), tuple(x[k] for x in out)
        start = stop
    return -1, ()


@dataclass(frozen=True)
class LinearStep:
    """Accepted linear step: distance α [m], the vision lower bound reached, and for every
    visible landmark its weight f̄(r')·⟨p'−q, u⟩⁺ and ⟨q − p', v⟩ at the new position p'."""

    alpha: float
    value: float
    weight: Array
    dv: Array


def linear_search(
    t: VisibleTerms, v: Array, direction: Array, grad_p: Array, steps: Array,
    term: DistanceTerm, beta: float, *, certify: bool = True,
) -> LinearStep:
    """Algorithm 6 (gradient form) for the linear velocity along the unit ``direction``.

    ``steps`` (K,) may be truncated at an obstacle boundary. Returns α = 0 (and the current
    vision) when no candidate satisfies the strict Armijo condition. ``certify=False`` skips
    the certified decisions and evaluates every candidate (the plain search, for comparison).
    """
    still = LinearStep(0.0, t.value, t.fb * t.pu, t.dv)
    if steps.size == 0 or t.r.size == 0:
        return still
    dd = direction @ t.dT  # ⟨q − p, dir⟩
    udir = direction @ t.uT
    vdir = float(v @ direction)
    r2 = t.r * t.r
    base, slope = still.value, beta * float(grad_p @ direction)
    order = None
    if certify and isinstance(term, ExpDistance) and _bounds_apply(direction, steps):
        bounds = _bounds_along(t, dd, udir, vdir, steps, term)
        order = _undecided(bounds, base + steps * slope)

    def evaluate(a: Array) -> tuple[Array, Array, Array]:
        return _vision_along_line(a, r2, dd, t.pu, udir, t.dv, vdir, term)

    k, row = _staged_search(evaluate, steps, base, slope, order)
    if k < 0:
        return still
    return LinearStep(float(steps[k]), float(row[0]), row[1], row[2])


def _vision_along_line(
    a: Array, r2: Array, dd: Array, pu: Array, udir: Array, dv: Array, vdir: float,
    term: DistanceTerm,
) -> tuple[Array, Array, Array]:
    """Eq. 3.8 over Q^V at p' = p + α·dir for each α [m] of ``a`` (K,): the vision (K,), and
    (K, m) f̄(r')·⟨p' − q, u⟩⁺ and ⟨q − p', v⟩, from r² = ‖q − p‖², ⟨q − p, dir⟩, ⟨p − q, u⟩,
    ⟨dir, u⟩, ⟨q − p, v⟩ (m,) and ⟨v, dir⟩, using q − p' = (q − p) − α·dir."""
    ac = a[:, None]
    x = ac * dd
    x *= -2.0
    x += r2
    x += ac * ac
    np.maximum(x, 1e-300, out=x)
    np.sqrt(x, out=x)
    pu_next = ac * udir
    pu_next += pu
    np.maximum(pu_next, 0.0, out=pu_next)
    weight = term.fbar(x)
    weight *= pu_next
    dv_next = dv - ac * vdir
    return (weight * np.maximum(dv_next, 0.0)).sum(axis=1), weight, dv_next


@dataclass(frozen=True)
class VisionBounds:
    """lower ≤ vis ≤ upper at each candidate step (K,) (Q^V vision of eq. 3.8, exact
    arithmetic), and the rounding margin (K,) by which a decision must clear the threshold."""

    lower: Array
    upper: Array
    margin: Array


def _bounds_apply(direction: Array, steps: Array) -> bool:
    """The bounds of :func:`_bounds_along` hold: a unit direction and steps α ∈ [0, α_max]."""
    return bool(abs(float(direction @ direction) - 1.0) <= 1e-9 and steps.size
                and steps.min() >= 0.0 and steps.max() > 0.0)


def linear_vision_bounds(
    t: VisibleTerms, v: Array, direction: Array, steps: Array, term: DistanceTerm
) -> VisionBounds | None:
    """Eq. 3.8 over Q^V at p + α_k·dir: certified bounds for every step α_k [m] (world ENU).

    Only for eq. 3.6 (:class:`ExpDistance`), a unit ``direction`` and steps ≥ 0; else None.
    """
    if not (isinstance(term, ExpDistance) and t.r.size and _bounds_apply(direction, steps)):
        return None
    return _bounds_along(t, direction @ t.dT, direction @ t.uT, float(v @ direction), steps, term)


def _bounds_along(
    t: VisibleTerms, dd: Array, udir: Array, vdir: float, steps: Array, term: ExpDistance
) -> VisionBounds:
    """Eq. 3.6-3.8 along p + α·dir: per-landmark Taylor polynomial at α = 0 ± a third-order
    remainder, summed; the landmarks crossing an edge of Q^V within α_max are evaluated."""
    a_max, inv_d = float(steps.max()), 1.0 / term.d_opt
    sums = np.zeros(6)
    edge_parts = []
    for lo in range(0, t.r.size, BLOCK):
        b = slice(lo, lo + BLOCK)
        pu, dv, r, fb, ddb, ub = t.pu[b], t.dv[b], t.r[b], t.fb[b], dd[b], udir[b]
        # Smooth on [0, α_max]: ⟨p' − q, u⟩ = pu + α·udir and ⟨q − p', v⟩ = dv − α·vdir stay
        # > 0 (no kink of the positive parts) and ‖q − p'‖ ≥ r − α_max ≥ r/2.
        smooth = (pu + a_max * ub > 0.0) & (dv - a_max * vdir > 0.0) & (r > 2.0 * a_max)
        if not smooth.all():
            edge_parts.append(lo + np.flatnonzero(~smooth))
            keep = np.flatnonzero(smooth)
            pu, dv, r, fb, ddb, ub = pu[keep], dv[keep], r[keep], fb[keep], ddb[keep], ub[keep]
        sums += _taylor_sums(pu, dv, r, fb, ddb, ub, vdir, a_max, inv_d)
    edge = np.zeros(steps.size)
    if edge_parts:
        e = np.concatenate(edge_parts)
        edge = _vision_along_line(steps, t.r[e] * t.r[e], dd[e], t.pu[e], udir[e], t.dv[e],
                                  vdir, term)[0]
    c0, c1, c2, c1_abs, c2_abs, r3 = sums.tolist()
    poly = c0 + steps * (c1 + steps * c2) + edge
    rem = steps * steps * steps * r3
    margin = ROUNDING * (c0 + steps * (c1_abs + steps * c2_abs) + rem + edge)
    return VisionBounds(lower=poly - rem, upper=poly + rem, margin=margin)


def _taylor_sums(
    pu: Array, dv: Array, r: Array, fb: Array, dd: Array, udir: Array, vdir: float,
    a_max: float, inv_d: float,
) -> Array:
    """Eq. 3.6-3.8 for smooth landmarks along p + α·dir, α ∈ [0, α_max] [m]: Σc₀, Σc₁, Σc₂,
    Σ|c₁|, Σ|c₂| and R with |w(α) − c₀ − c₁α − c₂α²| ≤ R·α³ summed (6,).

    Per landmark w(α) = f̄(r(α))·A(α)·B(α), r(α) = ‖q − p − α·dir‖, A = pu + α·udir,
    B = dv − α·vdir (inputs as in :func:`_vision_along_line`; fb = f̄(r)).
    """
    # With c = ⟨q − p, dir⟩/r: r'(0) = −c, r''(0) = (1 − c²)/r; eq. 3.7 for eq. 3.6 gives
    # f̄' = −f̄·s, f̄'' = f̄·(s² + 1/r²), f̄''' = −f̄·(s³ + 3s/r² + 2/r³), s = 1/d_opt + 1/r.
    inv_r = 1.0 / r
    s, c = inv_d + inv_r, dd * inv_r
    f1 = fb * s * c  # d/dα f̄(r(α)) at 0
    f2 = fb * ((s * s + inv_r * inv_r) * (c * c) - s * (1.0 - c * c) * inv_r)  # d²/dα² at 0
    ab, dab = pu * dv, udir * dv - vdir * pu  # A·B and (A·B)' at 0; (A·B)'' = −2·udir·vdir
    c1 = f1 * ab + fb * dab
    c2 = 0.5 * f2 * ab + f1 * dab - fb * (udir * vdir)
    # Remainder |w'''|/6 on [0, α_max]: r(α) ≥ r_m = r − α_max, |r'| ≤ 1, 0 ≤ r'' ≤ 1/r_m,
    # |r'''| = 3|r'|·r''/r ≤ 3/r_m², and every |f̄^(k)| decreases with r (taken at r_m), so
    # |d^k/dα^k f̄(r(α))| ≤ f̄(r_m)·P_k with P₁ = s_m, P₂ = s_m² + i² + s_m·i,
    # P₃ = s_m³ + 3s_m·i² + 2i³ + 3(s_m² + i²)·i + 3s_m·i² (i = 1/r_m, s_m = 1/d_opt + i);
    # A, B > 0 on the interval and (A·B)'' = −2·udir·vdir, so by Leibniz |w'''| ≤
    # F₃·A_hi·B_hi + 3F₂·(|udir|·B_hi + A_hi·|vdir|) + 6F₁·|udir·vdir|, F_k = f̄(r_m)·P_k.
    inv_m = 1.0 / (r - a_max)
    fbm = fb * (math.exp(a_max * inv_d) * r * inv_m)  # f̄(r_m) for eq. 3.6
    sm = inv_d + inv_m
    sm2, im2 = sm * sm, inv_m * inv_m
    p1 = sm
    p2 = sm2 + im2 + sm * inv_m
    p3 = sm * (sm2 + 6.0 * im2 + 3.0 * sm * inv_m) + 5.0 * im2 * inv_m
    a_hi = pu + a_max * np.maximum(udir, 0.0)  # max of A on [0, α_max]
    b_hi = dv + a_max * max(-vdir, 0.0)  # max of B
    au, bv = np.abs(udir), abs(vdir)
    w3 = fbm * (p3 * a_hi * b_hi + 3.0 * p2 * (au * b_hi + bv * a_hi) + (6.0 * bv) * p1 * au)
    return np.array([np.sum(fb * ab), np.sum(c1), np.sum(c2), np.sum(np.abs(c1)),
                     np.sum(np.abs(c2)), np.sum(w3) / 6.0])


def _undecided(bounds: VisionBounds, threshold: Array) -> NDArray[np.intp]:
    """Algorithm 6 candidates still to evaluate: all not certainly rejected (upper bound below
    the Armijo threshold), up to and including the first certainly accepted one."""
    slack = bounds.margin + ROUNDING * np.abs(threshold)
    order = np.flatnonzero(bounds.upper >= threshold - slack)
    accepted = np.flatnonzero(bounds.lower > threshold + slack)
    return order[order <= accepted[0]] if accepted.size else order


@dataclass(frozen=True)
class AngularStep:
    """Accepted angular step: angle α [rad], vision lower bound, and the new direction v⁺."""

    alpha: float
    value: float
    v_next: Array


def angular_search(
    t: VisibleTerms, v: Array, lin: LinearStep, shift: Array, omega_dir: Array,
    grad_v: Array, steps: Array, beta: float,
) -> AngularStep:
    """Algorithm 6 (gradient form) for the angular velocity about the unit axis ``omega_dir``.

    The camera is evaluated where the linear step ``lin`` took it (p + ``shift``) and the
    candidates are the integrator's own result (eq. 5.1 with re-normalisation),
    v_k = (v + α_k·(ω_dir × v)) / ‖·‖, so the accepted vision is the one actually reached.
    """
    if steps.size == 0 or t.r.size == 0:
        return AngularStep(0.0, lin.value, v)
    c = cross(omega_dir, v)
    dc = c @ t.dT - float(c @ shift)  # ⟨q − p', ω × v⟩
    vc, cc = float(v @ c), float(c @ c)
    # Σ_j w_j·max(dv_j + α·dc_j, 0) over α ∈ [0, α_0]: a landmark whose term is ≥ 0 at both
    # ends is linear in α throughout, one ≤ 0 at both ends is 0; only the others (crossing
    # the edge of the field of view) need the (K, m') evaluation.
    dv0, w = lin.dv, lin.weight
    dv_end = dv0 + steps.max() * dc
    lin_part = (dv0 >= 0.0) & (dv_end >= 0.0)
    cross_part = ~lin_part & ((dv0 > 0.0) | (dv_end > 0.0))
    const, slope = float(w[lin_part] @ dv0[lin_part]), float(w[lin_part] @ dc[lin_part])
    dv_x, dc_x, w_x = dv0[cross_part], dc[cross_part], w[cross_part]

    def evaluate(a: Array) -> tuple[Array]:
        norm = np.sqrt(1.0 + 2.0 * a * vc + a * a * cc)  # ‖v + α·c‖
        total = const + a * slope
        if w_x.size:
            total = total + np.maximum(dv_x + a[:, None] * dc_x, 0.0) @ w_x
        return (total / norm,)

    k, row = _staged_search(evaluate, steps, lin.value, beta * float(grad_v @ omega_dir))
    if k < 0:
        return AngularStep(0.0, lin.value, v)
    vk = v + steps[k] * c
    return AngularStep(float(steps[k]), float(row[0]), vk / np.linalg.norm(vk))
