"""The agent core's view of its vehicle: the last :class:`~agent.runtime.core.events.Fix` stepped in
(with :class:`~agent.runtime.core.events.Start`, :class:`~agent.runtime.core.events.Tick`, and as
the
answer to each :class:`~agent.runtime.core.events.Command`), and the vehicle's actions as effects.
The vehicle itself (a kinematic one, or a flown quadcopter behind MAVLink) is the runtime's
(:mod:`agent.runtime.shell.pose`); nothing here reads a clock or talks to a vehicle.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Protocol

import numpy as np
from numpy.typing import NDArray

from agent.core.tilt import TiltLimits
from agent.runtime.core.events import Asking, Fix, Hold, Trigger, command
from agent.wire.peer import Battery

Array = NDArray[np.float64]


class SettleTest(Protocol):
    """A second convergence test for vehicles that never sit exactly on the optimum.

    ``update`` sees every measured pose while the planner still moves; it returns the pose to
    hold (mean position [m; world ENU], unit camera direction) once the vehicle counts as
    settled, else None. ``reset`` is called when the planner itself declares convergence
    (section 4.4).
    """

    def update(self, t: float, p: Array, v: Array) -> tuple[Array, Array] | None: ...

    def reset(self) -> None: ...


class VehicleView:
    """Where the core's vehicle is, as last stepped in, and what it is told.

    Args:
        fix: the vehicle before the first event (the journal's last pose, or the start).
        act: queues an action effect (after the records queued before it).
    """

    def __init__(self, fix: Fix, act: Callable[[Hold | Trigger], None]) -> None:
        self.fix = fix
        self._act = act

    def current(self) -> tuple[Array, Array, float]:
        """(position p (3,) [m; world ENU], unit camera direction v (3,), mission time t
        [s]) of the last fix (copies)."""
        f = self.fix
        return f.p.copy(), f.v.copy(), f.t

    def command(self, p_dot: Array, omega: Array, dt: float) -> Asking[None]:
        """Eq. 5.1's command: fly ``p_dot`` [m/s; world ENU] and turn ``omega`` [rad/s;
        world ENU] for ``dt`` [s] (a :class:`~agent.runtime.core.events.Command`); the fix after
        it is the view's."""
        got = yield from command(np.asarray(p_dot, dtype=np.float64),
                                 np.asarray(omega, dtype=np.float64), float(dt))
        if got is not None:
            self.fix = got

    def hold(self, p: Array, yaw: float) -> None:
        """Figure 6.2: hold position ``p`` [m; world ENU] and camera yaw ``yaw`` [rad]."""
        self._act(Hold(np.asarray(p, dtype=np.float64).copy(), float(yaw)))

    def trigger(self, ids: list[int]) -> None:
        """One image for the capture of ``ids`` (its record queued before)."""
        self._act(Trigger(tuple(int(i) for i in ids)))

    def tilt_limits(self) -> TiltLimits | None:
        """The camera tilt limits [rad] of the vehicle (None: the thesis' free camera)."""
        return self.fix.tilt

    def battery(self) -> Battery | None:
        """The vehicle's battery as last read (None: it has none, e.g. kinematic)."""
        return self.fix.battery
