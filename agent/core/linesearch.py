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
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from agent.core.vision import DistanceTerm, VisibleTerms, cross

Array = NDArray[np.float64]

#: Candidates evaluated in the first batch; the rest only if none of these is accepted.
HEAD = 4


def candidate_steps(alpha0: float, alpha_min: float, tau: float) -> Array:
    """Algorithm 6: the step sizes α_0·τ^k, k = 0, 1, … while α ≥ α_min."""
    if alpha0 <= 0.0 or alpha0 < alpha_min:
        return np.zeros(0)
    k = int(np.floor(np.log(alpha_min / alpha0) / np.log(tau))) + 1 if alpha_min > 0 else 64
    steps = alpha0 * tau ** np.arange(k, dtype=np.float64)
    return steps[steps >= alpha_min * (1.0 - 1e-12)]


def _staged_search(
    evaluate: Callable[[Array], tuple[Array, ...]], steps: Array, base: float, slope: float
) -> tuple[int, tuple[Array, ...]]:
    """Largest accepted candidate: its index (−1 if none) and its row of every evaluated array.

    ``evaluate(batch)`` returns arrays whose first axis runs over the batch; the first one
    holds the vision at each candidate.
    """
    start = 0
    for stop in (min(HEAD, steps.size), steps.size):
        if stop <= start:
            continue
        batch = steps[start:stop]
        out = evaluate(batch)
        ok = out[0] > base + batch * slope
        if ok.any():
            k = int(np.argmax(ok))
            return start + k, tuple(x[k] for x in out)
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
    term: DistanceTerm, beta: float,
) -> LinearStep:
    """Algorithm 6 (gradient form) for the linear velocity along the unit ``direction``.

    ``steps`` (K,) may be truncated at an obstacle boundary. Returns α = 0 (and the current
    vision) when no candidate satisfies the strict Armijo condition.
    """
    still = LinearStep(0.0, t.value, t.fb * t.pu, t.dv)
    if steps.size == 0 or t.r.size == 0:
        return still
    dd = direction @ t.dT  # ⟨q − p, dir⟩
    udir = direction @ t.uT
    vdir = float(v @ direction)
    r2 = t.r * t.r

    def terms(a: Array) -> tuple[Array, Array, Array]:
        """f̄(r'), ⟨p' − q, u⟩⁺ and ⟨q − p', v⟩ at p' = p + α·dir (q − p' = d − α·dir)."""
        x = a * dd
        x *= -2.0
        x += r2
        x += a * a
        np.maximum(x, 1e-300, out=x)
        np.sqrt(x, out=x)
        pu = a * udir
        pu += t.pu
        np.maximum(pu, 0.0, out=pu)
        return term.fbar(x), pu, t.dv - a * vdir

    def evaluate(a: Array) -> tuple[Array, Array, Array]:
        weight, pu, dv = terms(a[:, None])
        weight *= pu
        return (weight * np.maximum(dv, 0.0)).sum(axis=1), weight, dv

    k, row = _staged_search(evaluate, steps, t.value, beta * float(grad_p @ direction))
    if k < 0:
        return still
    return LinearStep(float(steps[k]), float(row[0]), row[1], row[2])


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
