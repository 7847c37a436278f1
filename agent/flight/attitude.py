"""Force to attitude (thesis section 6.1, figure 6.1): the desired force F* and the yaw become
the quadcopter's inputs, normalised thrust T*, roll α*, pitch β* (and the yaw rate γ̇*).

Construction (PX4's, in NED/FRD): the body z axis points against the thrust,
z_B = −F/‖F‖; the heading direction y_C = (−sin ψ, cos ψ, 0); x_B = normalise(y_C × z_B);
y_B = z_B × x_B; R = [x_B y_B z_B] (R_NED←FRD). The ZYX yaw of R equals ψ exactly.
Thrust: T = hover_thrust · ‖F‖ / (m g) (a linear thrust curve through the hover point).
Before the construction the force is limited: the upward component to at least the minimum
thrust, the horizontal component to the tilt limit (vertical has priority, as in PX4), and
the magnitude to the thrust limits.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import ArrayLike, NDArray

from agent.flight.frames import enu_to_ned, euler_from_matrix, quat_from_matrix, yaw_enu_to_ned

Array = NDArray[np.float64]

G = 9.81  #: gravity [m/s²]


@dataclass(frozen=True)
class ThrustModel:
    """Vehicle constants for section 6.1: mass [kg], g [m/s²], normalised hover thrust and
    thrust limits (0..1), tilt limit [rad]."""

    mass: float = 1.5
    g: float = G
    hover_thrust: float = 0.5
    thrust_min: float = 0.08
    thrust_max: float = 0.9
    tilt_max: float = math.radians(35.0)

    def __post_init__(self) -> None:
        if not (self.mass > 0 and self.g > 0 and 0 < self.hover_thrust < 1):
            raise ValueError("mass, g must be > 0 and hover_thrust in (0, 1)")
        if not 0 <= self.thrust_min < self.hover_thrust < self.thrust_max <= 1:
            raise ValueError("need 0 <= thrust_min < hover_thrust < thrust_max <= 1")
        if not 0 < self.tilt_max < math.pi / 2:
            raise ValueError("tilt_max must be in (0, π/2) rad")

    @property
    def weight(self) -> float:
        """m g [N]."""
        return self.mass * self.g

    def force_of(self, thrust: float) -> float:
        """Force magnitude [N] produced by normalised thrust T: ‖F‖ = T m g / T_hover."""
        return thrust * self.weight / self.hover_thrust

    def thrust_of(self, force: float) -> float:
        """Normalised thrust (unclamped) for a force magnitude [N]: T = T_hover ‖F‖ / (m g)."""
        return self.hover_thrust * force / self.weight

    def with_hover_thrust(self, hover_thrust: float) -> ThrustModel:
        """The same model with another hover thrust (e.g. an online estimate, which changes at
        run time), kept 1e-3 inside (thrust_min, thrust_max) so the model stays valid."""
        if not math.isfinite(hover_thrust):
            raise ValueError("hover_thrust must be finite")
        lo, hi = self.thrust_min + 1e-3, self.thrust_max - 1e-3
        return replace(self, hover_thrust=min(max(hover_thrust, lo), hi))


@dataclass(frozen=True)
class AttitudeCommand:
    """Section 6.1 output: normalised thrust, NED ZYX angles [rad], q = R_NED←FRD (w, x, y, z)
    and the force actually realised after limiting [N, NED]."""

    thrust: float
    roll: float
    pitch: float
    yaw: float
    q: Array
    force_ned: Array = field(repr=False)


def limit_force_ned(force_ned: ArrayLike, model: ThrustModel) -> Array:
    """Section 6.1 limits on F* [N, NED]: upward part ≥ minimum thrust, tilt ≤ tilt_max
    (horizontal part scaled, vertical kept), ‖F‖ within the thrust limits."""
    f = np.asarray(force_ned, dtype=np.float64).copy()
    up_min = model.force_of(model.thrust_min) * math.cos(model.tilt_max)
    up = max(-f[2], up_min, 1e-6)
    h = math.hypot(f[0], f[1])
    h_max = up * math.tan(model.tilt_max)
    if h > h_max:
        f[0:2] *= h_max / h
    f[2] = -up
    n = float(np.linalg.norm(f))
    n_lo, n_hi = model.force_of(model.thrust_min), model.force_of(model.thrust_max)
    if n > n_hi:
        f *= n_hi / n
    elif n < n_lo:
        f *= n_lo / n
    return f


def force_to_attitude_ned(
    force_ned: ArrayLike, yaw_ned: float, model: ThrustModel
) -> AttitudeCommand:
    """Section 6.1 (PX4 construction): F* [N, NED] and heading ψ [rad, NED] → thrust (0..1),
    roll, pitch, yaw [rad] and q = R_NED←FRD, after :func:`limit_force_ned`."""
    f = np.asarray(force_ned, dtype=np.float64)
    if f.shape != (3,) or not np.all(np.isfinite(f)) or not math.isfinite(yaw_ned):
        raise ValueError("force_to_attitude needs a finite 3-vector force and a finite yaw")
    f = limit_force_ned(f, model)
    z_b = -f / np.linalg.norm(f)
    y_c = np.array([-math.sin(yaw_ned), math.cos(yaw_ned), 0.0])
    x_b = np.cross(y_c, z_b)
    x_b /= np.linalg.norm(x_b)  # never degenerate: the tilt limit keeps z_B off horizontal
    y_b = np.cross(z_b, x_b)
    r = np.column_stack([x_b, y_b, z_b])
    roll, pitch, yaw = euler_from_matrix(r)
    thrust = min(max(model.thrust_of(float(np.linalg.norm(f))), model.thrust_min),
                 model.thrust_max)
    return AttitudeCommand(thrust, roll, pitch, yaw, quat_from_matrix(r), f)


def force_to_attitude(force_enu: ArrayLike, yaw_enu: float, model: ThrustModel) -> AttitudeCommand:
    """Section 6.1 in mission frames: F* [N, world ENU] and yaw ψ [rad, ENU] → the NED/FRD
    command of :func:`force_to_attitude_ned` (what SET_ATTITUDE_TARGET carries)."""
    return force_to_attitude_ned(enu_to_ned(force_enu), yaw_enu_to_ned(yaw_enu), model)


def level_attitude(
    yaw_ned: float, model: ThrustModel, thrust: float | None = None
) -> AttitudeCommand:
    """Failsafe set-point: level (roll = pitch = 0) at heading ψ [rad, NED] and hover thrust
    (or ``thrust``, 0..1)."""
    t = model.hover_thrust if thrust is None else thrust
    cmd = force_to_attitude_ned(np.array([0.0, 0.0, -model.force_of(t)]), yaw_ned, model)
    return AttitudeCommand(t, 0.0, 0.0, cmd.yaw, cmd.q, cmd.force_ned)
