"""Centralised reference for the coverage score: a global search over all poses jointly.

Ownership is by best view: each landmark belongs to the drone that sees it best, so the
score of poses (P, V) is Σ_j max_i vis(p_i, v_i, q_j) (eq. 3.10 with the best partition for
those poses; an upper bound of eq. 3.10 for any partition at those poses).

Search: candidate viewpoints seeded from every landmark neighbourhood
(:func:`agent.core.viewpoints.seed_viewpoints`), each refined on the landmarks it sees well;
the (K, m) vision matrix; for several starts (the best candidates and random ones as first
pick) greedy selection of n viewpoints pairwise ≥ R_s apart plus one-for-one swaps; then a
joint Lloyd refinement (assign by best view, refine every pose on its set, repeat), whose
poses are added to the pool and searched again. The best over all starts is then improved by
centralised 2-opt and 3-opt (every pair and triple of drones re-chosen jointly for the
landmarks they own).
Positions stay in the mission space, outside the structure (with clearance) and ≥ R_s apart.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from agent.core.viewpoints import (
    feasible,
    refine_team,
    refine_viewpoints,
    seed_viewpoints,
    select_viewpoints,
    vision_matrix,
)
from bench.quality.structures import R_S, Structure

Array = NDArray[np.float64]


@dataclass(frozen=True)
class Reference:
    """The best joint poses found: P, V (n, 3), best-view owners (m,), score [vision units]."""

    P: Array
    V: Array
    owner: NDArray[np.intp]
    score: float
    starts: int


def candidate_pool(s: Structure, d_opt: float, refine: bool = True) -> tuple[Array, Array]:
    """Feasible seeded viewpoints of the whole structure, each refined (eq. 3.8) on the
    landmarks it sees at ≥ 30 % of its best landmark's vision."""
    env = s.environment()
    P, V = seed_viewpoints(s.q, s.u, d_opt)
    ok = feasible(P, env)
    P, V = P[ok], V[ok]
    if refine and P.shape[0]:
        M = vision_matrix(P, V, s.q, s.u, d_opt)
        W = (M >= 0.3 * M.max(axis=1, keepdims=True)) & (M > 0.0)
        P2, V2, _ = refine_viewpoints(P, V, s.q, s.u, d_opt, W=W.astype(np.float64), env=env,
                                      iters=15)
        P, V = np.vstack([P, P2]), np.vstack([V, V2])
    return P, V


def reference(s: Structure, n: int, d_opt: float, starts: int = 12, seed: int = 0) -> Reference:
    """Multi-start global optimisation of n poses jointly (best-view ownership)."""
    env = s.environment()
    P, V = candidate_pool(s, d_opt)
    M = vision_matrix(P, V, s.q, s.u, d_opt)
    rng = np.random.default_rng(seed)
    order = np.argsort(-M.sum(axis=1), kind="stable")
    firsts = [None, *order[:max(1, starts // 2)].tolist(),
              *rng.choice(P.shape[0], size=max(0, starts - 1 - starts // 2), replace=False)]
    best: Reference | None = None
    for first in firsts:
        chosen, _ = select_viewpoints(M, P, n, R_S, first=None if first is None else int(first))
        Pt, Vt, owner, value = refine_team(P[chosen], V[chosen], s.q, s.u, d_opt, env)
        # Search again with the refined poses in the pool (they often beat every seed).
        P2, V2 = np.vstack([P, Pt]), np.vstack([V, Vt])
        M2 = np.vstack([M, vision_matrix(Pt, Vt, s.q, s.u, d_opt)])
        init = np.arange(P.shape[0], P2.shape[0], dtype=np.intp)
        chosen2, _ = _swap_from(M2, P2, init)
        Pt2, Vt2, owner2, value2 = refine_team(P2[chosen2], V2[chosen2], s.q, s.u, d_opt, env)
        if value2 > value:
            Pt, Vt, owner, value = Pt2, Vt2, owner2, value2
        if best is None or value > best.score:
            best = Reference(Pt, Vt, owner, value, len(firsts))
    assert best is not None
    return _pair_two_opt(s, best, d_opt, P, V)


def _groups(n: int, size: int) -> list[tuple[int, ...]]:
    """All groups of ``size`` distinct drones out of n, in lexicographic order."""
    if size == 2:
        return [(i, j) for i in range(n) for j in range(i + 1, n)]
    return [(i, j, k) for i in range(n) for j in range(i + 1, n) for k in range(j + 1, n)]


def _pair_two_opt(s: Structure, ref: Reference, d_opt: float, pool_P: Array, pool_V: Array,
                  sweeps: int = 3) -> Reference:
    """Centralised 2-opt and 3-opt: for every pair, then every triple of drones, re-choose
    their poses jointly for the landmarks they own (seeded candidates of that union plus the
    pool and their current poses), the others fixed; keep a change when the group's
    best-view score rises (the team's cannot fall then), and repeat while anything changes."""
    env = s.environment()
    P, V, owner, value = ref.P.copy(), ref.V.copy(), ref.owner.copy(), ref.score
    n = P.shape[0]
    for _ in range(sweeps):
        improved = False
        for size in (2, 3):
            for g in _groups(n, size):  # loops over groups of drones
                grp = list(g)
                mine = np.isin(owner, grp)
                if not mine.any():
                    continue
                q, u = s.q[mine], s.u[mine]
                others = np.delete(P, grp, axis=0)
                old = float(vision_matrix(P[grp], V[grp], q, u, d_opt).max(axis=0).sum())
                cP, cV = seed_viewpoints(q, u, d_opt)
                cP, cV = np.vstack([cP, pool_P]), np.vstack([cV, pool_V])
                ok = feasible(cP, env, others)
                cP, cV = np.vstack([P[grp], cP[ok]]), np.vstack([V[grp], cV[ok]])
                M = vision_matrix(cP, cV, q, u, d_opt)
                chosen, _ = select_viewpoints(M, cP, size, R_S)
                if chosen.size < size:
                    continue
                Pp, Vp, _, new = refine_team(cP[chosen], cV[chosen], q, u, d_opt, env,
                                             fixed_others=others)
                if new > old + 1e-6:
                    P[grp], V[grp] = Pp, Vp
                    M_all = vision_matrix(P, V, s.q, s.u, d_opt)
                    owner = np.argmax(M_all, axis=0).astype(np.intp)
                    value, improved = float(M_all.max(axis=0).sum()), True
        if not improved:
            break
    P, V, owner, value2 = refine_team(P, V, s.q, s.u, d_opt, env, owner=owner, rounds=2)
    return Reference(P, V, owner, max(value, value2), ref.starts)


def _swap_from(M: Array, P: Array, init: NDArray[np.intp]) -> tuple[NDArray[np.intp], float]:
    """One-for-one swap search started from the selection ``init``."""
    chosen = init.copy()
    value = float(M[chosen].max(axis=0).sum())
    for _ in range(20):
        improved = False
        for s in range(chosen.size):  # loop over team slots
            rest = np.delete(chosen, s)
            base = M[rest].max(axis=0) if rest.size else np.zeros(M.shape[1])
            val = np.maximum(M, base[None, :]).sum(axis=1)
            d = np.sqrt(((P[:, None, :] - P[rest][None, :, :]) ** 2).sum(axis=2))
            val[~(d >= R_S).all(axis=1)] = -np.inf
            val[rest] = -np.inf
            k = int(np.argmax(val))
            if val[k] > value + 1e-9 and k != chosen[s]:
                chosen[s], value, improved = k, float(val[k]), True
        if not improved:
            break
    return chosen, value
