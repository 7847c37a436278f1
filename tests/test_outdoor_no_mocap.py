"""Outdoors there is no motion capture (issue 23): drones fly on their autopilots' pose, the
ground station started with ``--gnss`` publishes no mocap (a real router: nothing arrives on
the mocap keys while its clock and landmarks do), and the way home keeps R_s from the other
drones by the poses and states their agents publish
(:class:`agent.runners.going_home.PublishedNeighbours`), saying its own pose as it flies."""

from __future__ import annotations

import collections
import itertools
import subprocess
import sys
import time
from collections.abc import Callable
from types import SimpleNamespace
from typing import cast

import numpy as np
from numpy.typing import NDArray

from agent.clock import WallClock
from agent.config.parse import load_scenario
from agent.flight.driver_types import PoseSample
from agent.flight.vehicle_pose import MavlinkPoseSource
from agent.net.clocksync import RemoteClock
from agent.net.memory import MemoryNetwork, MemoryTransport
from agent.net.router import client_config, start_router_process, stop_router_process
from agent.net.transport import ZenohTransport
from agent.runners.going_home import PublishedNeighbours, fly_home
from agent.wire import keys
from agent.wire.peer import Pose
from tests.conftest import reap, repo_env, scenario_path, wait_until
from tests.test_status_identity import PUB, state

Array = NDArray[np.float64]
CUBE = scenario_path("cube_6_2")


def _pose(sender: str, p: tuple[float, float, float], seq: int = 1) -> bytes:
    return PUB.encode(Pose(sender=sender, seq=seq, t=0.0, p=p, v=(1.0, 0.0, 0.0)))


def test_neighbours_are_the_poses_and_states_the_other_agents_publish() -> None:
    net = MemoryNetwork()
    peers = net.transport("peers")
    nb = PublishedNeighbours(net.transport("A"), "m", "A")
    peers.publish(keys.pose_key("m", "A"), _pose("A", (0.0, 0.0, 1.0)))  # itself: not one
    peers.publish(keys.pose_key("m", "B"), _pose("B", (1.0, 2.0, 3.0)))
    st = state("C", 1, 0.0, {3: 0})  # a state carries the position too
    peers.publish(keys.state_key("m", "C"), PUB.encode(st))
    peers.publish(keys.pose_key("m", "D"), b"\x93garbage")  # counted, not a crash
    peers.publish(keys.pose_key("m", "E"), _pose("B", (9.0, 9.0, 9.0)))  # B's on E's key
    got = sorted(map(tuple, nb.positions().tolist()))
    assert got == [(0.0, 0.0, 0.0), (1.0, 2.0, 3.0)]
    assert nb.rejects.total == 2
    peers.publish(keys.pose_key("m", "B"), _pose("B", (1.5, 2.0, 3.0), seq=2))
    assert (1.5, 2.0, 3.0) in map(tuple, nb.positions().tolist())  # the newest
    time.sleep(0.05)
    assert nb.positions(max_age_s=0.01).shape == (0, 3)  # nothing heard lately
    said: list[Pose] = []

    def hear(key: str, payload: bytes) -> None:
        msg = PUB.decode(payload, key)
        assert isinstance(msg, Pose) and key == keys.pose_key("m", "A")
        said.append(msg)

    peers.subscribe(keys.all_agents("m", "pose"), hear)
    nb.seq = 41  # continues the runtime's numbering
    nb.say(np.array([1.0, 2.0, 3.0]), np.array([0.0, 1.0, 0.0]), 7.5)
    assert [(m.seq, m.t, m.p, m.v) for m in said] == [(42, 7.5, (1.0, 2.0, 3.0),
                                                       (0.0, 1.0, 0.0))]
    nb.close()


class PointVehicle:
    """A vehicle that flies the commanded velocity exactly (the way home's pose source);
    each step the other drone ``other`` publishes its pose, as a live agent does."""

    def __init__(self, p: Array, clock: WallClock, other: MemoryTransport,
                 other_p: tuple[float, float, float]) -> None:
        self.p, self.vel, self.clock = p.astype(np.float64), np.zeros(3), clock
        self.driver = SimpleNamespace(released=None)
        self.other, self.other_p = other, other_p
        self.path = [self.p.copy()]
        self._say_other()

    def _say_other(self) -> None:
        self.other.publish(keys.pose_key("m", "B"), _pose("B", self.other_p))

    def pose(self) -> PoseSample:
        return PoseSample(self.clock.now(), self.p.copy(), self.vel.copy(),
                          np.array([1.0, 0.0, 0.0, 0.0]))

    def current(self) -> tuple[Array, Array, float]:
        return self.p.copy(), np.array([1.0, 0.0, 0.0]), self.clock.now()

    def command(self, vel: Array, _omega: Array, dt: float) -> None:
        self.vel = np.asarray(vel, dtype=np.float64)
        self.p = self.p + self.vel * dt
        self.path.append(self.p.copy())
        self._say_other()

    def hold(self, p: Array | None = None, _yaw: float | None = None) -> None:
        self.vel = np.zeros(3)
        self._say_other()


def _fly_home_past_b(neighbours_of_a: bool) -> tuple[float, list[Pose]]:
    """Drone A flies home along y = −1.2 m of the cube's cage while B hovers on that line:
    A's closest approach to B [m] and the poses A said."""
    sc = load_scenario(CUBE)
    net = MemoryNetwork()
    b_at = (0.0, -1.2, 1.0)
    vehicle = PointVehicle(np.array([1.8, -1.2, 1.0]), WallClock(time_scale=50.0),
                           net.transport("B"), b_at)
    nb = PublishedNeighbours(net.transport("A"), "m", "A")
    said: list[Pose] = []

    def hear(key: str, payload: bytes) -> None:
        msg = PUB.decode(payload, key)
        if isinstance(msg, Pose) and msg.sender == "A":
            said.append(msg)

    net.transport("observer").subscribe(keys.all_agents("m", "pose"), hear)

    class NoOne:
        def positions(self, max_age_s: float = 1.0) -> Array:
            return np.zeros((0, 3))

    fly_home(cast(MavlinkPoseSource, vehicle), nb if neighbours_of_a else NoOne(),
             np.array([-1.8, -1.2, 0.0]), sc, vehicle.clock, timeout_s=25.0, say=nb.say)
    nb.close()
    path = np.array(vehicle.path)
    return float(np.linalg.norm(path - np.array(b_at), axis=1).min()), said


def test_the_way_home_keeps_r_s_from_a_drone_known_by_its_published_pose() -> None:
    """Outdoors (no mocap): B is known to A only by the pose B's agent publishes; A keeps
    R_s from it (without that pose A flies straight through B), and A says its own pose on
    its pose key every step, so B, going home too, keeps R_s from A."""
    r_s = load_scenario(CUBE).params.r_s
    closest, said = _fly_home_past_b(True)
    assert closest >= r_s - 0.05, closest
    assert len(said) > 20 and all(b.seq == a.seq + 1 for a, b in itertools.pairwise(said))
    blind, _ = _fly_home_past_b(False)
    assert blind < 0.2 * r_s, blind


def test_a_gnss_ground_station_publishes_no_mocap() -> None:
    """``viscover groundstation --gnss rtk``: its clock and landmarks reach a client through
    a real router, nothing on ``mocap/*`` or ``mocap_status/*``."""
    router, endpoint = start_router_process()
    gs = subprocess.Popen(
        [sys.executable, "-m", "agent.cli", "groundstation", "--source", "sim", "--gnss", "rtk",
         "--scenario", str(CUBE), "--connect", endpoint, "--time-scale", "3", "--duration",
         "60", "--ports", "A=0,B=0,C=0"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=repo_env())
    obs = clock = None
    try:
        obs = ZenohTransport(client_config(endpoint), None, "observer")
        counts: collections.Counter[str] = collections.Counter()
        def counter(kind: str) -> Callable[[str, bytes], None]:
            return lambda _key, _payload: counts.update([kind])

        for kind in ("mocap", "mocap_status"):
            obs.subscribe(keys.all_agents("cube_6_2", kind), counter(kind))
        obs.subscribe(keys.landmarks_key("cube_6_2"), counter("lm"))
        assert gs.stdout is not None
        ready = gs.stdout.readline()
        assert ready.startswith("viscover-groundstation ready mission=cube_6_2"), ready
        clock = RemoteClock(obs, "cube_6_2")
        assert clock.wait_synced(5.0)
        t0 = clock.now()
        assert wait_until(lambda: counts["lm"] >= 2 and clock is not None
                          and clock.now() - t0 > 3.0, 10.0)  # 3 s sim: 300 ticks
        assert counts["mocap"] == 0 and counts["mocap_status"] == 0, counts
        gs.terminate()
        assert gs.wait(10) == 0
    finally:
        if clock is not None:
            clock.close()
        if obs is not None:
            obs.close()
        reap([gs])
        stop_router_process(router)
