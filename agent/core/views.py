"""View sectors: each landmark imaged from k directions a parallax angle apart (beyond the
thesis, which images each landmark once).

Photogrammetry needs each surface point in several images taken from different directions.
The requirement "landmark j is in k images whose viewing directions (landmark → camera)
differ pairwise by at least θ" is reduced here to k ordinary captures: landmark j is replaced
by k *view landmarks* (same position and normal, :mod:`agent.world.views`), view s of which
is captured only by an image whose viewing direction lies in *sector* s, a cone around a
fixed axis. The sectors are far enough apart that any two images in two different sectors
differ by θ, so capturing all k view landmarks once each is k images pairwise θ apart; the
capture table, set cover, tours, trades and captured sets work on view landmarks unchanged.

Geometry. For a landmark with unit normal u take the horizontal unit e1 = u × ẑ / |u × ẑ|
(x̂ when u is vertical) and e2 = u × e1, so (e1, e2, u) is right-handed and orthonormal.
Sector s of k (s = 0 … k − 1) has the unit axis

    a_s = cos τ · u + sin τ · (cos φ_s · e1 + sin φ_s · e2),   φ_s = 2πs / k,

tilted τ off the normal, and the cone of half-angle ρ around it: a unit viewing direction w
(from the landmark to the camera) is in sector s when ⟨w, a_s⟩ ≥ cos ρ.

Guarantee. Two axes a_s, a_t lie on the circle of polar angle τ around u, their azimuths
2π|s − t|/k apart; the chord between them is 2 sin τ · sin(π|s − t|/k), smallest for
adjacent sectors, so any two axes are at least δ(τ) = 2·asin(sin τ · sin(π/k)) apart. For
w in sector s and w' in sector t ≠ s the triangle inequality of angles on the sphere gives
∠(w, w') ≥ ∠(a_s, a_t) − ∠(w, a_s) − ∠(w', a_t) ≥ δ(τ) − 2ρ. Every w in a sector is at
most τ + ρ off the normal. So with

    δ(τ) − 2ρ ≥ θ   and   τ + ρ ≤ β   (β the largest incidence, 75° when none is given)

the sectors are disjoint (one image captures at most one view of a landmark), two images
in different sectors differ by at least θ, and every image in a sector meets the incidence
limit. :func:`sector_cone` takes the largest ρ meeting both, the maximum over τ of
ρ(τ) = min((δ(τ) − θ)/2, β − τ): the first term grows with τ and the second shrinks, so it is
where they meet (found by bisection); a ρ below :data:`MIN_CONE` is refused (the sectors
would be too narrow to fly to), and :func:`sector_fit` says which parallax or incidence would
fit.

The reduction is sufficient, not necessary: k images pairwise θ apart that do not fall in
the k sectors do not count. Pure numpy; angles [rad]; vectors in the world frame (ENU).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

Array = NDArray[np.float64]
Mask = NDArray[np.bool_]

#: Most views per landmark.
MAX_VIEWS = 6
#: The narrowest sector cone accepted (half-angle) [rad].
MIN_CONE = math.radians(5.0)
#: The largest incidence the sectors keep to when the inspection sets none [rad].
DEFAULT_INCIDENCE = math.radians(75.0)
#: Bisection steps of :func:`sector_cone` (τ to well under 1e-12 rad).
BISECTIONS = 60


@dataclass(frozen=True)
class SectorCone:
    """The sectors of ``views`` = k views ``parallax`` = θ apart [rad]: their axes are tilted
    ``tilt`` = τ off the normal, their cones have the half-angle ``half`` = ρ [rad]."""

    views: int
    parallax: float
    tilt: float
    half: float

    @property
    def cos(self) -> float:
        """cos ρ: w is in a sector when ⟨w, axis⟩ ≥ this."""
        return math.cos(self.half)

    @property
    def separation(self) -> float:
        """The least angle between two directions in different sectors, δ(τ) − 2ρ [rad]."""
        return float(axis_separation(self.views, self.tilt)) - 2.0 * self.half


def axis_separation(views: int, tilt: float | Array) -> Array:
    """δ(τ) = 2·asin(sin τ · sin(π/k)): the least angle between two sector axes [rad]."""
    return np.asarray(2.0 * np.arcsin(np.sin(tilt) * math.sin(math.pi / views)))


def sector_cone(views: int, parallax: float, max_incidence: float | None = None
                ) -> SectorCone | None:
    """The widest sectors of ``views`` ≥ 2 views pairwise at least ``parallax`` apart within
    the incidence limit (``max_incidence``, else :data:`DEFAULT_INCIDENCE`) [rad]; None when
    their cones would be narrower than :data:`MIN_CONE`."""
    beta = DEFAULT_INCIDENCE if max_incidence is None else max_incidence

    def rho(tau: float) -> tuple[float, float]:  # both bounds on ρ at this tilt
        return (float(axis_separation(views, tau)) - parallax) / 2.0, beta - tau

    lo, hi = 0.0, beta  # the first bound is below the second at lo, not below it at hi
    for _ in range(BISECTIONS):
        mid = 0.5 * (lo + hi)
        sep, inc = rho(mid)
        lo, hi = (mid, hi) if sep < inc else (lo, mid)
    half = min(rho(lo)) - 1e-12  # both bounds hold, with a hair to spare for rounding
    if not half >= MIN_CONE:
        return None
    return SectorCone(views, parallax, lo, half)


def sector_fit(views: int, parallax: float, max_incidence: float | None = None
               ) -> tuple[float, float | None]:
    """What would leave cones of :data:`MIN_CONE`: the largest parallax at this incidence
    limit, and the smallest incidence limit (None: none up to 90°) at this parallax [rad].

    δ(τ) grows with τ, so the largest parallax is δ(β − ρ) − 2ρ at ρ = MIN_CONE, and the
    smallest incidence τ + ρ with δ(τ) = θ + 2ρ, i.e. sin τ = sin(θ/2 + ρ) / sin(π/k)."""
    beta = DEFAULT_INCIDENCE if max_incidence is None else max_incidence
    rho = MIN_CONE
    largest = float(axis_separation(views, max(0.0, beta - rho))) - 2.0 * rho
    s = math.sin(parallax / 2.0 + rho) / math.sin(math.pi / views)
    if s > 1.0:
        return largest, None
    smallest = math.asin(s) + rho
    return largest, (smallest if smallest <= math.pi / 2 else None)


def sector_basis(u: Array) -> tuple[Array, Array]:
    """(e1, e2) (m, 3) for unit normals u (m, 3): e1 = u × ẑ normalised (x̂ when u is
    vertical), e2 = u × e1."""
    e1 = np.cross(u, np.array([0.0, 0.0, 1.0]))
    n = np.linalg.norm(e1, axis=1)
    flat = n < 1e-9
    e1 = np.where(flat[:, None], np.array([1.0, 0.0, 0.0]),
                  e1 / np.where(flat, 1.0, n)[:, None])
    return e1, np.cross(u, e1)


def sector_axes(u: Array, views: int, tilt: float) -> Array:
    """The unit axes a_s (m, k, 3) of the k = ``views`` sectors of each landmark with unit
    normal u (m, 3), tilted ``tilt`` = τ [rad] off it (see the module docstring)."""
    e1, e2 = sector_basis(u)
    phi = 2.0 * np.pi * np.arange(views) / views
    ring = (np.cos(phi)[None, :, None] * e1[:, None, :]
            + np.sin(phi)[None, :, None] * e2[:, None, :])
    out = math.cos(tilt) * u[:, None, :] + math.sin(tilt) * ring
    return np.asarray(out / np.linalg.norm(out, axis=2, keepdims=True), dtype=np.float64)


def in_sector(w: Array, axis: Array, cos_cone: float) -> Mask:
    """Unit viewing directions w (…, 3) (landmark → camera) inside the cones of half-angle
    acos(``cos_cone``) around the unit ``axis`` (…, 3) (broadcast)."""
    return np.asarray((w * axis).sum(axis=-1) >= cos_cone, dtype=np.bool_)
