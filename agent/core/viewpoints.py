"""Candidate viewpoints for a landmark set and their vision, vectorised over candidates.

A *viewpoint* is a camera pose (p, v): position p (3,) [m; world ENU] and unit viewing
direction v (3,). K candidate viewpoints are stacked as P, V of shape (K, 3). The vision of
every candidate over every landmark is the (K, m) matrix of eq. 3.1/3.8
(f̄(r)·⟨q−p, v⟩⁺·⟨p−q, u⟩⁺, each entry in [0, 1] for the distance term of eq. 3.6).

Candidates are generated from the landmarks themselves: for every landmark, several
neighbourhoods (landmarks close in position and normal) give a centroid c and a mean normal
n̄; the camera is put at c + t·n̄ for a few distances t around d_opt, looking along −n̄.
They are then improved by a vectorised local ascent of eq. 3.8 on a per-candidate subset
(:func:`refine_viewpoints`): the camera direction by the fixed point v ← a/‖a‖ of eq. 3.12
(an exact ascent step on the visible set) and the position by backtracking gradient steps
of eq. 3.16.

Feasibility (:func:`feasible`): inside the mission box, outside every obstacle box inflated
by a margin, and at least R_s from the given other agents' positions.

Occlusion (``visibility = "occlusion"``): an :class:`Environment` may carry a line-of-sight
test (:data:`SightFn`, a batched ray cast supplied by the layer that holds the mesh). Then a
landmark whose line of sight the structure blocks counts 0 in every vision matrix here
(:func:`seen_vision_matrix`); a local refinement keeps the lines of sight of its start pose
and is re-valued with those of its end pose.

Pure numpy, deterministic, no Python loops over landmarks or candidates.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from agent.core.sight import SightFn
from agent.core.vision import DistanceTerm, as_distance_term

Array = NDArray[np.float64]
Mask = NDArray[np.bool_]

#: Neighbourhoods used to seed candidates: (radius [in units of d_opt], least cos(normals)).
NEIGHBOURHOODS: tuple[tuple[float, float], ...] = (
    (0.0, 1.0), (1.0, 0.7), (2.0, 0.7), (4.0, 0.7), (1.5, -0.2), (3.0, -0.2),
)
#: Sizes of the nearest-neighbour groups (by ideal viewpoint q + d_opt·u) used as seeds too;
#: their centroids fall between landmarks, where symmetric neighbourhoods never do.
NEAREST: tuple[int, ...] = (2, 4, 8)
#: Camera distances from the neighbourhood centroid [in units of d_opt].
DISTANCES: tuple[float, ...] = (0.8, 1.0, 1.4, 2.0)




@dataclass(frozen=True)
class Environment:
    """What limits a viewpoint: mission box [lo, hi] [m], obstacle boxes (B, 2, 3) [m]
    (rows lo, hi; e.g. the inspected structure), their clearance margin [m], R_s [m], and
    with occlusion the line-of-sight test (None: the facing model of eq. 3.8)."""

    lo: Array
    hi: Array
    boxes: Array
    margin: float = 0.3
    r_s: float = 1.0
    sight: SightFn | None = None

    @staticmethod
    def free(r_s: float = 1.0) -> Environment:
        """Unbounded space without obstacles."""
        return Environment(np.full(3, -np.inf), np.full(3, np.inf), np.zeros((0, 2, 3)), 0.0,
                           r_s)


def vision_matrix(P: Array, V: Array, q: Array, u: Array, d_opt: float | DistanceTerm) -> Array:
    """Eq. 3.1/3.8 for K cameras × m landmarks: entry (k, j) is the vision of landmark j
    from camera (P[k], V[k]); P, V (K, 3), q, u (m, 3) [m; world ENU]; returns (K, m)."""
    term = as_distance_term(d_opt)
    D = q[None, :, :] - P[:, None, :]  # (K, m, 3): q − p
    dv = np.einsum("kmi,ki->km", D, V)
    pu = -np.einsum("kmi,mi->km", D, u)
    r = np.sqrt(np.einsum("kmi,kmi->km", D, D))
    vis = (dv > 0.0) & (pu > 0.0) & (r > 0.0)
    out = np.zeros(r.shape)
    out[vis] = term.fbar(r[vis]) * dv[vis] * pu[vis]
    return out


def clear_matrix(P: Array, q: Array, u: Array, env: Environment | None,
                 where: Mask | None = None) -> Array:
    """(K, m) weights: 1 where the line of sight P[k] → q[j] is clear (every entry, or only
    those of ``where``; the rest 0), all 1 without an occlusion test."""
    W = np.ones((P.shape[0], q.shape[0]))
    if env is None or env.sight is None:
        return W
    pairs = np.nonzero(np.ones(W.shape, dtype=np.bool_) if where is None else where)
    W[:] = 0.0
    W[pairs] = env.sight(P, q, u, (pairs[0].astype(np.intp), pairs[1].astype(np.intp)))
    return W


def seen_vision_matrix(P: Array, V: Array, q: Array, u: Array,
                       d_opt: float | DistanceTerm, env: Environment | None) -> Array:
    """Eq. 3.1/3.8 K × m as :func:`vision_matrix`, with the entries whose line of sight the
    structure blocks set to 0 (``env.sight``; the facing model without it)."""
    M = vision_matrix(P, V, q, u, d_opt)
    if env is None or env.sight is None:
        return M
    out: Array = M * clear_matrix(P, q, u, env, M > 0.0)
    return out


def feasible(P: Array, env: Environment, others: Array | None = None) -> Mask:
    """Which positions P (K, 3) [m] lie in the mission box, outside every obstacle box
    inflated by ``env.margin`` and at least R_s from every row of ``others`` (n, 3) [m]."""
    ok = np.all((P >= env.lo) & (P <= env.hi), axis=1)
    if env.boxes.shape[0]:
        lo = env.boxes[:, 0, :] - env.margin
        hi = env.boxes[:, 1, :] + env.margin
        inside = np.all((P[:, None, :] > lo[None]) & (P[:, None, :] < hi[None]), axis=2)
        ok &= ~inside.any(axis=1)
    if others is not None and others.shape[0]:
        d = np.sqrt(((P[:, None, :] - others[None, :, :]) ** 2).sum(axis=2))
        ok &= (d >= env.r_s).all(axis=1)
    return np.asarray(ok, dtype=np.bool_)


def _unit_rows(x: Array) -> tuple[Array, Mask]:
    """Rows of x normalised, and which rows had a non-negligible norm."""
    n = np.sqrt((x * x).sum(axis=-1))
    good = n > 1e-9
    return x / np.where(good, n, 1.0)[..., None], good


def seed_viewpoints(
    q: Array, u: Array, d_opt: float,
    neighbourhoods: tuple[tuple[float, float], ...] = NEIGHBOURHOODS,
    distances: tuple[float, ...] = DISTANCES,
    nearest: tuple[int, ...] = NEAREST,
    block: int | None = None,
) -> tuple[Array, Array]:
    """Candidate poses c + t·n̄ looking along −n̄, for the centroid c and mean normal n̄ of
    every landmark's neighbourhoods (radius [d_opt], least normal cosine) and of its groups
    of nearest ideal viewpoints; returns P, V (K, 3), K ≤ m·(#groups)·len(distances).
    q, u (m, 3) [m; world ENU]. With ``block``, more than ``block`` landmarks are grouped
    ``block`` rows at a time (:func:`_blocked_groups`: O(block·m) memory, O(m²) time
    without the sorts; equal ties among the nearest may then go another way)."""
    if q.shape[0] == 0:
        return np.zeros((0, 3)), np.zeros((0, 3))
    if block is not None and q.shape[0] > block:
        c, nu = _blocked_groups(q, u, d_opt, neighbourhoods, nearest, block)
        return _group_poses(c, nu, d_opt, distances)
    dist = np.sqrt(((q[:, None, :] - q[None, :, :]) ** 2).sum(axis=2))  # (m, m) [m]
    cos = u @ u.T
    radius = np.array([h[0] for h in neighbourhoods]) * d_opt  # (H,)
    least = np.array([h[1] for h in neighbourhoods])
    W = ((dist[None] <= radius[:, None, None] + 1e-9)
         & (cos[None] >= least[:, None, None] - 1e-9)).astype(np.float64)  # (H, m, m)
    x = q + d_opt * u  # ideal viewpoints
    dx = np.sqrt(((x[:, None, :] - x[None, :, :]) ** 2).sum(axis=2))
    rank = np.argsort(np.argsort(dx, axis=1, kind="stable"), axis=1, kind="stable")
    ks = np.array([k for k in nearest if 1 < k < q.shape[0]], dtype=np.intp)
    W = np.concatenate([W, (rank[None] < ks[:, None, None]).astype(np.float64)])
    count = W.sum(axis=2, keepdims=True)
    c = (W @ q) / count  # (H, m, 3)
    return _group_poses(c, W @ u, d_opt, distances)


def _group_poses(c: Array, nu: Array, d_opt: float, distances: tuple[float, ...]
                 ) -> tuple[Array, Array]:
    """The poses c + t·n̄ looking along −n̄ of the groups' centroids c and summed normals nu
    (H, m, 3) [m; world ENU] (groups whose normals cancel out left out)."""
    n, good = _unit_rows(nu)
    t = np.asarray(distances) * d_opt  # (T,)
    P = c[:, :, None, :] + t[None, None, :, None] * n[:, :, None, :]  # (H, m, T, 3)
    V = np.broadcast_to(-n[:, :, None, :], P.shape)
    keep = np.broadcast_to(good[:, :, None], P.shape[:3]).reshape(-1)
    return P.reshape(-1, 3)[keep], V.reshape(-1, 3)[keep]


def _blocked_groups(q: Array, u: Array, d_opt: float,
                    neighbourhoods: tuple[tuple[float, float], ...], nearest: tuple[int, ...],
                    block: int) -> tuple[Array, Array]:
    """The groups of :func:`seed_viewpoints` ``block`` landmarks at a time: centroids c and
    summed normals (H, m, 3) [m]; the k nearest ideal viewpoints by a partial sort."""
    m = q.shape[0]
    radius = np.array([h[0] for h in neighbourhoods]) * d_opt
    least = np.array([h[1] for h in neighbourhoods])
    ks = [k for k in nearest if 1 < k < m]
    H = len(neighbourhoods) + len(ks)
    c, nu = np.zeros((H, m, 3)), np.zeros((H, m, 3))
    x = q + d_opt * u  # ideal viewpoints
    top = max(ks, default=0)
    for a in range(0, m, block):  # blocks of landmarks: O(block·m) memory
        b = min(m, a + block)
        dist = np.sqrt(((q[a:b, None, :] - q[None, :, :]) ** 2).sum(axis=2))  # (B, m)
        cos = u[a:b] @ u.T
        W = ((dist[None] <= radius[:, None, None] + 1e-9)
             & (cos[None] >= least[:, None, None] - 1e-9)).astype(np.float64)  # (Hn, B, m)
        if ks:
            dx = np.sqrt(((x[a:b, None, :] - x[None, :, :]) ** 2).sum(axis=2))
            part = np.argpartition(dx, top - 1, axis=1)[:, :top]  # the top nearest, unsorted
            order = np.argsort(np.take_along_axis(dx, part, axis=1), axis=1, kind="stable")
            part = np.take_along_axis(part, order, axis=1)  # nearest first
            near = np.zeros((len(ks), b - a, m))
            rows = np.arange(b - a)[:, None]
            for g, k in enumerate(ks):  # a few group sizes (2, 4, 8)
                near[g, rows, part[:, :k]] = 1.0
            W = np.concatenate([W, near])
        c[:, a:b] = (W @ q) / W.sum(axis=2, keepdims=True)
        nu[:, a:b] = W @ u
    return c, nu


def _masked_value(P: Array, V: Array, q: Array, u: Array, W: Array, term: DistanceTerm
                  ) -> Array:
    """Eq. 3.8 with per-candidate landmark weights W (K, m): Σ_j W_kj·vis_kj, shape (K,)."""
    out: Array = (vision_matrix(P, V, q, u, term) * W).sum(axis=1)
    return out


def _best_directions(P: Array, V: Array, q: Array, u: Array, W: Array, term: DistanceTerm
                     ) -> Array:
    """Eq. 3.12: v ← a/‖a‖, a = Σ_{visible} W·f̄(r)·⟨p−q, u⟩·(q−p) (ascent on the visible set)."""
    D = q[None, :, :] - P[:, None, :]
    dv = np.einsum("kmi,ki->km", D, V)
    pu = -np.einsum("kmi,mi->km", D, u)
    r = np.sqrt(np.einsum("kmi,kmi->km", D, D))
    vis = (dv > 0.0) & (pu > 0.0) & (r > 0.0)
    c = np.zeros(r.shape)
    c[vis] = term.fbar(r[vis]) * pu[vis]
    a = np.einsum("km,kmi->ki", c * W, D)
    a_unit, good = _unit_rows(a)
    return np.where(good[:, None], a_unit, V)


def _position_gradients(P: Array, V: Array, q: Array, u: Array, W: Array, term: DistanceTerm
                        ) -> Array:
    """Eq. 3.16 per candidate with landmark weights W (K, m): ∇_p Σ_j W_kj·vis_kj, (K, 3)."""
    D = q[None, :, :] - P[:, None, :]
    dv = np.einsum("kmi,ki->km", D, V)
    pu = -np.einsum("kmi,mi->km", D, u)
    r = np.sqrt(np.einsum("kmi,kmi->km", D, D))
    vis = (dv > 0.0) & (pu > 0.0) & (r > 0.0)
    rs = np.where(vis, r, 1.0)
    fb = np.where(vis, term.fbar(rs), 0.0) * W
    fbp = np.where(vis, term.fbar_prime(rs), 0.0) * W
    c_d = fbp / rs * (-pu) * dv
    grad: Array = (np.einsum("km,kmi->ki", c_d, D) + (fb * dv) @ u
                   - (fb * pu).sum(axis=1)[:, None] * V)
    return grad


def refine_viewpoints(
    P: Array, V: Array, q: Array, u: Array, d_opt: float | DistanceTerm,
    W: Array | None = None, env: Environment | None = None, others: Array | None = None,
    iters: int = 25, step0: float = 0.5,
) -> tuple[Array, Array, Array]:
    """Local ascent of eq. 3.8 for every candidate on its weighted set W (K, m) (default: all):
    v by eq. 3.12, p by backtracking steps along eq. 3.16 kept feasible; returns P, V, value."""
    term = as_distance_term(d_opt)
    W0 = np.ones((P.shape[0], q.shape[0])) if W is None else W
    W = W0 * clear_matrix(P, q, u, env)  # the lines of sight of the start poses
    P, V = P.copy(), V.copy()
    V = _best_directions(P, V, q, u, W, term)
    val = _masked_value(P, V, q, u, W, term)
    step = np.full(P.shape[0], step0)
    for _ in range(iters):
        g, ok = _unit_rows(_position_gradients(P, V, q, u, W, term))
        trial_p = P + step[:, None] * g
        trial_v = _best_directions(trial_p, V, q, u, W, term)
        trial = _masked_value(trial_p, trial_v, q, u, W, term)
        better = ok & (trial > val)
        if env is not None:
            better &= feasible(trial_p, env, others)
        P[better], V[better], val[better] = trial_p[better], trial_v[better], trial[better]
        step = np.where(better, np.minimum(step * 1.5, 2.0), step * 0.4)
        if float(step.max()) < 1e-3:
            break
    if env is not None and env.sight is not None:  # valued with the end poses' sight lines
        val = (seen_vision_matrix(P, V, q, u, term, env) * W0).sum(axis=1)
    return P, V, val


def best_viewpoint(
    q: Array, u: Array, d_opt: float, env: Environment, others: Array | None = None,
    extra_P: Array | None = None, extra_V: Array | None = None, keep: int = 12,
) -> tuple[Array, Array, float]:
    """Best feasible pose for the whole set (q, u) (eq. 3.8): seeds (plus ``extra`` poses),
    the ``keep`` best refined; returns (p, v, vision). Vision 0 and p = nan if none feasible."""
    P, V = seed_viewpoints(q, u, d_opt)
    if extra_P is not None and extra_V is not None:
        P, V = np.vstack([P, extra_P]), np.vstack([V, extra_V])
    ok = feasible(P, env, others)
    P, V = P[ok], V[ok]
    if P.shape[0] == 0:
        return np.full(3, np.nan), np.array([1.0, 0.0, 0.0]), 0.0
    val = seen_vision_matrix(P, V, q, u, d_opt, env).sum(axis=1)
    top = np.argsort(-val, kind="stable")[:keep]
    P, V, val = refine_viewpoints(P[top], V[top], q, u, d_opt, env=env, others=others)
    k = int(np.argmax(val))
    return P[k], V[k], float(val[k])


def _separated(P: Array, chosen: NDArray[np.intp], r_s: float) -> Mask:
    """Which rows of P (K, 3) [m] are ≥ R_s from every chosen row (pairwise safety)."""
    if chosen.size == 0:
        return np.ones(P.shape[0], dtype=bool)
    d = np.sqrt(((P[:, None, :] - P[chosen][None, :, :]) ** 2).sum(axis=2))
    return np.asarray((d >= r_s).all(axis=1), dtype=np.bool_)


def select_viewpoints(
    M: Array, P: Array, n: int, r_s: float, first: int | None = None, max_rounds: int = 20,
    init: NDArray[np.intp] | None = None,
) -> tuple[NDArray[np.intp], float]:
    """n candidates maximising eq. 3.10 with best-view ownership, Σ_j max_{k∈S} M_kj, over the
    (K, m) vision matrix M, pairwise ≥ R_s apart (positions P (K, 3) [m]): greedy from
    ``init`` or ``first`` (default: the best single candidate), then one-for-one swaps until
    none improves. Returns the chosen indices (≤ n if too few are separated) and the value."""
    K = M.shape[0]
    if K == 0 or n <= 0:
        return np.zeros(0, dtype=np.intp), 0.0
    chosen = np.zeros(0, dtype=np.intp)
    cur = np.zeros(M.shape[1])
    if init is not None and init.size:
        chosen = init.astype(np.intp).copy()
        cur = M[chosen].max(axis=0)
    elif first is not None:
        chosen = np.array([first], dtype=np.intp)
        cur = M[first].copy()
    while chosen.size < n:
        gain = np.maximum(M - cur[None, :], 0.0).sum(axis=1)
        gain[~_separated(P, chosen, r_s)] = -np.inf
        gain[chosen] = -np.inf
        k = int(np.argmax(gain))
        if not np.isfinite(gain[k]):
            break
        chosen = np.append(chosen, k)
        cur = np.maximum(cur, M[k])
    value = float(cur.sum())
    for _ in range(max_rounds):
        improved = False
        for s in range(chosen.size):  # loop over team slots, not landmarks
            rest = np.delete(chosen, s)
            base = M[rest].max(axis=0) if rest.size else np.zeros(M.shape[1])
            val = np.maximum(M, base[None, :]).sum(axis=1)
            val[~_separated(P, rest, r_s)] = -np.inf
            val[rest] = -np.inf
            k = int(np.argmax(val))
            if val[k] > value + 1e-9 and k != chosen[s]:
                chosen[s] = k
                value = float(val[k])
                improved = True
        if not improved:
            break
    return chosen, value


def best_view_owner(M: Array, default: NDArray[np.intp]) -> NDArray[np.intp]:
    """Best-view ownership over a (n, m) vision matrix: argmax_i M_ij; a landmark nobody sees
    (column all zero) keeps ``default[j]``."""
    owner = np.argmax(M, axis=0).astype(np.intp)
    return np.where(M.max(axis=0) > 0.0, owner, default).astype(np.intp)


def refine_team(
    P: Array, V: Array, q: Array, u: Array, d_opt: float, env: Environment,
    fixed_others: Array | None = None, owner: NDArray[np.intp] | None = None, rounds: int = 4,
) -> tuple[Array, Array, NDArray[np.intp], float]:
    """Lloyd-style joint refinement of eq. 3.10 with best-view ownership: assign every landmark
    to the pose that sees it best, refine each pose on its set (R_s from the team and from
    ``fixed_others``), repeat; returns P, V, owner, value Σ_j max_i vis_ij."""
    n = P.shape[0]
    P, V = P.copy(), V.copy()
    M = seen_vision_matrix(P, V, q, u, d_opt, env)
    owner = best_view_owner(M, np.zeros(q.shape[0], dtype=np.intp) if owner is None else owner)
    fixed = np.zeros((0, 3)) if fixed_others is None else fixed_others
    value = float(M.max(axis=0).sum()) if n else 0.0
    for _ in range(rounds):
        for i in range(n):  # loop over team members, each a vectorised refinement
            others = np.vstack([np.delete(P, i, axis=0), fixed])
            mine = owner == i
            if not mine.any():
                continue
            Pi, Vi, _ = refine_viewpoints(P[i:i + 1], V[i:i + 1], q[mine], u[mine], d_opt,
                                          env=env, others=others)
            P[i], V[i] = Pi[0], Vi[0]
        M = seen_vision_matrix(P, V, q, u, d_opt, env)
        owner = best_view_owner(M, owner)
        new = float(M.max(axis=0).sum())
        if new <= value + 1e-9:
            value = max(value, new)
            break
        value = new
    return P, V, owner, value
