"""The shared simulation clock (like ROS's /clock): simulation seconds that may run faster
than real time.

* :class:`ScaledClock` is the master: t_sim = t0 + time_scale · (monotonic − m0).
* :class:`ClockPublisher` publishes :class:`ClockMsg` on the mission's clock key at a fixed
  wall rate (the ground station runs one).
* :class:`RemoteClock` follows those messages in another process and extrapolates between
  them with the announced time scale, so every process sleeps and times out in simulation
  seconds.

Every clock has ``now()`` [s sim], ``time_scale`` (sim s per wall s) and ``sleep(dt)`` /
``wall(dt)`` converting simulation durations to wall durations.
"""

from __future__ import annotations

import logging
import threading
import time
from typing import Protocol, runtime_checkable

import msgspec

from agent.net import keys
from agent.net.codec import Codec
from agent.net.transport import Declared, Transport

_log = logging.getLogger(__name__)


@runtime_checkable
class Clock(Protocol):
    """Simulation time source: ``now()`` [s], ``time_scale`` [sim s / wall s]."""

    time_scale: float

    def now(self) -> float:
        """Current simulation time [s]."""

    def sleep(self, dt: float) -> None:
        """Sleep ``dt`` simulation seconds."""

    def wall(self, dt: float) -> float:
        """Wall seconds that ``dt`` simulation seconds take."""


class ScaledClock:
    """Master clock: simulation time runs ``time_scale`` times faster than the monotonic clock."""

    def __init__(self, time_scale: float = 1.0, t0: float = 0.0) -> None:
        if not time_scale > 0:
            raise ValueError(f"time scale must be > 0, got {time_scale}")
        self.time_scale = float(time_scale)
        self.scale = self.time_scale  # the name agent.runtime.clock uses
        self._t0 = float(t0)
        self._m0 = time.monotonic()

    def now(self) -> float:
        """Simulation time [s]."""
        return self._t0 + (time.monotonic() - self._m0) * self.time_scale

    def slip(self, dt: float) -> None:
        """Hold simulation time back by ``dt`` [s] (time dilation: the simulator could not
        keep up, so simulated time waits for it instead of jumping)."""
        if dt > 0:
            self._t0 -= dt

    def wall(self, dt: float) -> float:
        """Wall seconds of ``dt`` simulation seconds."""
        return max(0.0, dt) / self.time_scale

    def sleep(self, dt: float) -> None:
        """Sleep ``dt`` simulation seconds."""
        time.sleep(self.wall(dt))


class ClockMsg(msgspec.Struct, kw_only=True):
    """Wire message on ``viscover/<m>/clock``: simulation time [s], time scale, sequence."""

    t: float
    time_scale: float
    seq: int = 0
    schema: int = 1


CLOCK_CODEC: Codec[ClockMsg] = Codec(ClockMsg)


class ClockPublisher:
    """Publishes ``clock`` on the mission's clock key every ``period_s`` wall seconds (thread)."""

    def __init__(self, transport: Transport, mission: str, clock: Clock,
                 period_s: float = 0.05) -> None:
        self.transport, self.clock, self.period_s = transport, clock, period_s
        self.key = keys.clock_key(mission)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="clock-pub", daemon=True)
        self.seq = 0

    def start(self) -> ClockPublisher:
        """Start publishing."""
        self._thread.start()
        return self

    def publish_once(self) -> None:
        """Publish the current time now."""
        self.seq += 1
        msg = ClockMsg(t=self.clock.now(), time_scale=self.clock.time_scale, seq=self.seq)
        self.transport.publish(self.key, CLOCK_CODEC.encode(msg), kind="clock")

    def _run(self) -> None:
        while not self._stop.wait(self.period_s):
            try:
                self.publish_once()
            except RuntimeError:  # transport closed under us
                return

    def stop(self) -> None:
        """Stop and join the thread."""
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(2.0)


class RemoteClock:
    """Follows a :class:`ClockPublisher`: ``now()`` = last t + scale · wall time since it came,
    extrapolated for at most ``max_extrapolate_s`` wall seconds (a stalled or dilated master
    stalls its followers too) and never going backwards.

    Before the first message ``now()`` raises RuntimeError; use :meth:`wait_synced`.
    """

    def __init__(self, transport: Transport, mission: str,
                 max_extrapolate_s: float = 0.25) -> None:
        self.max_extrapolate_s = max_extrapolate_s
        self._last_now = -float("inf")
        self._lock = threading.Lock()
        self._t = 0.0
        self._m = 0.0
        self.time_scale = 1.0
        self._synced = threading.Event()
        self._seq = -1
        self._sub: Declared = transport.subscribe(keys.clock_key(mission), self._on_msg)

    def _on_msg(self, key: str, payload: bytes) -> None:
        msg = CLOCK_CODEC.decode(payload, key)
        if msg is None or msg.time_scale <= 0:
            return
        with self._lock:
            if msg.seq <= self._seq and self._synced.is_set():
                return  # stale or duplicated
            self._seq, self._t, self._m = msg.seq, msg.t, time.monotonic()
            self.time_scale = msg.time_scale
        self._synced.set()

    @property
    def scale(self) -> float:
        """The time scale under the name ``agent.runtime.clock`` uses."""
        return self.time_scale

    def wait_synced(self, timeout_s: float) -> bool:
        """Wait (wall seconds) for the first clock message; True once synced."""
        return self._synced.wait(timeout_s)

    def now(self) -> float:
        """Simulation time [s] extrapolated from the last message."""
        if not self._synced.is_set():
            raise RuntimeError("no clock message received yet")
        with self._lock:
            ahead = min(time.monotonic() - self._m, self.max_extrapolate_s) * self.time_scale
            self._last_now = max(self._last_now, self._t + ahead)
            return self._last_now

    def wall(self, dt: float) -> float:
        """Wall seconds of ``dt`` simulation seconds at the current scale."""
        return max(0.0, dt) / self.time_scale

    def sleep(self, dt: float) -> None:
        """Sleep ``dt`` simulation seconds."""
        time.sleep(self.wall(dt))

    def close(self) -> None:
        """Stop following the clock."""
        self._sub.undeclare()
