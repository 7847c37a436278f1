"""Vision of one camera over a landmark set (thesis chapter 3, eq. 3.1-3.16).

Frames and units: every vector is in the world frame (ENU), positions in metres.
A camera is ``(p, v)``: position ``p`` (3,) [m] and unit viewing direction ``v`` (3,).
Landmarks are ``(q, u)``: positions ``q`` (m, 3) [m] and unit surface normals ``u`` (m, 3).

All functions are pure numpy and vectorised over landmarks. Internally landmarks are kept
as (3, m) columns (:class:`Landmarks`), which makes the per-landmark arithmetic contiguous.
The distance term ``f`` of eq. 3.6 is the default; any other :class:`DistanceTerm` can be
passed instead of ``d_opt``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

import numpy as np
from numpy.typing import NDArray

Array = NDArray[np.float64]


class DistanceTerm(Protocol):
    """A distance term f(r) of eq. 3.6 folded into f̄(r) = f(r)/r² (eq. 3.7)."""

    def fbar(self, r: Array) -> Array:
        """Eq. 3.7: f̄(r) = f(r) / r² for distances r > 0 [m]."""
        ...

    def fbar_prime(self, r: Array) -> Array:
        """Derivative d f̄ / d r of eq. 3.7."""
        ...


@dataclass(frozen=True)
class ExpDistance:
    """Eq. 3.6: f(r) = (r / d_opt) · exp(1 − r / d_opt), maximal (= 1) at r = d_opt [m]."""

    d_opt: float

    def __post_init__(self) -> None:
        if not (np.isfinite(self.d_opt) and self.d_opt > 0):
            raise ValueError(f"d_opt must be a positive finite distance [m], got {self.d_opt}")

    def f(self, r: Array) -> Array:
        """Eq. 3.6: the normalised distance term."""
        x = r / self.d_opt
        return x * np.exp(1.0 - x)

    def fbar(self, r: Array) -> Array:
        """Eq. 3.7 for eq. 3.6: f̄(r) = exp(1 − r/d_opt) / (d_opt · r)."""
        out = r * (-1.0 / self.d_opt)
        out += 1.0
        np.exp(out, out=out)
        out /= r
        out *= 1.0 / self.d_opt
        return out

    def fbar_prime(self, r: Array) -> Array:
        """Derivative of eq. 3.7 for eq. 3.6: −f̄(r) · (1/d_opt + 1/r)."""
        return -self.fbar(r) * (1.0 / self.d_opt + 1.0 / r)


@dataclass(frozen=True)
class GenericDistance:
    """Any f with derivative df, folded into eq. 3.7: f̄ = f/r², f̄' = f'/r² − 2f/r³."""

    f: Callable[[Array], Array]
    df: Callable[[Array], Array]

    def fbar(self, r: Array) -> Array:
        """Eq. 3.7: f̄(r) = f(r) / r²."""
        return self.f(r) / (r * r)

    def fbar_prime(self, r: Array) -> Array:
        """Derivative of eq. 3.7: f'(r)/r² − 2 f(r)/r³."""
        return self.df(r) / (r * r) - 2.0 * self.f(r) / (r * r * r)


def as_distance_term(d_opt: float | DistanceTerm) -> DistanceTerm:
    """A number means eq. 3.6 with that d_opt [m]; a DistanceTerm is used as given."""
    if isinstance(d_opt, (int, float, np.floating)):
        return ExpDistance(float(d_opt))
    return d_opt


@dataclass(frozen=True)
class Landmarks:
    """A landmark set as contiguous columns: qT, uT of shape (3, m) [m; world ENU]."""

    qT: Array
    uT: Array

    @staticmethod
    def of(q: Array, u: Array) -> Landmarks:
        """From row arrays q, u of shape (m, 3)."""
        q = np.asarray(q, dtype=np.float64).reshape(-1, 3)
        u = np.asarray(u, dtype=np.float64).reshape(-1, 3)
        return Landmarks(np.ascontiguousarray(q.T), np.ascontiguousarray(u.T))

    @property
    def m(self) -> int:
        """Number of landmarks."""
        return int(self.qT.shape[1])


def cross(a: Array, b: Array) -> Array:
    """a × b for 3-vectors or rows of (n, 3) arrays (cheaper than ``np.cross`` for small inputs)."""
    if a.ndim == 1 and b.ndim == 1:
        a0, a1, a2 = a.tolist()
        b0, b1, b2 = b.tolist()
        return np.array([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0])
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    return np.stack([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0], axis=-1)


@dataclass(frozen=True)
class VisibleTerms:
    """Per-landmark terms of eq. 3.8 restricted to Q^V (the visible landmarks), as columns."""

    dT: Array  #: q − p (3, k) [m]
    uT: Array  #: normals (3, k)
    r: Array  #: ‖q − p‖ (k,) [m]
    dv: Array  #: ⟨q − p, v⟩ > 0 (k,)
    pu: Array  #: ⟨p − q, u⟩ > 0 (k,)
    fb: Array  #: f̄(r) (k,)

    @property
    def value(self) -> float:
        """Eq. 3.8: vision over Q^V."""
        return float(self.fb @ (self.dv * self.pu))


def visible_terms(p: Array, v: Array, lm: Landmarks, term: DistanceTerm) -> VisibleTerms:
    """Section 4.2: Q^V = {⟨q − p, v⟩ > 0, ⟨p − q, u⟩ > 0} and its terms of eq. 3.8."""
    dT = lm.qT - p[:, None]
    dv = v @ dT
    pu = -(dT * lm.uT).sum(axis=0)
    vis = (dv > 0.0) & (pu > 0.0)
    if not vis.all():
        idx = np.flatnonzero(vis)
        dT, uT, dv, pu = dT[:, idx], lm.uT[:, idx], dv[idx], pu[idx]
    else:
        uT = lm.uT
    r = np.sqrt((dT * dT).sum(axis=0))
    if r.size and not r.min() > 0.0:  # a landmark exactly at the camera is not visible
        keep = np.flatnonzero(r > 0.0)
        dT, uT, dv, pu, r = dT[:, keep], uT[:, keep], dv[keep], pu[keep], r[keep]
    return VisibleTerms(dT=dT, uT=uT, r=r, dv=dv, pu=pu, fb=term.fbar(r))


def per_landmark(p: Array, v: Array, q: Array, u: Array, d_opt: float | DistanceTerm) -> Array:
    """Eq. 3.1/3.8: vision of each landmark, f̄(r)·⟨q−p, v⟩⁺·⟨p−q, u⟩⁺, shape (m,)."""
    return per_landmark_cols(p, v, Landmarks.of(q, u), d_opt)


def per_landmark_cols(p: Array, v: Array, lm: Landmarks, d_opt: float | DistanceTerm) -> Array:
    """Eq. 3.1/3.8 on the column layout: vision of each landmark of ``lm``, shape (m,)."""
    term = as_distance_term(d_opt)
    p, v = np.asarray(p, dtype=np.float64), np.asarray(v, dtype=np.float64)
    dT = lm.qT - p[:, None]
    dv = v @ dT
    pu = np.einsum("ij,ij->j", dT, lm.uT)
    pu *= -1.0
    r = np.sqrt(np.einsum("ij,ij->j", dT, dT))
    vis = (dv > 0.0) & (pu > 0.0) & (r > 0.0)
    out = np.zeros(r.shape)
    out[vis] = term.fbar(r[vis]) * dv[vis] * pu[vis]
    return out


def vision(p: Array, v: Array, q: Array, u: Array, d_opt: float | DistanceTerm) -> float:
    """Eq. 3.4/3.8: vision of camera (p, v) over the landmark set (q, u)."""
    return float(per_landmark(p, v, q, u, d_opt).sum())


def gradients(
    p: Array, v: Array, q: Array, u: Array, d_opt: float | DistanceTerm
) -> tuple[Array, Array]:
    """Eq. 3.16 and 3.15: (∇_p vis, ∇_v vis), each (3,); ∇_v is ⟂ v (an angular-rate gradient)."""
    term = as_distance_term(d_opt)
    return gradients_of(visible_terms(p, v, Landmarks.of(q, u), term), v, term)


def gradients_of(t: VisibleTerms, v: Array, term: DistanceTerm) -> tuple[Array, Array]:
    """Eq. 3.16 and 3.15 from precomputed visible terms."""
    if t.r.size == 0:
        return np.zeros(3), np.zeros(3)
    # Eq. 3.16 expanded: Σ f̄'/r·⟨d,u⟩⟨d,v⟩·d + f̄·(⟨d,v⟩·u + ⟨d,u⟩·v), with ⟨d,u⟩ = −pu.
    c_d = term.fbar_prime(t.r) / t.r * (-t.pu) * t.dv
    grad_p = t.dT @ c_d + t.uT @ (t.fb * t.dv) - float(t.fb @ t.pu) * v
    # Eq. 3.12: vis = ⟨a, v⟩ with a = Σ f̄·⟨p−q, u⟩·(q−p); eq. 3.15: ∇_v = S(v)·a = v × a.
    a = t.dT @ (t.fb * t.pu)
    return grad_p, cross(v, a)


def coverage_score(
    poses_p: Array, poses_v: Array, q: Array, u: Array, owner: NDArray[np.intp],
    d_opt: float | DistanceTerm,
) -> float:
    """Eq. 3.10: Σ_i vis(p_i, v_i, Q_i), where ``owner[j]`` is the agent index owning landmark j."""
    total = 0.0
    for i in range(poses_p.shape[0]):  # loop over agents, not landmarks
        mine = owner == i
        if mine.any():
            total += vision(poses_p[i], poses_v[i], q[mine], u[mine], d_opt)
    return total


def unit(x: Array) -> Array:
    """x / ‖x‖ (the zero vector stays zero)."""
    n = float(np.sqrt(x @ x))
    return x / n if n > 0.0 else np.zeros_like(x)
