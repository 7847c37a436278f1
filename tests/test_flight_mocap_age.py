"""The stale-mocap failsafe judges a pose's age on the ground station's own stamps.

The agent's own (extrapolated) clock and a :class:`~agent.clock.ManualClock` standing for
the local monotonic clock are moved by hand; the ground station's clock messages and poses
travel on an in-memory network. A busy machine that delays delivery (or a starved simulator)
must not trip the failsafe; a real gap must, once, said in one line.
"""

from __future__ import annotations

import logging
import math
import socket
from collections.abc import Iterator

import numpy as np
import pytest

from agent.clock import ManualClock
from agent.flight.controllers import FlightConfig, FlightController
from agent.flight.driver_types import DriverConfig, PoseSample
from agent.flight.mavlink_driver import MavlinkDriver
from agent.flight.monitor import MocapAge
from agent.flight.vehicle_pose import ZenohMocapFeed
from agent.net.memory import MemoryNetwork, MemoryTransport
from agent.runners import flying
from agent.runners.flying import phase_announcer
from agent.wire.ground import CLOCK_CODEC, MOCAP_CODEC, ClockMsg, MocapPose
from agent.wire.keys import clock_key, mocap_key

STALE_S = 0.2  # [s mission], the driver's default


class Station:
    """The ground station's side: clock messages and poses of drone A, stamped by hand."""

    def __init__(self, tp: MemoryTransport) -> None:
        self.tp, self.seq = tp, 0

    def clock(self, t: float) -> None:
        self.seq += 1
        self.tp.publish(clock_key("m"), CLOCK_CODEC.encode(ClockMsg(t=t, time_scale=1.0,
                                                                   seq=self.seq)))

    def pose(self, t: float) -> None:
        self.seq += 1
        msg = MocapPose(drone="A", seq=self.seq, t=t, p=[0.0, 0.0, 1.0], q=[1.0, 0.0, 0.0, 0.0],
                        v=[0.0, 0.0, 0.0], source="sim")
        self.tp.publish(mocap_key("m", "A"), MOCAP_CODEC.encode(msg))


@pytest.fixture
def rig(monkeypatch: pytest.MonkeyPatch
        ) -> Iterator[tuple[MavlinkDriver, Station, ManualClock, list[str]]]:
    net = MemoryNetwork()
    station = Station(net.transport("groundstation"))
    feed = ZenohMocapFeed(net.transport("A"), "m", "A")
    wall = ManualClock(100.0)  # the local monotonic clock [s]
    feed.mocap_age = MocapAge(0.5, wall=wall.now)
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:  # a port nobody reads
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    agent_clock = ManualClock(0.0)  # the agent's own clock (extrapolated between messages)
    driver = MavlinkDriver(f"udpout:127.0.0.1:{port}", feed,
                           FlightController(FlightConfig(lo=(-5, -5, 0), hi=(5, 5, 5))),
                           DriverConfig(mocap_stale_s=STALE_S, failsafe_hold_s=100.0),
                           agent_clock)
    lines: list[str] = []  # the flying agent's phase lines
    monkeypatch.setattr(flying, "say", lambda agent_id, phase: lines.append(f"{agent_id}: {phase}"))
    driver.on_phase = phase_announcer("A", driver)
    driver.streaming = True
    driver.phase = "flying"
    try:
        yield driver, station, wall, lines
    finally:
        driver.close()
        feed.close()


def test_mocap_age_rule_on_master_stamps() -> None:
    wall = ManualClock(0.0)
    age = MocapAge(0.5, wall=wall.now)
    assert age.age(1.0) == math.inf  # never heard
    age.heard(10.0)
    age.heard(9.0)  # an older stamp arriving late moves nothing back
    assert age.age(9.95) == pytest.approx(0.05)
    wall.advance(0.49)  # delivery late by 0.49 s wall: the stamps alone count
    assert age.age(9.95) == pytest.approx(0.05)
    wall.advance(0.02)  # the master silent for 0.51 s wall: lost
    assert age.age(9.95) == math.inf
    assert age.silent_for() == pytest.approx(0.51)


def test_delayed_but_fresh_mocap_is_no_failsafe(
        rig: tuple[MavlinkDriver, Station, ManualClock, list[str]],
        caplog: pytest.LogCaptureFixture) -> None:
    driver, station, wall, lines = rig
    clock = driver.clock
    assert isinstance(clock, ManualClock)
    # Nominal: 100 Hz poses, clock messages at 20 Hz, all on time.
    for k in range(100):
        t = k * 0.01
        station.pose(t)
        if k % 5 == 0:
            station.clock(t)
        clock.t, wall.t = t, 100.0 + t
        driver._step()
    # The machine is busy: nothing is delivered for 0.3 s wall, the agent's clock runs on
    # (extrapolated); then the late batch arrives, stamped as it was captured.
    clock.advance(0.3)
    wall.advance(0.3)
    driver._step()
    for k in range(100, 130):
        station.pose(k * 0.01)
    station.clock(1.29)
    driver._step()
    # A starved simulator: its physics (the mission clock) stood still while the agent's clock
    # extrapolated 0.4 s ahead; the station's stamps agree with each other.
    clock.advance(0.4)
    wall.advance(0.2)
    station.clock(1.30)
    station.pose(1.30)
    driver._step()
    assert driver.stats.failsafes == 0 and driver.phase == "flying"
    assert lines == [] and not [r for r in caplog.records if "mocap" in r.getMessage()
                                and r.levelno >= logging.WARNING]


def test_real_gap_is_one_failsafe_said_once(
        rig: tuple[MavlinkDriver, Station, ManualClock, list[str]],
        caplog: pytest.LogCaptureFixture) -> None:
    driver, station, wall, lines = rig
    clock = driver.clock
    assert isinstance(clock, ManualClock)
    dt = 1.0 / 128.0  # [s]: exact in binary, so the threshold is crossed at a known step
    for k in range(64):
        station.pose(k * dt)
        station.clock(k * dt)
        clock.t, wall.t = k * dt, 100.0 + k * dt
        driver._step()
    assert driver.stats.failsafes == 0
    # The body is lost: the clock runs on, no pose of A after 63 dt; a step each dt.
    for k in range(64, 128):
        station.clock(k * dt)
        clock.t, wall.t = k * dt, 100.0 + k * dt
        driver._step()
        assert driver.phase == ("flying" if (k - 63) * dt <= STALE_S else "failsafe_hold")
    assert driver.stats.failsafes == 1
    assert driver.failsafe_reason == "newest pose 0.203 s old, limit 0.200 s"  # 26 dt
    # Back: one line again.
    station.pose(1.0)
    station.clock(1.0)
    clock.t = 1.0
    driver._step()
    assert driver.phase == "flying"
    assert lines == ["A: mocap lost (newest pose 0.203 s old, limit 0.200 s): level hover at "
                     "hover thrust", "A: mocap back after 0.30 s: resuming"]
    assert not [r for r in caplog.records if r.levelno >= logging.WARNING]


def test_silent_ground_station_is_a_gap(
        rig: tuple[MavlinkDriver, Station, ManualClock, list[str]]) -> None:
    driver, station, wall, lines = rig
    station.pose(0.0)
    station.clock(0.0)
    driver._step()
    assert driver.phase == "flying"
    wall.advance(0.4)  # no message at all, but not for long: a hiccup
    driver._step()
    assert driver.phase == "flying"
    wall.advance(0.2)  # 0.6 s wall of silence: the station or the link is gone
    driver._step()
    assert driver.phase == "failsafe_hold" and driver.stats.failsafes == 1
    assert lines[0].startswith("A: mocap lost (ground station silent for 0.60 s)")


def test_own_clock_without_a_station_clock() -> None:
    """A provider without ``mocap_age``: the driver's clock stands for the station's."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    clock = ManualClock(0.0)
    sample = PoseSample(0.0, np.zeros(3), np.zeros(3), np.array([1.0, 0.0, 0.0, 0.0]))
    driver = MavlinkDriver(f"udpout:127.0.0.1:{port}", lambda: sample,
                           FlightController(FlightConfig(lo=(-5, -5, 0), hi=(5, 5, 5))),
                           DriverConfig(mocap_stale_s=STALE_S, failsafe_hold_s=100.0), clock)
    try:
        driver.streaming, driver.phase = True, "flying"
        clock.t = 0.2
        driver._step()
        assert driver.phase == "flying"
        clock.t = 0.25
        driver._step()
        assert driver.phase == "failsafe_hold" and driver.stats.failsafes == 1
    finally:
        driver.close()
