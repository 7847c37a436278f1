"""Collision avoidance (thesis section 4.3): safe directions and obstacle constraints.

A direction ``x`` (unit, world frame) is *acceptable* for obstacle normals ``w`` (k, 3) and
bounds ``lam`` (k,) when ⟨p_opt, x⟩ ≥ 0 and ⟨w_i, x⟩ ≥ λ_i for every i. Abrupt avoidance
(problem 4.7) is the case λ = 0 for obstacles the agent touches; smooth avoidance (problem 4.11)
uses λ_i = −d_i / D_w (eq. 4.10) for obstacles closer than the worry distance D_w.

:func:`safe_direction` solves the problem exactly by enumerating every KKT candidate
(Conjectures 1 and 2, extended with the degenerate cases) in one batch of array operations.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from agent.core.vision import cross

Array = NDArray[np.float64]

#: Slack [dimensionless] accepted when checking a candidate direction against a constraint.
FEASIBILITY_TOL = 1e-10
#: Distance [m] under which an abrupt-mode obstacle counts as touched (problem 4.7).
CONTACT_TOL = 1e-9

_XY = np.array([1.0, 1.0, 0.0])

AvoidanceMode = Literal["none", "abrupt", "smooth"]


@dataclass(frozen=True)
class MissionSpace:
    """Axis-aligned box Ω = [lo, hi] [m; world ENU]; infinite bounds mean no wall."""

    lo: Array
    hi: Array

    @staticmethod
    def unbounded() -> MissionSpace:
        """The free space of section 5.1."""
        return MissionSpace(np.full(3, -np.inf), np.full(3, np.inf))

    def contains(self, p: Array, tol: float = 0.0) -> bool:
        """Whether p lies in Ω (within ``tol`` metres)."""
        return bool(np.all(p >= self.lo - tol) and np.all(p <= self.hi + tol))

    def clip(self, p: Array) -> Array:
        """p projected into Ω (used only to absorb floating-point round-off)."""
        return np.clip(p, self.lo, self.hi)

    def walls(self, planar: bool) -> tuple[Array, Array]:
        """Finite walls as (W, c): inward unit normals W (k, 3) and offsets with d = W·p + c [m]."""
        key = "_walls_planar" if planar else "_walls"
        cached = self.__dict__.get(key)
        if cached is None:
            axes = 2 if planar else 3
            eye = np.eye(3)[:axes]
            lo, hi = self.lo[:axes], self.hi[:axes]
            w = np.vstack([eye[np.isfinite(lo)], -eye[np.isfinite(hi)]]).reshape(-1, 3)
            c = np.concatenate([-lo[np.isfinite(lo)], hi[np.isfinite(hi)]])
            cached = (w, c)
            object.__setattr__(self, key, cached)
        return cached


@functools.lru_cache(maxsize=128)
def _pairs(n: int) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
    """Index pairs i < j of n constraints."""
    return np.triu_indices(n, k=1)


def _unit_rows(x: Array) -> tuple[Array, NDArray[np.bool_]]:
    """Rows of x normalised, and which rows had a usable (non-negligible) norm."""
    n = np.sqrt((x * x).sum(axis=-1))
    good = n > 1e-12
    return x / np.where(good, n, 1.0)[..., None], good


def _circle_points(wi: Array, li: float) -> Array:
    """Four points of the circle {⟨w, x⟩ = λ, ‖x‖ = 1} (used when p_opt ∥ w: all tie)."""
    e1 = cross(wi, np.eye(3)[int(np.argmin(np.abs(wi)))])
    e1 /= np.sqrt(e1 @ e1)
    e2 = cross(wi, e1)
    out: Array = li * wi + np.sqrt(1.0 - li * li) * np.array([e1, -e1, e2, -e2])
    return out


def _candidates_3d(p_opt: Array, cw: Array, cl: Array) -> Array:
    """Conjecture 2, completed: p_opt, the point of each cone nearest p_opt, and both points
    where any two cones meet (the last constraint row is ⟨p_opt, x⟩ ≥ 0 itself).

    These are all KKT points of problem 4.11 on the sphere; rows may be NaN or non-unit
    where a construction does not exist, and are then rejected by the feasibility check.
    """
    w, lam = cw[:-1], np.clip(cl[:-1], -1.0, 1.0)
    # Nearest point of the circle {⟨w, x⟩ = λ, ‖x‖ = 1} to p_opt: λw + √(1−λ²)·e.
    tang = p_opt - (w @ p_opt)[:, None] * w
    e, good = _unit_rows(tang)
    parts = [p_opt[None, :], lam[:, None] * w + np.sqrt(1.0 - lam * lam)[:, None] * e]
    if not good.all():
        parts.extend(_circle_points(wi, li) for wi, li in zip(w[~good], lam[~good], strict=True))
    # Intersections of two circles: x = a·w_i + b·w_j ± c·(w_i × w_j)/‖w_i × w_j‖.
    i, j = _pairs(cw.shape[0])
    if i.size:
        wi, wj, li, lj = cw[i], cw[j], cl[i], cl[j]
        g = (wi * wj).sum(axis=1)
        den = 1.0 - g * g
        ok = den > 1e-12
        den = np.where(ok, den, 1.0)
        a = (li - g * lj) / den
        b = (lj - g * li) / den
        c2 = 1.0 - (a * a + b * b + 2.0 * a * b * g)
        c = np.where(ok & (c2 >= 0.0), np.sqrt(np.maximum(c2, 0.0)), np.nan)
        n = cross(wi, wj) * (c / np.sqrt(den))[:, None]
        base = a[:, None] * wi + b[:, None] * wj
        parts.extend([base + n, base - n])
    return np.vstack(parts)


def _candidates_2d(p_opt: Array, cw: Array, cl: Array) -> Array:
    """Propositions 1 and 2: p_opt and the two rays bounding each constraint, in the xy-plane."""
    cl = np.clip(cl, -1.0, 1.0)
    perp = np.stack([-cw[:, 1], cw[:, 0], np.zeros(cw.shape[0])], axis=1)
    s = np.sqrt(1.0 - cl * cl)[:, None]
    base = cl[:, None] * cw
    return np.vstack([p_opt[None, :], base + s * perp, base - s * perp])


def safe_direction(
    p_opt: Array, w: Array, lam: Array, *, planar: bool = False, tol: float = FEASIBILITY_TOL
) -> Array:
    """Problem 4.11 (4.7 when lam = 0): the unit x maximising ⟨p_opt, x⟩ s.t. ⟨w_i, x⟩ ≥ λ_i.

    ``p_opt`` (3,) unit, ``w`` (k, 3) unit obstacle normals pointing away from the obstacle,
    ``lam`` (k,) bounds in [−1, 1]. Returns the zero vector when no acceptable direction
    exists. ``planar=True`` restricts x to the xy-plane (the 2-D mode of chapter 5).
    """
    p_opt = np.asarray(p_opt, dtype=np.float64)
    w = np.asarray(w, dtype=np.float64).reshape(-1, 3)
    lam = np.asarray(lam, dtype=np.float64).reshape(-1)
    if planar:
        # Restricted to the plane, ⟨w, x⟩ ≥ λ reads ⟨w_xy/‖w_xy‖, x⟩ ≥ λ/‖w_xy‖.
        p_opt = p_opt * _XY
        w_xy = w * _XY
        n_xy = np.sqrt((w_xy * w_xy).sum(axis=1))
        keep = n_xy > 1e-12
        # A normal with no planar component constrains nothing in the plane unless λ > 0.
        if np.any(~keep & (lam > tol)):
            return np.zeros(3)
        w, lam = w_xy[keep] / n_xy[keep, None], lam[keep] / n_xy[keep]
    norm = float(np.sqrt(p_opt @ p_opt))
    if norm == 0.0:
        return np.zeros(3)
    p_opt = p_opt / norm
    if w.shape[0] == 0 or bool(np.all(w @ p_opt >= lam)):
        return p_opt
    cw = np.vstack([w, p_opt])  # ⟨p_opt, x⟩ ≥ 0 is one more constraint of the same form
    cl = np.append(lam, 0.0)
    cands = _candidates_2d(p_opt, cw, cl) if planar else _candidates_3d(p_opt, cw, cl)
    n2 = (cands * cands).sum(axis=1)
    ok = (np.abs(n2 - 1.0) < 1e-9) & np.all(cands @ cw.T >= cl - tol, axis=1)
    if not ok.any():
        return np.zeros(3)
    score = np.where(ok, cands @ p_opt, -np.inf)
    best: Array = cands[int(np.argmax(score))]
    return best / np.sqrt(best @ best)


@dataclass(frozen=True)
class Constraints:
    """Active obstacle constraints ⟨w_i, x⟩ ≥ λ_i and the distances d_i [m] they come from."""

    w: Array
    lam: Array
    dist: Array

    def with_direction_limit(self, prev_dir: Array, lambda_dir: float) -> Constraints:
        """Section 5.2: add ⟨x, ṗ_dir(t−1)⟩ ≥ λ_dir (limits the change of direction)."""
        return Constraints(
            np.vstack([self.w, prev_dir[None, :]]),
            np.append(self.lam, lambda_dir),
            np.append(self.dist, 0.0),
        )


def obstacle_distances(
    p: Array, space: MissionSpace, others: Array, r_s: float, planar: bool
) -> tuple[Array, Array]:
    """Distances d_i [m] to walls and to other agents' safety spheres, and their normals ŵ_i."""
    w, c = space.walls(planar)
    if not others.shape[0]:
        return w, w @ p + c
    diff = p - others
    if planar:
        diff[:, 2] = 0.0
    dist = np.sqrt((diff * diff).sum(axis=1))
    normals = diff / np.where(dist > 0.0, dist, 1.0)[:, None]
    return np.vstack([w, normals]), np.concatenate([w @ p + c, dist - r_s])


def active_constraints(
    p: Array,
    space: MissionSpace,
    others: Array,
    *,
    mode: AvoidanceMode,
    r_s: float,
    d_w: float,
    planar: bool,
    extra: tuple[Array, Array] | None = None,
) -> Constraints:
    """Problem 4.7 (abrupt: touched obstacles, λ = 0) or 4.11 (smooth: d < D_w, eq. 4.10).

    ``extra`` = (ŵ (k, 3), d (k,)) adds obstacles computed by the caller, e.g. the closest
    points of a structure mesh (unit normals away from the obstacle, distances [m]).
    """
    w, d = obstacle_distances(p, space, others, r_s, planar)
    if extra is not None and extra[1].size:
        w, d = np.vstack([w, extra[0].reshape(-1, 3)]), np.concatenate([d, extra[1]])
    if mode == "abrupt":
        sel = d <= CONTACT_TOL
        lam = np.zeros(int(sel.sum()))
    elif mode == "smooth":
        sel = d < d_w
        lam = -np.maximum(d[sel], 0.0) / d_w
    else:
        sel = np.zeros(d.shape, dtype=bool)
        lam = np.zeros(0)
    return Constraints(w[sel], lam, d[sel])


#: Depth [m] a path must reach inside another agent's safety sphere before it counts as
#: entering it; absorbs round-off for paths that start on the sphere and leave tangentially.
SPHERE_SLACK = 1e-10


def max_step_to_boundary(
    p: Array, direction: Array, space: MissionSpace, others: Array, r_s: float
) -> float:
    """Largest α ≥ 0 [m] such that the segment p + s·dir, s ∈ [0, α], stays in Ω and ≥ R_s apart."""
    w, c = space.walls(False)
    rate = w @ direction  # d(wall distance)/dα
    closing = rate < 0.0
    alpha = np.inf
    if closing.any():
        alpha = float(((w[closing] @ p + c[closing]) / -rate[closing]).min())
    if others.shape[0]:
        # ‖e + α·dir‖² = ‖e‖² + 2αb + α², e = p − p_j, b = ⟨e, dir⟩.
        e = p - others
        b = e @ direction
        ee = (e * e).sum(axis=1)
        inner = r_s - SPHERE_SLACK
        enters = (b < 0.0) & (b * b - ee + inner * inner > 0.0)
        if enters.any():
            disc = np.maximum(b[enters] ** 2 - ee[enters] + r_s * r_s, 0.0)
            alpha = min(alpha, float(np.maximum(-b[enters] - np.sqrt(disc), 0.0).min()))
    return max(alpha, 0.0)
