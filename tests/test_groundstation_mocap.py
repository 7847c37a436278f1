"""Ground-station pose sources and publishing: the motioncapture ``mock`` backend, a fake
libmotioncapture for stale/missing bodies, and the station over the in-memory transport."""

from __future__ import annotations

import time
from types import SimpleNamespace

import numpy as np
import pytest

from agent.clock import WallClock
from agent.net.memory import MemoryNetwork
from agent.wire.ground import (
    LANDMARKS_CODEC,
    MOCAP_CODEC,
    STATUS_CODEC,
    MocapPose,
    MocapStatus,
)
from groundstation.mocap import Health, MocapError, MotionCaptureSource, SimMocapSource
from groundstation.station import Station, landmark_set
from groundstation.vehicle.fleet import SimFleet
from groundstation.vehicle.params import VehicleParams
from tests.conftest import decoded, wait_until


def test_mock_backend_maps_bodies_to_drones() -> None:
    clock = WallClock(1.0)
    src = MotionCaptureSource(
        "mock", {"cf1": "A", "cf2": "B", "cf9": "C"}, clock,
        options={"rigid_bodies": "cf1(0.5,-1,1.2,0.9238795,0,0,0.3826834);cf2(1,2,3,1,0,0,0)"})
    try:
        assert wait_until(lambda: src.frames >= 2)
        got = src.read(clock.now())
        a, b = got["A"], got["B"]
        assert a is not None and b is not None and got["C"] is None  # cf9 not in the frames
        np.testing.assert_allclose(a.p, [0.5, -1.0, 1.2], atol=1e-6)
        np.testing.assert_allclose(a.q, [0.9238795, 0.0, 0.0, 0.3826834], atol=1e-6)  # w first
        np.testing.assert_allclose(b.p, [1.0, 2.0, 3.0])
        np.testing.assert_allclose(a.v, 0.0, atol=1e-9)  # a still body: zero velocity
    finally:
        src.close()


def test_mock_backend_through_the_station() -> None:
    clock = WallClock(1.0)
    net = MemoryNetwork()
    gs, obs = net.transport("groundstation"), net.transport("observer")
    heard: list[MocapPose | None] = []
    heard_status: list[MocapStatus | None] = []
    obs.subscribe("viscover/m1/mocap/*", lambda k, p: heard.append(MOCAP_CODEC.decode(p, k)))
    obs.subscribe("viscover/m1/mocap_status/*",
                  lambda k, p: heard_status.append(STATUS_CODEC.decode(p, k)))
    src = MotionCaptureSource("mock", {"cf1": "A", "ghost": "B"}, clock,
                              options={"rigid_bodies": "cf1(0,0,1,1,0,0,0)"})
    station = Station(gs, "m1", src, clock, rate_hz=200.0, stale_s=0.1)
    try:
        station.run(duration=0.5)
    finally:
        src.close()
    poses, statuses = decoded(heard), decoded(heard_status)
    assert poses and all(p.drone == "A" and p.source == "motioncapture" for p in poses)
    assert [p.seq for p in poses] == list(range(1, len(poses) + 1))
    assert len({p.t for p in poses}) == len(poses)  # every published pose is a new frame
    assert len(poses) >= 20  # the mock runs at about 100 frames per second
    assert any(s.drone == "B" and s.state == "missing" for s in statuses)
    assert any(s.drone == "A" and s.state == "ok" for s in statuses)


class _FakeBody:
    def __init__(self, p: list[float]) -> None:
        self.position = np.array(p)
        self.rotation = SimpleNamespace(w=1.0, x=0.0, y=0.0, z=0.0)


class _FakeMocap:
    """libmotioncapture look-alike: bodies scripted per frame, 5 ms per frame."""

    def __init__(self) -> None:
        self.frame = 0
        self.rigidBodies: dict[str, _FakeBody] = {}

    def waitForNextFrame(self) -> None:
        time.sleep(0.005)
        self.frame += 1
        x = 0.01 * self.frame
        self.rigidBodies = {"r1": _FakeBody([x, 0.0, 1.0])}
        if self.frame < 20:  # r2 is occluded after frame 20
            self.rigidBodies["r2"] = _FakeBody([0.0, 1.0, 1.0])


def test_occluded_body_goes_stale_and_is_not_repeated() -> None:
    fake = _FakeMocap()
    module = SimpleNamespace(connect=lambda kind, cfg: fake)
    clock = WallClock(1.0)
    src = MotionCaptureSource("vicon", {"r1": "A", "r2": "B"}, clock, host="10.0.0.1",
                              module=module)
    net = MemoryNetwork()
    gs, obs = net.transport("gs"), net.transport("obs")
    per: dict[str, int] = {"A": 0, "B": 0}
    states: list[tuple[str, str]] = []

    def on_pose(k: str, p: bytes) -> None:
        msg = MOCAP_CODEC.decode(p, k)
        assert msg is not None
        per[msg.drone] += 1

    def on_status(k: str, p: bytes) -> None:
        msg = STATUS_CODEC.decode(p, k)
        assert msg is not None
        states.append((msg.drone, msg.state))

    obs.subscribe("viscover/m/mocap/*", on_pose)
    obs.subscribe("viscover/m/mocap_status/*", on_status)
    station = Station(gs, "m", src, clock, rate_hz=400.0, stale_s=0.05)
    try:
        station.run(duration=0.5)
    finally:
        src.close()
    assert per["A"] > 40
    assert 0 < per["B"] <= 20  # only the frames in which r2 was seen
    assert ("B", "stale") in states and ("B", "ok") in states
    vx = station.source.read(clock.now())  # nothing new after stop is fine either way
    assert vx is not None


def test_mocap_errors_are_one_line() -> None:
    clock = WallClock(1.0)
    with pytest.raises(MocapError, match="unknown mocap type"):
        MotionCaptureSource("kinect", {}, clock)
    with pytest.raises(MocapError, match="--mocap-host is required"):
        MotionCaptureSource("vicon", {"a": "A"}, clock)

    def refuse(kind: str, cfg: dict[str, str]) -> None:
        raise RuntimeError("Unknown motion capture type!")

    with pytest.raises(MocapError, match="cannot connect to qualisys"):
        MotionCaptureSource("qualisys", {"a": "A"}, clock, host="h",
                            module=SimpleNamespace(connect=refuse))


def test_health_states() -> None:
    seen: list[tuple[str, str]] = []
    h = Health(["A", "B"], 0.1, lambda d, s, _age: seen.append((d, s)))
    h.seen("A", 1.0)
    h.update(1.05)
    assert seen == [("A", "ok"), ("B", "missing")]
    h.update(1.2)
    assert seen[-1] == ("A", "stale")


def test_sim_source_publishes_every_drone_with_landmarks() -> None:
    clock = WallClock(2.0)
    fleet = SimFleet(["A", "B"], clock, VehicleParams(mocap_latency=0.02, mocap_noise_pos=0.01),
                     start=np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]]), seed=3)
    src = SimMocapSource(fleet.start())
    net = MemoryNetwork()
    gs, obs = net.transport("gs"), net.transport("obs")
    heard: list[MocapPose | None] = []
    lms: list[bytes] = []
    obs.subscribe("viscover/sim/mocap/*", lambda k, p: heard.append(MOCAP_CODEC.decode(p, k)))
    obs.subscribe("viscover/sim/landmarks", lambda k, p: lms.append(p))
    lm = landmark_set("sim", [1, 2], np.eye(3)[:2], np.eye(3)[1:])
    station = Station(gs, "sim", src, clock, rate_hz=100.0, landmarks=lm)
    try:
        station.run(duration=1.0)
    finally:
        src.close()
    poses = decoded(heard)
    a = [p for p in poses if p.drone == "A"]
    b = [p for p in poses if p.drone == "B"]
    # Both drones all along (100 Hz asked; a starved loop publishes fewer, never stale ones:
    # the rate itself is a benchmark, bench_flight's sim_realtime rows).
    assert len(a) >= 20 and len(b) >= 20
    assert np.mean([p.p[0] for p in b]) == pytest.approx(1.0, abs=0.01)
    # The configured noise, within 3 standard errors of a sample std of len(b) draws.
    assert np.std([p.p[0] for p in b]) == pytest.approx(0.01, rel=3 / np.sqrt(2 * len(b)))
    got = LANDMARKS_CODEC.decode(lms[0])
    assert got is not None and got.ids == [1, 2] and got.q[1] == [0.0, 1.0, 0.0]
