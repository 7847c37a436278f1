"""Camera orientation helpers: optimal orientation (section 3.4) and latitude-longitude
angles (section 2.3)."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from agent.core.vision import DistanceTerm, as_distance_term

Array = NDArray[np.float64]

#: Algorithm 1 enumerates 2^m subsets; refuse sets larger than this.
MAX_BRUTE_FORCE_LANDMARKS = 16


def optimal_orientation(p: Array, q: Array, u: Array, d_opt: float | DistanceTerm) -> Array:
    """Algorithm 1 (eq. 3.17): v_opt(p, Q) by trying every subset Q* of Q (exponential).

    Returns the zero vector when no orientation sees any landmark.
    """
    term = as_distance_term(d_opt)
    d = q - p
    r = np.linalg.norm(d, axis=1)
    pu = -np.einsum("ij,ij->i", d, u)  # ⟨p − q, u⟩
    cand = (pu > 0.0) & (r > 0.0)  # only these can ever be visible
    idx = np.flatnonzero(cand)
    if idx.size > MAX_BRUTE_FORCE_LANDMARKS:
        raise ValueError(
            f"Algorithm 1 is exponential: {idx.size} candidate landmarks exceed "
            f"{MAX_BRUTE_FORCE_LANDMARKS}"
        )
    if idx.size == 0:
        return np.zeros(3)
    s = (term.fbar(r[idx]) * pu[idx])[:, None] * d[idx]  # summands of eq. 3.17 (k, 3)
    k = idx.size
    subsets = ((np.arange(1, 2**k)[:, None] >> np.arange(k)[None, :]) & 1).astype(bool)
    a = subsets.astype(np.float64) @ s  # (2^k − 1, 3)
    n = np.linalg.norm(a, axis=1)
    ok = n > 0.0
    subsets, a, n = subsets[ok], a[ok], n[ok]
    v_star = a / n[:, None]
    seen = (v_star @ d[idx].T) > 0.0  # visibility of each candidate from each v*
    consistent = np.all(seen == subsets, axis=1)
    if not consistent.any():
        return np.zeros(3)
    values = np.where(consistent, n, -np.inf)  # vis(p, v*, Q*) = ⟨a, a/‖a‖⟩ = ‖a‖
    best: Array = v_star[int(np.argmax(values))]
    return best


def direction_from_angles(lat: float, lon: float) -> Array:
    """Eq. 2.3: unit vector from latitude θ and longitude ψ [rad]."""
    return np.array([np.cos(lat) * np.cos(lon), np.cos(lat) * np.sin(lon), np.sin(lat)])


def angles_from_direction(v: Array) -> tuple[float, float]:
    """Eq. 2.3 inverted: (θ, ψ) [rad] of a unit vector (ψ undefined at the poles: 0)."""
    lon = float(np.arctan2(v[1], v[0])) if abs(v[0]) + abs(v[1]) > 0 else 0.0
    lat = float(np.arctan2(v[2], np.hypot(v[0], v[1])))
    return lat, lon


def angle_rates(omega: Array, lat: float, lon: float) -> tuple[float, float]:
    """Eq. 2.4-2.5: (θ̇, ψ̇) [rad/s] of v = v(θ, ψ) under v̇ = ω × v (ω world, [rad/s]).

    θ̇ = sin ψ·ω₁ − cos ψ·ω₂ is eq. 2.5. Eq. 2.4 (ψ̇ = ω₃) is exact only at θ = 0; in general
    ψ̇ = ω₃ − tan θ·(cos ψ·ω₁ + sin ψ·ω₂), which is what this returns (undefined at the poles).
    """
    s, c = np.sin(lon), np.cos(lon)
    lat_rate = s * omega[0] - c * omega[1]
    lon_rate = omega[2] - np.tan(lat) * (c * omega[0] + s * omega[1])
    return float(lat_rate), float(lon_rate)


def turn_towards(v: Array, target: Array, max_angle: float) -> Array:
    """Unit camera direction v (3,) rotated towards unit ``target`` (3,) by at most
    ``max_angle`` [rad] (Rodrigues about v × target; about v × ẑ, or x̂, when the two are
    opposite); exactly ``target`` once within reach."""
    ang = float(np.arccos(np.clip(v @ target, -1.0, 1.0)))
    if ang <= max_angle:
        return np.asarray(target, dtype=np.float64).copy()
    axis = np.cross(v, target)
    if np.linalg.norm(axis) < 1e-12:
        axis = np.cross(v, np.array([0.0, 0.0, 1.0]))
        if np.linalg.norm(axis) < 1e-12:
            axis = np.cross(v, np.array([1.0, 0.0, 0.0]))
    axis = axis / np.linalg.norm(axis)
    c, s = np.cos(max_angle), np.sin(max_angle)
    out = v * c + np.cross(axis, v) * s + axis * float(axis @ v) * (1.0 - c)
    return np.asarray(out / np.linalg.norm(out), dtype=np.float64)
