"""The one clock contract of viscover, and the two local clocks.

Every process reads time through a :class:`Clock`: agents, the ground station, the MAVLink
driver, simulators and tests. ``now()`` is mission time [s]; ``time_scale`` is mission seconds
per wall second (a simulation may run faster than real time); ``wall(dt)`` converts a mission
duration to the wall seconds a thread should wait; ``sleep(dt)`` waits ``dt`` mission seconds.

* :class:`WallClock`: the monotonic clock scaled by ``time_scale``; the master of a simulated
  mission (the ground station publishes it) and the clock of a kinematic agent.
* :class:`ManualClock`: moves only when told (tests, in-memory simulations).
* The clock followed over the network (``viscover/<m>/clock``) is
  :class:`agent.net.clocksync.RemoteClock`; the simulated fleet's physics clock is
  :class:`groundstation.vehicle.fleet.FleetClock`. Both satisfy :class:`Clock`.

This module has no dependencies inside viscover.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from typing import Protocol, runtime_checkable


@runtime_checkable
class Clock(Protocol):
    """Mission time source: ``now()`` [s], ``time_scale`` [mission s / wall s]."""

    @property
    def time_scale(self) -> float:
        """Mission seconds per wall second (> 0)."""
        ...

    def now(self) -> float:
        """Mission time [s]."""
        ...

    def wall(self, dt: float) -> float:
        """Wall seconds that ``dt`` mission seconds take (0 for dt ≤ 0)."""
        ...

    def sleep(self, dt: float) -> None:
        """Wait ``dt`` mission seconds (may return early if the clock is stopped)."""
        ...


class WallClock:
    """Monotonic time scaled by ``time_scale``: now = t0 + time_scale · (monotonic − m0).

    ``stop`` (optional) ends every :meth:`sleep` early when set, so a process that sleeps in
    mission time still stops at once on SIGINT/SIGTERM.
    """

    def __init__(self, time_scale: float = 1.0, stop: threading.Event | None = None,
                 t0: float = 0.0) -> None:
        if not time_scale > 0.0:
            raise ValueError(f"time scale must be > 0, got {time_scale}")
        self._scale = float(time_scale)
        self._t0 = float(t0)
        self._m0 = time.monotonic()
        self._stop = stop if stop is not None else threading.Event()

    @property
    def time_scale(self) -> float:
        """Mission seconds per wall second."""
        return self._scale

    def now(self) -> float:
        """Mission time [s]."""
        return self._t0 + (time.monotonic() - self._m0) * self._scale

    def slip(self, dt: float) -> None:
        """Hold mission time back by ``dt`` [s] (time dilation: a simulator that could not
        keep up makes time wait for it instead of jumping)."""
        if dt > 0.0:
            self._t0 -= dt

    def wall(self, dt: float) -> float:
        """Wall seconds of ``dt`` mission seconds."""
        return max(0.0, dt) / self._scale

    def sleep(self, dt: float) -> None:
        """Wait ``dt`` mission seconds, or until ``stop`` is set."""
        if dt > 0.0:
            self._stop.wait(self.wall(dt))


class ManualClock:
    """A clock that only moves when told: :meth:`advance` / :meth:`sleep`, or that follows
    ``source()`` (e.g. ``lambda: network.now`` of an in-memory network) when given.

    Nothing runs in wall time under it: ``wall(dt)`` is ``dt``, ``time_scale`` is 1.
    """

    time_scale = 1.0

    def __init__(self, t0: float = 0.0, source: Callable[[], float] | None = None) -> None:
        self.t = float(t0)
        self._source = source

    def now(self) -> float:
        """Mission time [s]: the source's, or the last advanced-to time."""
        return self._source() if self._source is not None else self.t

    def advance(self, dt: float) -> None:
        """Move forward ``dt`` seconds (ignored when following a source)."""
        self.t += dt

    def wall(self, dt: float) -> float:
        """Wall seconds for ``dt`` mission seconds: the same number."""
        return max(0.0, dt)

    def sleep(self, dt: float) -> None:
        """Advance by ``dt`` at once."""
        self.advance(dt)
