"""The MAVLink driver against the simulated vehicle: both in-process, loopback UDP, and a
simulation clock running faster than real time. Everything is checked from the vehicle's
side (its MAVLink log and its true state)."""

from __future__ import annotations

import math
import os
import signal
import threading
import time
from collections.abc import Callable, Iterator
from typing import Any

import numpy as np
import pytest

from agent.clock import WallClock
from agent.flight.controllers import (
    AttitudeSetpoint,
    FlightConfig,
    FlightController,
    FlightState,
)
from agent.flight.driver_types import DriverConfig, FlightError, PoseSample
from agent.flight.frames import enu_to_ned, quat_from_euler, yaw_ned_to_enu
from agent.flight.mavlink_driver import MavlinkDriver, land_on_signals
from agent.flight.vehicle_pose import MavlinkPoseSource, MocapNeighbours, ZenohMocapFeed
from agent.net.faults import FaultConfig, FaultInjector
from agent.net.memory import MemoryNetwork
from agent.wire.ground import MOCAP_CODEC, MocapPose
from agent.wire.keys import mocap_key
from agent.wire.mavlink import mavlink, mavutil
from groundstation.vehicle.fleet import SimFleet
from groundstation.vehicle.params import VehicleParams
from tests.conftest import wait_until

SCALE = 3.0  # simulation seconds per wall second
LO, HI = (-2.0, -2.0, 0.0), (2.0, 2.0, 3.0)


class Rig:
    """One simulated vehicle, one driver, and a 100 Hz (sim) mocap feed that can be paused."""

    def __init__(self, autopilot: str = "ardupilot", params: VehicleParams | None = None,
                 cfg: DriverConfig | None = None, faults: FaultInjector | None = None) -> None:
        self.clock = WallClock(SCALE)
        params = params or VehicleParams(autopilot=autopilot)
        self.fleet = SimFleet(["A"], self.clock, params, start=np.array([[0.0, 0.0, 0.0]]))
        self.quad = self.fleet.quads[0]
        self.feeding = True
        self.hook: Callable[[], None] | None = None  # replaces the direct feed when set
        self._latest: PoseSample | None = None
        self.controller = FlightController(FlightConfig(lo=LO, hi=HI))
        # 0.5 s (sim) before the mocap failsafe: at 3× a scheduling stall of the shared CI
        # machine must not look like lost mocap.
        cfg = cfg or DriverConfig(autopilot=autopilot, mocap_stale_s=0.5)
        self.driver = MavlinkDriver(f"udpout:127.0.0.1:{self.quad.port}", self.pose,
                                    self.controller, cfg, self.clock, faults=faults)
        self._stop = threading.Event()
        self._feed = threading.Thread(target=self._feed_loop, daemon=True)

    def pose(self) -> PoseSample | None:
        return self._latest

    def _feed_loop(self) -> None:
        while not self._stop.is_set():
            if self.feeding and self.hook is not None:
                self.hook()
            elif self.feeding:
                s = self.fleet.mocap(0)
                self._latest = PoseSample(s.t, s.p, s.v, s.q, time.monotonic())
                self.driver.notify_pose()
            self._stop.wait(self.clock.wall(0.01))

    def __enter__(self) -> Rig:
        self.fleet.start()
        self._feed.start()
        self.driver.start()
        return self

    def __exit__(self, *_exc: object) -> None:
        self._stop.set()
        self._feed.join(2.0)
        self.driver.close()
        self.fleet.close()

    def run_for(self, dt: float, every: Callable[[], None] | None = None) -> None:
        """Let dt simulation seconds pass, calling ``every`` each 20 ms (sim)."""
        end = self.clock.now() + dt
        while self.clock.now() < end:
            if every is not None:
                every()
            time.sleep(self.clock.wall(0.02))

    def position(self) -> np.ndarray:
        return self.fleet.position_enu(0)

    def takeoff(self, z: float = 0.6, settle: float = 3.0) -> None:
        self.driver.engage()
        self.controller.set_hold([0.0, 0.0, z], 0.0)
        self.run_for(settle)


@pytest.fixture
def rig() -> Iterator[Rig]:
    with Rig() as r:
        yield r


def test_handshake_ardupilot(rig: Rig) -> None:
    rig.driver.engage()
    q = rig.quad
    assert q.armed and q.mode == 20  # GUIDED_NOGPS
    assert q.params_table["GUID_OPTIONS"] == 8  # thrust is thrust (bit 3)
    names = [n for _, n in q.log.events]
    assert names.index("mode_20") < names.index("armed")
    assert rig.driver.vehicle.armed and rig.driver.vehicle.custom_mode == 20
    rig.run_for(0.5)
    assert q.log.heartbeats_rx >= 1  # our 1 Hz onboard-controller heartbeat
    assert q.log.setpoints > 10 and q.log.last_type_mask == 7
    assert q.log.vision > 10  # mocap forwarded as VISION_POSITION_ESTIMATE


def test_handshake_px4_streams_before_offboard() -> None:
    with Rig("px4", cfg=DriverConfig(autopilot="px4", forward="odometry", mocap_stale_s=0.5,
                                     yaw_rate_ff=True)) as r:
        r.driver.engage()
        q = r.quad
        assert q.armed and q.mode == 6 << 16  # OFFBOARD
        assert not q.log.has("offboard_refused")
        r.run_for(0.3)
        assert q.log.odometry > 5 and q.log.last_type_mask == 3


def test_px4_refuses_offboard_without_stream() -> None:
    with Rig("px4", cfg=DriverConfig(autopilot="px4", ack_timeout_s=0.5,
                                     heartbeat_timeout_s=1.5)) as r:
        r.driver.wait_heartbeat()
        with pytest.raises(FlightError, match="refused"):
            r.driver.set_mode(6)
        assert r.quad.log.has("offboard_refused")


def test_no_vehicle_is_one_clear_error() -> None:
    clock = WallClock(SCALE)
    drv = MavlinkDriver("udpout:127.0.0.1:9", lambda: None, FlightController(),
                        DriverConfig(heartbeat_timeout_s=0.5), clock)
    with drv, pytest.raises(FlightError, match="no HEARTBEAT"):
        drv.wait_heartbeat()


def test_hover_holds_altitude_within_5cm(rig: Rig) -> None:
    rig.takeoff(0.8, settle=4.0)
    zs: list[float] = []
    rig.run_for(3.0, every=lambda: zs.append(float(rig.position()[2])))
    assert len(zs) > 50
    assert max(abs(z - 0.8) for z in zs) < 0.05
    assert np.linalg.norm(rig.position()[:2]) < 0.05


def test_velocity_steps_tracked(rig: Rig) -> None:
    rig.takeoff(1.0)
    src = MavlinkPoseSource(rig.driver, rig.pose)
    for step in ([0.3, 0.0, 0.0], [0.0, -0.3, 0.1]):
        v_cmd = np.array(step)
        vs: list[np.ndarray] = []

        def command(v_cmd: np.ndarray = v_cmd, vs: list[np.ndarray] = vs) -> None:
            src.command(v_cmd, np.zeros(3), 0.1)
            s = rig.pose()
            if s is not None:
                vs.append(s.vel.copy())

        rig.run_for(2.5, every=command)
        tail = np.array(vs[len(vs) // 2:])  # after the transient
        np.testing.assert_allclose(tail.mean(axis=0), v_cmd, atol=0.03)
        assert np.abs(tail - v_cmd).max() < 0.08
    src.command(np.zeros(3), np.zeros(3), 0.1)  # zero command: hold
    assert rig.controller.mode == "hold"


def test_yaw_rate_and_simulated_tilt(rig: Rig) -> None:
    rig.takeoff(1.0, settle=2.0)
    src = MavlinkPoseSource(rig.driver, rig.pose)
    omega = np.array([0.0, 0.0, 0.3])
    yaw0 = yaw_ned_to_enu(float(rig.fleet.att[0, 2]))
    rig.run_for(2.0, every=lambda: src.command(np.zeros(3), omega, 0.1))
    yaw1 = yaw_ned_to_enu(float(rig.fleet.att[0, 2]))
    turned = (yaw1 - yaw0 + math.pi) % (2 * math.pi) - math.pi
    assert 0.3 * 2.0 * 0.6 < turned < 0.3 * 2.0 * 1.2  # ψ̇ = ω₃ (eq. 2.4), with the lag
    # Latitude: ω about the horizontal axis ⊥ heading tilts the simulated camera (eq. 2.5).
    # The yaw rate is stopped first: a heading still turning between reading it and the
    # command would tilt about a slightly different axis (seen at load 10).
    rig.run_for(1.5, every=lambda: src.command(np.zeros(3), np.zeros(3), 0.1))
    _, v, _ = src.current()
    psi = math.atan2(v[1], v[0])
    src.command(np.zeros(3), np.array([math.sin(psi), -math.cos(psi), 0.0]) * 0.2, 1.0)
    _, v2, _ = src.current()
    assert math.asin(v2[2]) == pytest.approx(0.2, abs=1e-9)


def test_failsafe_stale_mocap_levels_then_lands(rig: Rig) -> None:
    rig.takeoff(0.8, settle=2.5)
    rig.controller.set_velocity([0.3, 0.0, 0.0], 0.0)
    rig.run_for(0.5)
    rig.feeding = False  # mocap stops: the pose goes stale
    rig.run_for(0.9)
    q = rig.quad
    roll, pitch, _ = (float(a) for a in q.sp_rpy)
    assert rig.driver.phase == "failsafe_hold"
    assert abs(roll) < 1e-9 and abs(pitch) < 1e-9  # level...
    assert q.log.last_thrust == pytest.approx(rig.controller.cfg.model.hover_thrust)  # ...hover
    rig.run_for(6.0)
    assert q.log.has("land") and q.log.has("landed") and not q.armed
    assert rig.position()[2] == pytest.approx(0.0, abs=1e-3)
    assert rig.driver.stats.failsafes == 1


def test_failsafe_recovers_when_mocap_returns(rig: Rig) -> None:
    rig.takeoff(0.8, settle=2.0)
    rig.feeding = False
    rig.run_for(0.8)
    assert rig.driver.phase == "failsafe_hold"
    rig.feeding = True
    rig.run_for(0.5)
    assert rig.driver.phase == "flying" and rig.quad.armed and not rig.quad.log.has("land")


def test_nan_never_leaves_the_process(rig: Rig, monkeypatch: pytest.MonkeyPatch) -> None:
    rig.takeoff(0.8, settle=2.0)
    src = MavlinkPoseSource(rig.driver, rig.pose)
    src.command(np.array([math.nan, 0.0, 0.0]), np.zeros(3), 0.1)
    src.command(np.zeros(3), np.array([0.0, 0.0, math.inf]), 0.1)
    assert src.rejected == 2 and rig.controller.mode == "hold"
    # A controller that goes bad: its NaN set-points are replaced by level hover.
    real_update = rig.controller.update

    def broken(s: FlightState) -> AttitudeSetpoint:
        sp = real_update(s)
        sp.cmd.q[:] = math.nan
        return sp

    with monkeypatch.context() as patch:
        patch.setattr(rig.controller, "update", broken)
        rig.run_for(0.3)
    assert rig.driver.stats.blocked > 5
    q = rig.quad
    assert q.log.rejected_nonfinite == 0 and q.log.rejected_quat == 0
    assert np.all(np.isfinite(q.log.last_q)) and q.armed
    assert rig.position()[2] > 0.5  # still flying


def test_positions_outside_the_space_are_never_commanded(rig: Rig) -> None:
    rig.takeoff(1.0, settle=2.0)
    rig.controller.set_hold([5.0, 0.0, 1.0], 0.0)  # outside Ω: clipped to the margin
    xs: list[float] = []
    rig.run_for(4.0, every=lambda: xs.append(float(rig.position()[0])))
    assert max(xs) <= HI[0]
    assert xs[-1] == pytest.approx(HI[0] - rig.controller.cfg.margin, abs=0.05)
    rig.controller.set_velocity([0.0, 0.0, 0.5], 0.0)  # straight up into the ceiling
    zs: list[float] = []
    rig.run_for(6.0, every=lambda: zs.append(float(rig.position()[2])))
    assert max(zs) <= HI[2]


def test_vehicle_levels_and_holds_when_setpoints_stop(rig: Rig) -> None:
    rig.takeoff(0.8, settle=2.5)
    z0 = float(rig.position()[2])
    rig.driver.streaming = False  # the companion stops talking
    rig.run_for(3.0)
    q = rig.quad
    assert q.log.has("setpoint_timeout") and q.failsafe and q.armed
    assert abs(float(rig.position()[2]) - z0) < 0.1
    assert np.allclose(rig.fleet.att[0, :2], 0.0, atol=1e-3)


def test_vehicle_rejects_non_unit_quaternion(rig: Rig) -> None:
    rig.takeoff(0.8, settle=1.0)
    conn = mavutil.mavlink_connection(f"udpout:127.0.0.1:{rig.quad.port}", source_system=7)
    try:
        for q in ([1.0, 0.1, 0.0, 0.0], [math.nan, 0.0, 0.0, 0.0]):
            conn.mav.set_attitude_target_send(0, 1, 1, 7, q, 0.0, 0.0, 0.0, 0.5)
        assert wait_until(lambda: rig.quad.log.rejected_quat == 1
                     and rig.quad.log.rejected_nonfinite == 1)
    finally:
        conn.close()


def test_dropped_setpoints_and_mocap_still_fly() -> None:
    faults = FaultInjector(FaultConfig(drop_out={"setpoint": 0.3}), seed=4)
    with Rig(faults=faults) as r:
        r.takeoff(0.8, settle=4.0)
        assert r.driver.stats.dropped > 20
        assert abs(float(r.position()[2]) - 0.8) < 0.08


def test_mocap_through_a_lossy_transport() -> None:
    """Poses published on the mocap key through a transport that drops 30 % of them."""
    net = MemoryNetwork()
    gs = net.transport("groundstation")
    agent = net.transport("A", FaultInjector(FaultConfig(drop_in={"mocap": 0.3}), seed=9))
    with Rig() as r:
        feed = ZenohMocapFeed(agent, "m", "A", on_pose=r.driver.notify_pose)
        r.driver.pose = feed
        seq = 0

        def publish() -> None:  # the ground station's side, 100 Hz (sim) from the feeder
            nonlocal seq
            s = r.fleet.mocap(0)
            seq += 1
            msg = MocapPose(drone="A", seq=seq, t=s.t, p=list(map(float, s.p)),
                            q=list(map(float, s.q)), v=list(map(float, s.v)))
            gs.publish(mocap_key("m", "A"), MOCAP_CODEC.encode(msg), kind="mocap")

        r.hook = publish
        r.driver.engage()
        r.controller.set_hold([0.0, 0.0, 0.8], 0.0)
        r.run_for(4.0)
        assert 0.55 < feed.received / seq < 0.85  # about 70 % arrive
        assert abs(float(r.position()[2]) - 0.8) < 0.05
        assert r.driver.stats.failsafes == 0
        feed.close()


def test_sigterm_lands_before_exit(rig: Rig) -> None:
    rig.takeoff(0.8, settle=2.0)
    with land_on_signals(rig.driver, timeout_s=20.0):
        os.kill(os.getpid(), signal.SIGTERM)
        rig.run_for(5.0)  # interrupted by the signal at once
        pytest.fail("SIGTERM did not interrupt")
    q = rig.quad
    assert q.log.has("land") and q.log.has("landed") and not q.armed
    assert rig.position()[2] == pytest.approx(0.0, abs=1e-3)


def test_ardupilot_climb_rate_thrust_without_guid_options() -> None:
    """Without GUID_OPTIONS bit 3 ArduCopter reads thrust 0.5 as "hold altitude"."""
    with Rig(cfg=DriverConfig(set_guid_options=False, mocap_stale_s=0.5)) as r:
        r.driver.engage()
        conn_q = quat_from_euler(0.0, 0.0, 0.0)
        assert r.quad.params_table["GUID_OPTIONS"] == 0
        r.driver.streaming = False
        conn = mavutil.mavlink_connection(f"udpout:127.0.0.1:{r.quad.port}", source_system=7)
        try:
            def climb() -> None:
                conn.mav.set_attitude_target_send(0, 1, 1, 7, list(conn_q), 0, 0, 0, 0.7)

            r.run_for(1.5, every=climb)
            assert r.position()[2] > 0.3  # climbing at (0.7 − 0.5) · 2 · 2.5 m/s
        finally:
            conn.close()


def test_frames_on_the_wire(rig: Rig, monkeypatch: pytest.MonkeyPatch) -> None:
    """The forwarded VISION_POSITION_ESTIMATE is the mocap pose in NED."""
    got: list[Any] = []  # pymavlink's messages (untyped)
    monkeypatch.setattr(rig.quad, "_handle", _tap(rig.quad._handle, got))
    rig.driver.engage()
    rig.controller.set_hold([0.3, -0.2, 0.7], 0.5)
    rig.run_for(3.0)
    m = next(m for m in reversed(got) if m.get_type() == "VISION_POSITION_ESTIMATE")
    p = rig.position()
    np.testing.assert_allclose([m.x, m.y, m.z], enu_to_ned(p), atol=0.05)
    assert m.yaw == pytest.approx(math.pi / 2 - 0.5, abs=0.05)
    assert mavlink.WIRE_PROTOCOL_VERSION == "2.0"


def _tap(handle: Callable[[Any, float], None], out: list[Any]
         ) -> Callable[[Any, float], None]:
    """``handle`` (of pymavlink's untyped messages), keeping every message in ``out``."""

    def tapped(msg: Any, t: float) -> None:
        out.append(msg)
        handle(msg, t)

    return tapped


def test_driver_adopts_the_vehicle_system_id() -> None:
    """Each simulated vehicle has its own system id (i + 1); the driver adopts it."""
    clock = WallClock(SCALE)
    with SimFleet(["A", "B"], clock, VehicleParams()) as fleet:
        fleet.start()
        drv = MavlinkDriver(f"udpout:127.0.0.1:{fleet.quads[1].port}", lambda: None,
                            FlightController(), DriverConfig(), clock)
        with drv:
            drv.wait_heartbeat()
            assert drv.target_system == 2 and drv.conn.mav.srcSystem == 2


def test_serial_connection_strings_carry_the_baud_rate() -> None:
    from agent.flight.driver_types import FlightError, split_baud

    assert split_baud("/dev/ttyAMA0,921600") == ("/dev/ttyAMA0", 921600)
    assert split_baud("/dev/ttyUSB0") == ("/dev/ttyUSB0", 115200)
    assert split_baud("udpout:127.0.0.1:14560") == ("udpout:127.0.0.1:14560", 115200)
    with pytest.raises(FlightError, match="DEVICE,BAUD"):
        split_baud("/dev/ttyAMA0,fast")


def test_mocap_neighbours_are_the_other_drones_heard_recently() -> None:
    net = MemoryNetwork()
    gs = net.transport("groundstation")
    nb = MocapNeighbours(net.transport("A"), "m", "A")

    def pose(drone: str, p: list[float]) -> None:
        msg = MocapPose(drone=drone, seq=1, t=0.0, p=p, q=[1.0, 0.0, 0.0, 0.0], v=[0.0] * 3)
        gs.publish(mocap_key("m", drone), MOCAP_CODEC.encode(msg), kind="mocap")

    pose("A", [0.0, 0.0, 1.0])  # itself: not a neighbour
    pose("B", [1.0, 2.0, 3.0])
    pose("C", [4.0, 5.0, 6.0])
    gs.publish(mocap_key("m", "D"), b"\x93garbage", kind="mocap")  # rejected, not a crash
    net.run_until_idle()
    got = nb.positions()
    assert got.shape == (2, 3)
    assert sorted(map(tuple, got.tolist())) == [(1.0, 2.0, 3.0), (4.0, 5.0, 6.0)]
    time.sleep(0.05)
    assert nb.positions(max_age_s=0.01).shape == (0, 3)  # nothing heard lately
    nb.close()
