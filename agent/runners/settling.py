"""Convergence of a flown vehicle: the :class:`~agent.runtime.core.vehicle.SettleTest` that
tolerates a real vehicle's limit cycle around the optimum (see :class:`Settling`)."""

from __future__ import annotations

import math
from typing import Any

import numpy as np


class Settling:
    """Convergence test (:class:`agent.runtime.core.vehicle.SettleTest`) tolerating a real vehicle.

    Section 4.4 declares convergence when the line search accepts no step at all. A flown
    vehicle never sits exactly on the optimum: each step is a velocity held for Δt, the vehicle
    answers it with a lag, overshoots by centimetres, and the planner sends it back: a limit
    cycle of a few centimetres around the optimum (about ±5 cm at 0.3 m/s with the default
    controllers) in which the line search always finds an improving step, so the agent would
    never stop optimising and never trade. Here the agent also counts as converged once its
    measured pose has *settled*: over the last ``window_s`` seconds every position lay within
    ``radius`` [m] of their mean and every camera direction within ``angle`` [rad] of theirs.
    The runtime then holds the mean position and direction (figure 6.2), the centre of the
    cycle, i.e. the optimum up to the cycle's asymmetry.
    """

    def __init__(self, window_s: float = 2.0, radius: float = 0.1, angle: float = 0.05) -> None:
        self.window_s, self.radius, self.angle = window_s, radius, angle
        self.hist: list[tuple[float, Any, Any]] = []
        self.settled = 0  #: convergences declared by this test (not by section 4.4)

    def reset(self) -> None:
        """The planner converged by itself: start a new window."""
        self.hist.clear()

    def update(self, t: float, p: Any, v: Any) -> tuple[Any, Any] | None:
        """Record the measured pose at mission time t [s]; (mean p, mean v) once settled."""
        self.hist.append((float(t), np.asarray(p, dtype=np.float64).copy(),
                          np.asarray(v, dtype=np.float64).copy()))
        t0 = self.hist[-1][0] - self.window_s
        if self.hist[0][0] > t0:
            return None
        self.hist = [h for h in self.hist if h[0] >= t0 - 1e-9]
        ps = np.array([h[1] for h in self.hist])
        vs = np.array([h[2] for h in self.hist])
        pm, vm = ps.mean(axis=0), vs.mean(axis=0)
        vm = vm / np.linalg.norm(vm)
        if np.max(np.linalg.norm(ps - pm, axis=1)) > self.radius:
            return None
        if np.min(vs @ vm) < math.cos(self.angle):
            return None
        self.hist.clear()
        self.settled += 1
        return pm, vm
