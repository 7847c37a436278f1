"""The ground station: publishes every drone's mocap pose, the landmark set and the clock.

Per tick (``rate`` Hz of simulation time) it reads the :class:`~groundstation.mocap.MocapSource`
and publishes each *new* sample as a :class:`~agent.wire.ground.MocapPose` on
``viscover/<m>/mocap/<drone>``. A drone without a new sample is not published (never
repeated); its :class:`~groundstation.mocap.Health` turns ``stale``/``missing`` and a
:class:`~agent.wire.ground.MocapStatus` goes out on ``viscover/<m>/mocap_status/<drone>``
(at each change and every second) with a warning in the log. The landmark set is published on
``viscover/<m>/landmarks`` every ``landmarks_period_s``. With ``mocap=False`` (outdoors, where
the drones fly on their autopilots' pose: ``viscover groundstation --gnss``) no pose and no
mocap health goes out, only the landmarks and the clock.

The mission clock (``viscover/<m>/clock``, :class:`~agent.wire.ground.ClockMsg`) goes out from
the same tick, after its poses, stamped with the tick's own reading of the clock, every
``clock_period_s`` wall seconds (``viscover groundstation``: 0.05 s; None: not published
here). A flying agent judges a pose's age as the newest master time heard minus the pose's
stamp (:class:`agent.flight.monitor.MocapAge`). A clock published from a thread of its own
(:class:`agent.net.clocksync.ClockPublisher`, as before) reads the physics' time on its own
schedule: when the tick thread is starved on a busy machine, the clock thread announced
times the poses had not been published for yet, and at ``--time-scale 3`` a stall of 70 ms
wall already made the newest pose look 0.2 s old: a false "mocap lost". From one tick, no
clock message announces a time later than the poses sent before it; a starved tick delays
both alike (and a tick that stops altogether is the master's silence, which the agents judge
on their own wall clock).
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field

from agent.clock import Clock
from agent.net.transport import Transport
from agent.wire import keys
from agent.wire.ground import (
    CLOCK_CODEC,
    LANDMARKS_CODEC,
    MOCAP_CODEC,
    STATUS_CODEC,
    ClockMsg,
    LandmarkSet,
    MocapPose,
    MocapStatus,
)
from agent.wire.keys import mocap_key, mocap_status_key
from groundstation.mocap import Health, MocapSource

_log = logging.getLogger(f"viscover.{__name__}")


@dataclass
class StationStats:
    """Counts of published messages and the wall period of ticks [s]."""

    poses: int = 0
    statuses: int = 0
    ticks: int = 0
    landmarks: int = 0
    clocks: int = 0
    per_drone: dict[str, int] = field(default_factory=dict)


def landmark_set(mission: str, ids: list[int], q: object, u: object) -> LandmarkSet:
    """The wire form of a scenario's landmarks (positions and normals as lists)."""
    return LandmarkSet(mission=mission, ids=[int(i) for i in ids],
                       q=[[float(a) for a in row] for row in q],  # type: ignore[attr-defined]
                       u=[[float(a) for a in row] for row in u])  # type: ignore[attr-defined]


class Station:
    """Publishes ``source``'s poses on ``transport`` for ``mission`` at ``rate_hz`` (sim)."""

    def __init__(self, transport: Transport, mission: str, source: MocapSource, clock: Clock,
                 rate_hz: float = 100.0, stale_s: float = 0.1,
                 landmarks: LandmarkSet | None = None, landmarks_period_s: float = 1.0,
                 status_period_s: float = 1.0, pace: Clock | None = None,
                 clock_period_s: float | None = None, clock_seq: int = 0,
                 wall: Callable[[], float] = time.monotonic, mocap: bool = True) -> None:
        keys.validate_id(mission, "mission")
        self.transport, self.mission, self.source, self.clock = transport, mission, source, clock
        self.mocap = mocap  #: publish poses and mocap health (False: landmarks and clock only)
        self.pace = pace or clock  # schedules the ticks (a smooth clock); ``clock`` stamps
        self.period = 1.0 / rate_hz
        self.landmarks, self.landmarks_period_s = landmarks, landmarks_period_s
        self.status_period_s = status_period_s
        self.health = Health(source.drone_ids if mocap else [], stale_s, self._report)
        self.stats = StationStats(per_drone=dict.fromkeys(source.drone_ids, 0))
        self.seq = dict.fromkeys(source.drone_ids, 0)
        self._next_lm = -float("inf")
        self._next_status = -float("inf")
        self.clock_period_s, self.clock_seq, self._wall = clock_period_s, clock_seq, wall
        self._next_clock = -float("inf")  # [s wall]
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def _report(self, drone: str, state: str, age: float) -> None:
        if state != "ok":
            _log.warning("mocap: drone %s is %s (last seen %.2f s ago)", drone, state, age)
        else:
            _log.info("mocap: drone %s tracked", drone)
        self._publish_status(drone, state, age)

    def _publish_status(self, drone: str, state: str, age: float) -> None:
        msg = MocapStatus(drone=drone, state=state, age=min(age, 1e9), t=self.clock.now())
        self.transport.publish(mocap_status_key(self.mission, drone), STATUS_CODEC.encode(msg),
                               kind="mocap_status")
        self.stats.statuses += 1

    def tick(self) -> None:
        """Read the source once and publish what is new; health, status and landmarks."""
        now = self.clock.now()
        for drone, s in (self.source.read(now) if self.mocap else {}).items():
            if s is None:
                continue
            self.health.seen(drone, s.t)
            self.seq[drone] += 1
            msg = MocapPose(drone=drone, seq=self.seq[drone], t=s.t,
                            p=[float(a) for a in s.p], q=[float(a) for a in s.q],
                            v=[float(a) for a in s.v], source=self.source.kind)
            self.transport.publish(mocap_key(self.mission, drone), MOCAP_CODEC.encode(msg),
                                   kind="mocap")
            self.stats.poses += 1
            self.stats.per_drone[drone] += 1
        self.health.update(now)
        if now >= self._next_status:
            self._next_status = now + self.status_period_s
            for d, state in self.health.state.items():
                self._publish_status(d, state, self.health.age(d, now))
        if self.landmarks is not None and now >= self._next_lm:
            self._next_lm = now + self.landmarks_period_s
            self.transport.publish(keys.landmarks_key(self.mission),
                                   LANDMARKS_CODEC.encode(self.landmarks), kind="landmarks")
            self.stats.landmarks += 1
        if self.clock_period_s is not None and self._wall() >= self._next_clock:
            self._next_clock = self._wall() + self.clock_period_s
            self.clock_seq += 1  # continues the seq of a publisher used before (monotonic)
            tick = ClockMsg(t=now, time_scale=float(self.clock.time_scale),
                            seq=self.clock_seq)
            self.transport.publish(keys.clock_key(self.mission), CLOCK_CODEC.encode(tick),
                                   kind="clock")
            self.stats.clocks += 1
        self.stats.ticks += 1

    def run(self, stop: threading.Event | None = None, duration: float | None = None,
            on_tick: Callable[[], None] | None = None) -> None:
        """Tick at the rate until ``stop`` is set or ``duration`` sim seconds have passed."""
        stop = stop or self._stop
        t_end = None if duration is None else self.pace.now() + duration
        nxt = self.pace.now()
        while not stop.is_set():
            now = self.pace.now()
            if t_end is not None and now >= t_end:
                return
            if now >= nxt:
                self.tick()
                if on_tick is not None:
                    on_tick()
                nxt += self.period
                if nxt < now:  # fell behind: skip, do not burst
                    nxt = now + self.period
            stop.wait(max(self.pace.wall(nxt - self.pace.now()), 0.0005))

    def start(self) -> Station:
        """Run on a daemon thread (see :meth:`stop`)."""
        self._thread = threading.Thread(target=self.run, name="station", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        """Stop and join the thread."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(5.0)


def wait_until(pred: Callable[[], bool], timeout_s: float, poll_s: float = 0.01) -> bool:
    """Poll ``pred`` until true or ``timeout_s`` wall seconds pass."""
    deadline = time.monotonic() + timeout_s
    while not pred():
        if time.monotonic() > deadline:
            return False
        time.sleep(poll_s)
    return True
