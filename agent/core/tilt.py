"""Camera tilt limits (a gimbal's pitch range) as a constraint of the planner's angular step.

The tilt is the latitude θ of eq. 2.3 (v_z = sin θ, world ENU); a gimbal holds it within
[θ_lo, θ_hi] [rad] (the thesis has no limit: θ ∈ [−π/2, π/2]). Pose optimisation then
ascends the vision by projected gradient with an active set (figure 4.1, section 4.4):

* direction: at a limit (θ within :data:`ACTIVE_RAD` of it) the component of the angular
  gradient ∇_v vis (eq. 3.15, an angular rate [rad/s; world]) that would tilt the camera
  further out is removed (:meth:`TiltLimits.project`); ω̂ · (v × ẑ) is the rate of v_z, so
  the removed part is the one along the unit pitch axis v × ẑ / ‖v × ẑ‖;
* magnitude: Algorithm 6's candidates v_k = (v + α_k (ω̂ × v)) / ‖·‖ (the integrator of
  eq. 5.1) follow a great circle; those past the first point where it crosses a limit are
  dropped and that point added as a candidate (:meth:`TiltLimits.max_step`), as the linear
  step is cut at a wall. Every accepted camera direction is within the limits.

A camera already outside the limits (a measured tilt a little past them) may only move
back: its own tilt widens the interval on that side. Angles [rad], directions unit vectors
[world ENU].
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

Array = NDArray[np.float64]

#: A camera this close to a limit [rad of tilt] counts as on it (the active set).
ACTIVE_RAD = 1e-9
_HALF_PI = math.pi / 2


@dataclass(frozen=True)
class TiltLimits:
    """The camera tilt θ (eq. 2.3 latitude) allowed: ``lo`` ≤ θ ≤ ``hi`` [rad], each within
    [−π/2, π/2] (±π/2: no limit on that side)."""

    lo: float = -_HALF_PI
    hi: float = _HALF_PI

    def __post_init__(self) -> None:
        if not (math.isfinite(self.lo) and math.isfinite(self.hi)
                and -_HALF_PI <= self.lo <= self.hi <= _HALF_PI):
            raise ValueError(f"tilt limits must satisfy -pi/2 <= lo <= hi <= pi/2 [rad], got "
                             f"lo={self.lo}, hi={self.hi}")

    @staticmethod
    def of(lo: float, hi: float) -> TiltLimits:
        """Limits [rad] clipped to [−π/2, π/2] (a gimbal may report −90° a little past it)."""
        return TiltLimits(min(max(lo, -_HALF_PI), _HALF_PI), min(max(hi, -_HALF_PI), _HALF_PI))

    def bounds_z(self, v: Array) -> tuple[float, float]:
        """The interval of v_z = sin θ a step from unit ``v`` may reach: [sin lo, sin hi],
        widened to v_z itself on a side v is already past; ±inf on a side without a limit."""
        z = float(v[2])
        lo = -math.inf if self.lo <= -_HALF_PI else min(math.sin(self.lo), z)
        hi = math.inf if self.hi >= _HALF_PI else max(math.sin(self.hi), z)
        return lo, hi

    def clamp(self, theta: float) -> float:
        """Tilt θ [rad] within [lo, hi]."""
        return min(max(theta, self.lo), self.hi)

    def clamp_direction(self, v: Array) -> Array:
        """Unit direction ``v`` with its tilt held within the limits, its heading ψ (eq. 2.3
        longitude) kept."""
        theta = math.asin(min(max(float(v[2]), -1.0), 1.0))
        th = self.clamp(theta)
        if th == theta:
            return np.asarray(v, dtype=np.float64).copy()
        h = float(math.hypot(v[0], v[1]))
        cx, cy = (v[0] / h, v[1] / h) if h > 0.0 else (1.0, 0.0)
        return np.array([math.cos(th) * cx, math.cos(th) * cy, math.sin(th)])

    def active(self, v: Array) -> tuple[bool, bool]:
        """Whether unit ``v`` is on (or past) the lower and the upper limit."""
        theta = math.asin(min(max(float(v[2]), -1.0), 1.0))
        return (self.lo > -_HALF_PI and theta <= self.lo + ACTIVE_RAD,
                self.hi < _HALF_PI and theta >= self.hi - ACTIVE_RAD)

    def project(self, v: Array, grad_v: Array) -> Array:
        """The angular gradient ``grad_v`` (eq. 3.15, ⟂ v) less its outward pitch component
        on an active limit: the projected gradient of the constrained problem."""
        axis = np.array([v[1], -v[0], 0.0])  # v × ẑ: ⟨ω, v × ẑ⟩ is the rate of v_z
        n = float(np.linalg.norm(axis))
        if n == 0.0:  # at a pole: a limit there is ±π/2, i.e. none
            return np.asarray(grad_v, dtype=np.float64).copy()
        axis /= n
        rate = float(grad_v @ axis)
        at_lo, at_hi = self.active(v)
        if (at_hi and rate > 0.0) or (at_lo and rate < 0.0):
            return np.asarray(grad_v - rate * axis, dtype=np.float64)
        return np.asarray(grad_v, dtype=np.float64).copy()

    def max_step(self, v: Array, c: Array) -> float:
        """The largest α ≥ 0 for which every direction (v + a·c)/‖v + a·c‖, 0 ≤ a ≤ α, is
        within :meth:`bounds_z` (c ⟂ v, e.g. ω̂ × v); inf when the great circle never leaves
        them within a quarter turn."""
        cn = float(np.linalg.norm(c))
        if cn == 0.0:
            return math.inf
        lo, hi = self.bounds_z(v)
        z, cz = float(v[2]), float(c[2]) / cn
        # Along the great circle at angle φ (tan φ = α‖c‖): v_z(φ) = z cos φ + cz sin φ.
        phi = min(_first_crossing(z, cz, hi), _first_crossing(-z, -cz, -lo))
        return math.inf if phi >= _HALF_PI else math.tan(phi) / cn


def _first_crossing(a: float, b: float, s: float) -> float:
    """The smallest φ ∈ [0, π/2) with a cos φ + b sin φ > s, given a ≤ s (π/2 if none; s may
    be inf)."""
    amp = math.hypot(a, b)
    if not s < amp:
        return _HALF_PI
    phi0, delta = math.atan2(b, a), math.acos(s / amp)  # above s on (φ0 − δ, φ0 + δ)
    phi = phi0 - delta
    if phi < 0.0:  # rounding at φ = 0 while rising (a = s), else the entry of the next turn
        phi = 0.0 if b > 0.0 else phi + 2.0 * math.pi
    return min(phi, _HALF_PI)
