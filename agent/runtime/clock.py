"""Mission clocks. ``now()`` is mission time [s]; ``sleep(dt)`` waits ``dt`` mission seconds.

:class:`WallClock` runs ``scale`` times faster than real time (``--rate-scale``);
:class:`ManualClock` is driven by tests (or follows a :class:`~agent.net.memory.MemoryNetwork`'s
virtual time through ``source``).
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from typing import Protocol, runtime_checkable


@runtime_checkable
class Clock(Protocol):
    """Mission time source."""

    def now(self) -> float:
        """Mission time [s]."""

    def sleep(self, dt: float) -> None:
        """Wait ``dt`` mission seconds (may return early if the clock is stopped)."""


class WallClock:
    """Monotonic wall time scaled by ``scale`` (> 0): mission seconds = scale × real seconds."""

    def __init__(self, scale: float = 1.0, stop: threading.Event | None = None) -> None:
        if not scale > 0.0:
            raise ValueError("clock scale must be > 0")
        self.scale = float(scale)
        self._t0 = time.monotonic()
        self._stop = stop if stop is not None else threading.Event()

    def now(self) -> float:
        return (time.monotonic() - self._t0) * self.scale

    def sleep(self, dt: float) -> None:
        if dt > 0.0:
            self._stop.wait(dt / self.scale)

    def wall(self, dt: float) -> float:
        """Real seconds corresponding to ``dt`` mission seconds."""
        return dt / self.scale


class ManualClock:
    """A clock that only moves when told: ``advance(dt)``/``sleep(dt)``, or follows
    ``source()`` (e.g. ``lambda: network.now``) when given."""

    #: Mission seconds per wall second (1: a manual clock has no wall-time relation).
    time_scale = 1.0

    def __init__(self, t0: float = 0.0, source: Callable[[], float] | None = None) -> None:
        self.t = float(t0)
        self._source = source

    def wall(self, dt: float) -> float:
        """Wall seconds for ``dt`` mission seconds (the same: nothing runs in wall time)."""
        return dt

    def now(self) -> float:
        return self._source() if self._source is not None else self.t

    def advance(self, dt: float) -> None:
        """Move forward ``dt`` seconds (ignored when following a source)."""
        self.t += dt

    def sleep(self, dt: float) -> None:
        self.advance(dt)
