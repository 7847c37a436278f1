"""The ground station publishes the mission clock from the tick that publishes the poses.

A flying agent ages its newest mocap pose as the newest master time heard minus the pose's
stamp (:class:`agent.flight.monitor.MocapAge`, the stale-mocap failsafe at 0.2 s mission).
Here the physics runs on (3 × wall time) while the station's tick thread is starved once for
0.15 s wall (a busy machine): with the clock on a publisher thread of its own (the wiring
before, kept as a control) the clock announced 0.45 s more while no pose could be sent, and
the agent's rule saw a 0.2 s old pose (a false "mocap lost"); with the clock sent by the tick
after its poses, no pose ever looks older than the tick's own lag.
"""

from __future__ import annotations

import threading
import time

import numpy as np

from agent.flight.monitor import MocapAge
from agent.net.clocksync import ClockPublisher
from agent.net.memory import MemoryNetwork
from agent.wire.ground import CLOCK_CODEC, MOCAP_CODEC
from agent.wire.keys import clock_key, mocap_key
from groundstation.mocap import BodySample
from groundstation.station import Station

STALE_S = 0.2  #: [s mission] the driver's default bound
SCALE = 3.0  #: mission seconds per wall second (make demo's --time-scale)
STALL_S = 0.15  #: [s wall] one starved tick


class Physics:
    """The simulator's clock: mission time runs at SCALE × wall time, whatever the station."""

    time_scale = SCALE

    def __init__(self) -> None:
        self.m0 = time.monotonic()

    def now(self) -> float:
        return SCALE * (time.monotonic() - self.m0)

    def wall(self, dt: float) -> float:
        return max(0.0, dt) / SCALE

    def sleep(self, dt: float) -> None:
        time.sleep(self.wall(dt))


class Source:
    """Drone A's mocap: a fresh sample at each read (5 ms mission latency); one read is
    starved for STALL_S wall seconds when asked."""

    kind = "sim"

    def __init__(self, physics: Physics) -> None:
        self.drone_ids = ["A"]
        self.physics = physics
        self.stall = threading.Event()

    def read(self, now: float) -> dict[str, BodySample | None]:
        if self.stall.is_set():
            self.stall.clear()
            time.sleep(STALL_S)
        t = self.physics.now() - 0.005
        return {"A": BodySample(t, np.array([0.0, 0.0, 1.0]), np.array([1.0, 0.0, 0.0, 0.0]),
                                np.zeros(3))}

    def close(self) -> None:
        pass


def _worst_age(own_thread_clock: bool) -> tuple[float, int]:
    """Run a station for 0.6 s wall with one starved tick; the worst pose age [s mission]
    the agent's rule saw at any clock message, and how many clock messages came."""
    net = MemoryNetwork()
    physics = Physics()
    source = Source(physics)
    gs = net.transport("groundstation")
    age = MocapAge(silence_s=0.5)
    lock = threading.Lock()
    newest: list[float] = []
    worst = [0.0]  # the worst age seen
    clocks = [0]  # clock messages heard

    def on_clock(key: str, payload: bytes) -> None:
        msg = CLOCK_CODEC.decode(payload, key)
        assert msg is not None
        with lock:
            age.heard(msg.t)
            worst[0] = max(worst[0], age.age(max(newest, default=None)))
            clocks[0] += 1

    def on_pose(key: str, payload: bytes) -> None:
        msg = MOCAP_CODEC.decode(payload, key)
        assert msg is not None
        with lock:
            age.heard(msg.t)
            newest.append(msg.t)

    agent = net.transport("A")
    subs = [agent.subscribe(clock_key("m"), on_clock), agent.subscribe(mocap_key("m", "A"),
                                                                       on_pose)]
    publisher = ClockPublisher(gs, "m", physics, period_s=0.02) if own_thread_clock else None
    station = Station(gs, "m", source, physics, rate_hz=100.0, pace=physics,
                      clock_period_s=None if own_thread_clock else 0.02)
    if publisher is not None:
        publisher.start()
    station.start()
    try:
        time.sleep(0.25)
        source.stall.set()
        time.sleep(0.35)
    finally:
        station.stop()
        if publisher is not None:
            publisher.stop()
        for s in subs:
            s.undeclare()
    return worst[0], clocks[0]


def test_the_clock_comes_with_the_poses() -> None:
    worst, clocks = _worst_age(own_thread_clock=False)
    assert clocks >= 10  # every 0.02 s wall from the tick
    assert worst < STALE_S, f"a pose looked {worst:.3f} s old"


def test_a_clock_of_its_own_thread_made_the_skew() -> None:
    """The control: the same starved tick with the clock on its own thread trips the rule,
    so the test above would see the defect if the station still published that way."""
    worst, clocks = _worst_age(own_thread_clock=True)
    assert clocks >= 10 and worst > STALE_S, worst
