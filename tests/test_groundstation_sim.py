"""The simulated quadrotor's physics and the shared simulation clock."""

from __future__ import annotations

import math
import time

import numpy as np
import pytest

from agent.clock import ManualClock, WallClock
from agent.net.clocksync import ClockPublisher, RemoteClock
from agent.net.memory import MemoryNetwork
from groundstation.vehicle.fleet import SimFleet
from groundstation.vehicle.params import VehicleParams


def _fleet(n: int = 1, params: VehicleParams | None = None) -> SimFleet:
    return SimFleet([f"d{i}" for i in range(n)], ManualClock(),
                    params if params is not None else VehicleParams(),
                    start=np.array([[float(i), 0.0, 0.0] for i in range(n)]))


def _fly(fleet: SimFleet, roll: float, pitch: float, yaw: float, thrust: float) -> None:
    q = fleet.quads[0]
    q.armed, q.mode = True, 20
    q.params_table["GUID_OPTIONS"] = 8
    q.sp_rpy, q.sp_thrust, q.sp_t = (roll, pitch, yaw), thrust, math.inf  # never times out


def test_ground_contact_and_gravity() -> None:
    with _fleet() as f:
        f.step_to(2.0)  # disarmed on the ground: stays there
        assert f.p[0, 2] == 0.0 and np.all(f.v[0] == 0.0)
        f.p[0, 2] = -1.0  # drop from 1 m (NED z = −1)
        f.step_to(2.2)
        assert f.v[0, 2] == pytest.approx(9.81 * 0.2, rel=0.05)  # falling (drag slows a bit)
        f.step_to(4.0)
        assert f.p[0, 2] == 0.0 and f.v[0, 2] == 0.0  # landed, no penetration


def test_hover_thrust_balances_gravity_and_tilt_accelerates() -> None:
    with _fleet(params=VehicleParams(hover_thrust=0.4)) as f:
        f.p[0, 2] = -1.0
        _fly(f, 0.0, 0.0, 0.0, 0.4)
        f.thrust[0] = 0.4
        f.step_to(2.0)
        assert f.p[0, 2] == pytest.approx(-1.0, abs=1e-6)
        _fly(f, 0.0, -0.1, 0.0, 0.4 / math.cos(0.1))  # NED pitch down: accelerate north (+x)
        f.step_to(3.0)
        assert f.v[0, 0] > 0.5 and abs(f.v[0, 1]) < 1e-9
        assert f.att[0, 1] == pytest.approx(-0.1, abs=1e-4)  # first-order response settled


def test_attitude_is_first_order() -> None:
    with _fleet(params=VehicleParams(tau_att=0.1)) as f:
        f.p[0, 2] = -2.0
        _fly(f, 0.2, 0.0, 0.0, 0.5)
        f.step_to(0.1)
        assert f.att[0, 0] == pytest.approx(0.2 * (1 - math.exp(-1)), rel=0.03)


def test_mocap_latency_and_noise_are_seeded() -> None:
    def run() -> tuple[float, np.ndarray]:
        with _fleet(params=VehicleParams(mocap_latency=0.05, mocap_noise_pos=0.02)) as f:
            f.step_to(1.0)
            s = f.mocap(0)
            return s.t, s.p

    t1, p1 = run()
    _, p2 = run()
    assert t1 == pytest.approx(0.95, abs=0.003)  # 50 ms old
    np.testing.assert_array_equal(p1, p2)  # same seed, same noise
    assert 0 < np.linalg.norm(p1) < 0.1


def test_scaled_clock_runs_faster_than_real_time() -> None:
    c = WallClock(5.0)
    t0, w0 = c.now(), time.monotonic()
    c.sleep(0.5)
    assert (c.now() - t0) / (time.monotonic() - w0) == pytest.approx(5.0, rel=0.05)
    with pytest.raises(ValueError):
        WallClock(0.0)


def test_remote_clock_follows_the_publisher() -> None:
    net = MemoryNetwork()
    master = WallClock(3.0, t0=100.0)
    pub = ClockPublisher(net.transport("gs"), "m", master)
    remote = RemoteClock(net.transport("agent"), "m")
    with pytest.raises(RuntimeError):
        remote.now()
    pub.publish_once()
    assert remote.wait_synced(1.0)
    assert remote.time_scale == 3.0
    assert remote.now() == pytest.approx(master.now(), abs=0.01)
    time.sleep(0.1)
    assert remote.now() == pytest.approx(master.now(), abs=0.02)  # extrapolated at 3×
    remote.close()


def test_fleet_keeps_up_with_a_fast_clock() -> None:
    clock = WallClock(5.0)
    with SimFleet(["a", "b", "c"], clock, VehicleParams()).start() as f:
        time.sleep(0.4)
        assert f.max_lag < 0.06  # never far behind: overload slips the clock instead
        assert f.steps * f.dt > 0.5  # 0.4 s wall at 5×: about 2 s simulated unless dilated


def test_overload_dilates_time_instead_of_jumping() -> None:
    clock = WallClock(1.0)
    with SimFleet(["a"], clock, VehicleParams()) as f:
        f.tick()
        time.sleep(0.3)  # the loop was starved for 300 ms
        f.tick()
        assert f.slipped == pytest.approx(0.3, abs=0.05)
        assert clock.now() - f.t < 0.01
