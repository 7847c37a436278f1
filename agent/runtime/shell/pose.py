"""The pose-source contract: where an agent is and how it executes commanded velocities.

The runtime talks to a :class:`PoseSource`: it reads it into the
:class:`~agent.runtime.core.events.Fix` it steps into the core (:func:`fix_of`) and carries the
core's vehicle effects out on it (:func:`carry_out`). :class:`KinematicPoseSource` here integrates
eq. 5.1 exactly (a kinematic agent); a flown quadcopter is
:class:`agent.flight.vehicle_pose.MavlinkPoseSource` (mocap in, MAVLink set-points out).

Besides the contract a vehicle may say more, each asked only where it exists: ``hold(p, yaw)``
(figure 6.2), ``tilt_limits()`` (its gimbal's pitch range, :func:`tilt_limits_of`, a
constraint of the planner) and ``battery()`` (:func:`battery_of`, published in the agent's
state); a kinematic agent has none of them.
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import numpy as np
from numpy.typing import NDArray

from agent.clock import Clock
from agent.core.avoidance import MissionSpace
from agent.core.planner import integrate
from agent.core.tilt import TiltLimits
from agent.runtime.core.events import Command, Fix, Hold
from agent.runtime.core.vehicle import SettleTest
from agent.wire.peer import Battery

__all__ = ["KinematicPoseSource", "PoseSource", "SettleTest", "battery_of", "carry_out",
           "fix_of", "tilt_limits_of"]

Array = NDArray[np.float64]


@runtime_checkable
class PoseSource(Protocol):
    """Pose of one vehicle in the mission's world frame (ENU, metres)."""

    def current(self) -> tuple[Array, Array, float]:
        """(position p (3,) [m], unit camera direction v (3,), mission time t [s])."""

    def command(self, p_dot: Array, omega: Array, dt: float) -> None:
        """Execute linear velocity ``p_dot`` [m/s] and angular velocity ``omega`` [rad/s,
        world frame] for ``dt`` seconds (zero commands hold the pose)."""


class KinematicPoseSource:
    """Eq. 5.1: integrates its own commands exactly (the simulator's vehicle)."""

    def __init__(
        self, p0: Array, v0: Array, clock: Clock, space: MissionSpace | None = None
    ) -> None:
        self.p = np.asarray(p0, dtype=np.float64).copy()
        v = np.asarray(v0, dtype=np.float64)
        self.v = v / np.linalg.norm(v)
        self.clock = clock
        self.space = space

    def current(self) -> tuple[Array, Array, float]:
        return self.p.copy(), self.v.copy(), self.clock.now()

    def command(self, p_dot: Array, omega: Array, dt: float) -> None:
        if not (np.any(p_dot) or np.any(omega)):
            return
        p, v = integrate(self.p, self.v, p_dot, omega, dt)
        self.p = self.space.clip(p) if self.space is not None else p
        self.v = v


def tilt_limits_of(pose: object) -> TiltLimits | None:
    """The camera tilt limits [rad] of the vehicle behind ``pose`` (None: none, the thesis)."""
    fn = getattr(pose, "tilt_limits", None)
    lim = fn() if callable(fn) else None
    return lim if isinstance(lim, TiltLimits) else None


def battery_of(pose: object) -> Battery | None:
    """The battery of the vehicle behind ``pose`` (None: it has none, e.g. kinematic)."""
    fn = getattr(pose, "battery", None)
    b = fn() if callable(fn) else None
    return b if isinstance(b, Battery) else None


def fix_of(pose: PoseSource) -> Fix:
    """The vehicle behind ``pose`` now, as stepped into the core."""
    p, v, t = pose.current()
    return Fix(np.asarray(p, dtype=np.float64), np.asarray(v, dtype=np.float64), float(t),
               battery_of(pose), tilt_limits_of(pose))


def carry_out(pose: PoseSource, effect: Command | Hold) -> Fix | None:
    """Execute the core's vehicle ``effect`` on ``pose``: a :class:`Command` answered with the
    fix after it; a :class:`Hold` where the vehicle can hold (a kinematic one holds by
    itself)."""
    if isinstance(effect, Command):
        pose.command(effect.p_dot, effect.omega, effect.dt)
        return fix_of(pose)
    hold = getattr(pose, "hold", None)
    if callable(hold):
        hold(effect.p, effect.yaw)
    return None
