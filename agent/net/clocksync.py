"""The shared simulation clock over Zenoh (like ROS's /clock).

* :class:`ClockPublisher` publishes a master :class:`~agent.clock.Clock` as
  :class:`~agent.wire.ground.ClockMsg` on ``viscover/<m>/clock`` at a fixed wall rate (the
  ground station runs one).
* :class:`RemoteClock` follows those messages in another process and extrapolates between
  them with the announced time scale, so every process sleeps and times out in simulation
  seconds. It satisfies :class:`agent.clock.Clock`.
"""

from __future__ import annotations

import logging
import threading
import time

from agent.clock import Clock
from agent.net.contract import Declared, Transport
from agent.wire import keys
from agent.wire.ground import CLOCK_CODEC, ClockMsg

_log = logging.getLogger(f"viscover.{__name__}")


def clock_heard(transport: Transport, mission: str, wait_s: float = 0.3) -> bool:
    """Whether someone publishes the mission's clock (heard within ``wait_s`` [s wall]): one
    ground station per mission, so a second one refuses to start."""
    heard = threading.Event()

    def on_clock(key: str, payload: bytes) -> None:
        if CLOCK_CODEC.decode(payload, key) is not None:
            heard.set()

    sub = transport.subscribe(keys.clock_key(mission), on_clock)
    try:
        return heard.wait(wait_s)
    finally:
        sub.undeclare()


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
    """Follows a :class:`ClockPublisher`: ``now()`` = last t + time_scale · wall time since it
    came, never going backwards.

    * Extrapolation is limited to ``max_extrapolate_s`` wall seconds: a stalled or dilated
      master stalls its followers too (time dilation of the simulator).
    * After ``lost_after_s`` further wall seconds without a message the master counts as lost
      and time runs on at the last announced scale (logged once). Without that a dead ground
      station would freeze every simulation-time timeout of the follower: a failsafe would
      never reach its landing step and a landing would wait forever for its acknowledgement.
      When the master comes back, time holds until the master has caught up (monotonic).

    Before the first message ``now()`` raises RuntimeError; use :meth:`wait_synced`.
    """

    def __init__(self, transport: Transport, mission: str, max_extrapolate_s: float = 0.25,
                 lost_after_s: float = 2.0) -> None:
        self.max_extrapolate_s = max_extrapolate_s
        self.lost_after_s = lost_after_s
        self.lost = False
        self._last_now = -float("inf")
        self._lock = threading.Lock()
        self._t = 0.0
        self._m = 0.0
        self._scale = 1.0
        self._synced = threading.Event()
        self._seq = -1
        self._sub: Declared = transport.subscribe(keys.clock_key(mission), self._on_msg)

    @property
    def time_scale(self) -> float:
        """Simulation seconds per wall second (the master's last announcement)."""
        return self._scale

    def _on_msg(self, key: str, payload: bytes) -> None:
        msg = CLOCK_CODEC.decode(payload, key)
        if msg is None or not msg.time_scale > 0:
            return
        with self._lock:
            if msg.seq <= self._seq and self._synced.is_set():
                return  # stale or duplicated
            self._seq, self._t, self._m = msg.seq, msg.t, time.monotonic()
            self._scale = msg.time_scale
            if self.lost:
                self.lost = False
                _log.warning("clock master back")
        self._synced.set()

    def wait_synced(self, timeout_s: float) -> bool:
        """Wait (wall seconds) for the first clock message; True once synced."""
        return self._synced.wait(timeout_s)

    def now(self) -> float:
        """Simulation time [s] extrapolated from the last message (see the class docstring)."""
        if not self._synced.is_set():
            raise RuntimeError("no clock message received yet")
        with self._lock:
            since = time.monotonic() - self._m
            ahead = min(since, self.max_extrapolate_s)
            beyond = since - self.max_extrapolate_s - self.lost_after_s
            if beyond > 0.0:
                if not self.lost:
                    self.lost = True
                    _log.error("no clock message for %.1f s: running on at x%g",
                               since, self._scale)
                ahead += beyond
            self._last_now = max(self._last_now, self._t + ahead * self._scale)
            return self._last_now

    def wall(self, dt: float) -> float:
        """Wall seconds of ``dt`` simulation seconds at the current scale."""
        return max(0.0, dt) / self._scale

    def sleep(self, dt: float) -> None:
        """Sleep ``dt`` simulation seconds."""
        time.sleep(self.wall(dt))

    def close(self) -> None:
        """Stop following the clock."""
        self._sub.undeclare()
