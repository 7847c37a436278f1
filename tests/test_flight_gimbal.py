"""The gimbal client (agent.flight.gimbal) against scripted autopilots: limits discovered
from GIMBAL_MANAGER_INFORMATION, the tilt commanded with DO_GIMBAL_MANAGER_PITCHYAW (PX4
only from its primary control) and measured back, the planner's pose source held to the
gimbal's limits and rate, and the simulated tilt (said in the log) without a gimbal."""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Iterator

import numpy as np
import pytest

from agent.clock import WallClock
from agent.flight.controllers import FlightController
from agent.flight.driver_types import DriverConfig, PoseSample
from agent.flight.gimbal import GimbalClient, GimbalConfig
from agent.flight.link import VehicleLink
from agent.flight.mavlink_driver import MavlinkDriver
from agent.flight.vehicle_pose import MavlinkPoseSource
from agent.wire.mavlink import mavlink
from tests.conftest import wait_until
from tests.flight_peer import Peer, decoded

FAST = GimbalConfig(discover_timeout_s=0.5, command_period_s=0.0)


def _link(peer: Peer) -> VehicleLink:
    cfg = DriverConfig(autopilot="px4" if peer.px4 else "ardupilot", ack_timeout_s=0.3)
    link = VehicleLink(peer.conn_str, cfg, WallClock()).start()
    link.wait_heartbeat()
    return link


@pytest.fixture(params=["ardupilot", "px4"])
def rig(request: pytest.FixtureRequest) -> Iterator[tuple[Peer, GimbalClient]]:
    with Peer(request.param) as peer, _link(peer) as link:
        g = GimbalClient(link, FAST)
        yield peer, g
        g.close()


def test_limits_command_and_measurement(rig: tuple[Peer, GimbalClient]) -> None:
    peer, g = rig
    lim = g.discover()
    assert g.present and not lim.simulated
    assert (lim.pitch_min, lim.pitch_max) == pytest.approx((math.radians(-90), math.radians(20)))
    assert lim.device_id == (0 if peer.px4 else 1)
    assert peer.gimbal_primary == (1, 191)  # we asked to be its primary control
    assert g.set_tilt(-0.5) == -0.5
    assert wait_until(lambda: peer.commands(mavlink.MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW), 3.0)
    cmd = peer.commands(mavlink.MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW)[-1]
    assert cmd.param1 == pytest.approx(math.degrees(-0.5), abs=1e-4) and cmd.param2 == 0
    assert math.isnan(cmd.param3) and math.isnan(cmd.param4)
    assert cmd.param5 == (mavlink.GIMBAL_MANAGER_FLAGS_ROLL_LOCK
                          | mavlink.GIMBAL_MANAGER_FLAGS_PITCH_LOCK)
    assert cmd.param7 == lim.device_id
    assert wait_until(lambda: g.measured() is not None
                      and abs(g.tilt() + 0.5) < 1e-3, 3.0)  # read back
    assert g.set_tilt(1.0) == pytest.approx(math.radians(20))  # above the limit: clamped
    assert g.denied == 0


def test_px4_refuses_a_gimbal_command_from_another_controller() -> None:
    with Peer("px4") as peer, _link(peer) as link:
        g = GimbalClient(link, FAST)
        g.discover()
        peer.gimbal_primary = (255, 190)  # a ground station took control
        g.set_tilt(-0.3)
        assert wait_until(lambda: g.denied == 1, 3.0)
        assert g.take_control() and peer.gimbal_primary == (1, 191)
        g.set_tilt(-0.31)
        assert wait_until(lambda: abs(g.tilt() + 0.31) < 1e-3, 3.0)
        g.close()


def test_no_gimbal_simulates_the_tilt(caplog: pytest.LogCaptureFixture) -> None:
    with Peer("ardupilot", gimbal=False) as peer, _link(peer) as link:
        g = GimbalClient(link, FAST)
        with caplog.at_level(logging.WARNING):
            lim = g.discover()
        assert lim.simulated and not g.present
        assert "camera tilt simulated" in caplog.text
        assert g.set_tilt(0.4) == 0.4 and g.tilt() == 0.4
        assert peer.commands(mavlink.MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW) == []
        g.close()


def test_unreadable_attitude_is_counted() -> None:
    with Peer("ardupilot", gimbal=False) as peer, _link(peer) as link:
        g = GimbalClient(link, FAST)
        bad = mavlink.MAVLink_gimbal_device_attitude_status_message(
            0, 0, 0, 0, [0.0, 0.0, 0.0, 0.0], 0, 0, 0, 0, 0, 0, 1)
        link.on_message(decoded(bad))
        assert g.bad == 1 and g.measured() is None
        g.close()


def test_pose_source_respects_gimbal_limits_and_rate() -> None:
    """The planner's θ̇ (eq. 2.5) goes to the gimbal within its rate and limits; the camera
    direction reports the measured tilt."""
    with Peer("ardupilot") as peer:
        clock = WallClock()

        def pose() -> PoseSample:  # at 1 m, heading east (ENU yaw 0)
            return PoseSample(clock.now(), np.array([0.0, 0.0, 1.0]), np.zeros(3),
                              np.array([1.0, 0.0, 0.0, 0.0]), time.monotonic())

        cfg = DriverConfig(ack_timeout_s=0.3, forward="none")
        with MavlinkDriver(peer.conn_str, pose, FlightController(), cfg, clock) as drv:
            drv.wait_heartbeat()
            g = GimbalClient(drv.link, GimbalConfig(discover_timeout_s=0.5,
                                                    rate_max=math.radians(30),
                                                    command_period_s=0.0))
            g.discover()
            src = MavlinkPoseSource(drv, pose, gimbal=g)
            # The planner's constraint (agent.core.tilt) is the gimbal's pitch range; none
            # with a simulated tilt (the thesis).
            lim = src.tilt_limits()
            assert lim is not None and (lim.lo, lim.hi) == pytest.approx(
                (-math.pi / 2, math.radians(20)))
            assert MavlinkPoseSource(drv, pose).tilt_limits() is None
            # ψ = 0: θ̇ = −ω₂; ask for −2 rad/s for 0.1 s: the gimbal allows 30 °/s.
            src.command(np.zeros(3), np.array([0.0, 2.0, 0.0]), 0.1)
            assert src.latitude.theta == pytest.approx(-math.radians(3.0))
            for _ in range(40):
                src.command(np.zeros(3), np.array([0.0, 2.0, 0.0]), 0.1)
            # At the limit (the integrator keeps 1 mrad off the pole, where tan θ blows up).
            assert src.latitude.theta == pytest.approx(math.radians(-90), abs=2e-3)
            assert wait_until(lambda: abs(src.tilt() - math.radians(-90)) < 2e-3, 5.0)
            _p, v, _t = src.current()
            assert v[2] == pytest.approx(-1.0, abs=1e-3)  # looking straight down
            g.close()
