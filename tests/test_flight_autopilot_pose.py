"""Pose from the autopilot (agent.flight.autopilot_pose): the EKF's local NED estimate in the
mission's world ENU frame at a shared geodetic origin, from LOCAL_POSITION_NED + ATTITUDE or
ODOMETRY; a wrong site or a missing origin refused in one line; bad samples dropped; and the
driver's stale-pose failsafe when the estimate stops."""

from __future__ import annotations

import math
from collections.abc import Iterator

import numpy as np
import pytest

from agent.clock import WallClock
from agent.flight.autopilot_pose import AutopilotPose
from agent.flight.controllers import FlightConfig, FlightController
from agent.flight.driver_types import DriverConfig, FlightError
from agent.flight.field import use_autopilot_pose
from agent.flight.frames import yaw_from_quat
from agent.flight.geodetic import LocalToWorld, Origin, enu_to_geodetic, geodetic_to_enu
from agent.flight.link import VehicleLink
from agent.flight.mavlink_driver import MavlinkDriver
from agent.wire.mavlink import mavlink
from tests.conftest import wait_until
from tests.flight_peer import Peer, decoded

EKF = Origin(47.397742, 8.545594, 488.0)  # the peer's GPS_GLOBAL_ORIGIN


def _site(east: float, north: float, up: float) -> Origin:
    """The geodetic point (east, north, up) [m] from the EKF origin."""
    lat, lon, alt = enu_to_geodetic([east, north, up], EKF)
    return Origin(float(lat), float(lon), float(alt))


def test_local_to_world_is_the_geodetic_map() -> None:
    world = _site(-120.0, 40.0, -3.0)  # the mission origin 120 m west of the EKF's
    fr = LocalToWorld.between(EKF, world)
    assert fr.distance_m == pytest.approx(math.sqrt(120**2 + 40**2 + 3**2), abs=1e-3)
    p_local = np.array([[10.0, 5.0, 3.0], [-50.0, 80.0, 12.0]])
    lat, lon, alt = enu_to_geodetic(p_local, EKF)
    np.testing.assert_allclose(fr.point(p_local), geodetic_to_enu(lat, lon, alt, world),
                               atol=1e-6)
    np.testing.assert_allclose(fr.point([0.0, 0.0, 0.0]), [120.0, -40.0, 3.0], atol=0.02)
    np.testing.assert_allclose(fr.rotation @ fr.rotation.T, np.eye(3), atol=1e-12)
    same = LocalToWorld.between(EKF, None)
    np.testing.assert_allclose(same.point([1.0, 2.0, 3.0]), [1.0, 2.0, 3.0])


@pytest.fixture
def link() -> Iterator[tuple[Peer, VehicleLink]]:
    with Peer("px4") as peer, VehicleLink(peer.conn_str, DriverConfig(autopilot="px4"),
                                          WallClock()) as lk:
        lk.wait_heartbeat()
        yield peer, lk


def test_local_ned_and_attitude_into_the_world_frame(link: tuple[Peer, VehicleLink]) -> None:
    peer, lk = link
    peer.pose_ned = [10.0, 5.0, -3.0, 1.0, 0.5, -0.2]  # north, east, down [m], [m/s]
    peer.rpy = [0.0, 0.0, 0.0]  # heading north
    world = _site(-100.0, 0.0, 0.0)  # the mission origin 100 m west of the EKF origin
    pose = AutopilotPose(lk, world)
    pose.wait_ready(5.0)
    assert wait_until(lambda: pose.home_world is not None and pose.received > 3, 3.0)
    s = pose()
    assert s is not None
    np.testing.assert_allclose(s.p, [105.0, 10.0, 3.0], atol=0.02)  # east, north, up
    np.testing.assert_allclose(s.vel, [0.5, 1.0, 0.2], atol=1e-3)
    assert yaw_from_quat(s.q) == pytest.approx(math.pi / 2, abs=2e-3)  # north in ENU
    assert pose.home_world is not None
    np.testing.assert_allclose(pose.home_world, [100.0, 0.0, 0.0], atol=0.02)
    pose.close()


def test_odometry_with_body_velocity(link: tuple[Peer, VehicleLink]) -> None:
    peer, lk = link
    peer.pose_ned = [1.0, 2.0, -4.0, 1.0, 0.0, 0.0]
    peer.rpy = [0.0, 0.0, math.pi / 2]  # heading east
    peer.odometry = True
    pose = AutopilotPose(lk, None)
    pose.wait_ready(5.0)
    assert wait_until(lambda: pose.received > 3, 3.0)  # past any message still in flight
    s = pose()
    assert s is not None
    np.testing.assert_allclose(s.p, [2.0, 1.0, 4.0], atol=1e-6)
    np.testing.assert_allclose(s.vel, [0.0, 1.0, 0.0], atol=1e-6)  # LOCAL_NED: north
    assert yaw_from_quat(s.q) == pytest.approx(0.0, abs=1e-6)  # east in ENU
    body = mavlink.MAVLink_odometry_message(
        10**12, mavlink.MAV_FRAME_LOCAL_NED, mavlink.MAV_FRAME_BODY_FRD, 1.0, 2.0, -4.0,
        [math.cos(math.pi / 4), 0.0, 0.0, math.sin(math.pi / 4)], 1.0, 0.0, 0.0, 0, 0, 0,
        [math.nan] * 21, [math.nan] * 21, 0, mavlink.MAV_ESTIMATOR_TYPE_AUTOPILOT, 100)
    peer.stream_pose = False
    lk.on_message(decoded(body))
    s = pose()
    assert s is not None
    np.testing.assert_allclose(s.vel, [1.0, 0.0, 0.0], atol=1e-6)  # forward = east
    pose.close()


def test_bad_samples_are_dropped(link: tuple[Peer, VehicleLink]) -> None:
    peer, lk = link
    pose = AutopilotPose(lk, None)
    pose.wait_ready(5.0)
    peer.stream_pose = False
    n, dropped = pose.received, pose.dropped
    lk.on_message(decoded(mavlink.MAVLink_attitude_message(0, 0.0, 0.0, 0.0, 0, 0, 0)))
    stale = mavlink.MAVLink_local_position_ned_message(1, 9.0, 9.0, 9.0, 0, 0, 0)  # old time
    nan = mavlink.MAVLink_local_position_ned_message(2**31, math.nan, 0, 0, 0, 0, 0)
    vision = mavlink.MAVLink_odometry_message(
        2**40, mavlink.MAV_FRAME_LOCAL_NED, mavlink.MAV_FRAME_LOCAL_NED, 0, 0, 0,
        [1.0, 0, 0, 0], 0, 0, 0, 0, 0, 0, [0.0] * 21, [0.0] * 21, 0,
        mavlink.MAV_ESTIMATOR_TYPE_VISION, 100)  # our own mocap looped back
    for m in (stale, nan, vision):
        lk.on_message(decoded(m))
    assert pose.received == n and pose.dropped == dropped + 3
    pose.close()


def test_wrong_site_and_missing_origin_are_one_line(link: tuple[Peer, VehicleLink],
                                                    monkeypatch: pytest.MonkeyPatch) -> None:
    peer, lk = link
    far = AutopilotPose(lk, _site(30_000.0, 0.0, 0.0), max_origin_offset_m=5000.0)
    with pytest.raises(FlightError, match=r"EKF origin is 30000 m from the mission origin"):
        far.wait_ready(3.0)
    far.close()
    peer.origin = (0, 0, 0)
    monkeypatch.setattr(peer, "_origin", lambda: False)  # no EKF origin yet
    none = AutopilotPose(lk, EKF)
    with pytest.raises(FlightError, match="no GPS_GLOBAL_ORIGIN from the autopilot"):
        none.wait_ready(0.5)
    none.close()


def test_stale_estimate_trips_the_failsafe() -> None:
    with Peer("ardupilot") as peer:
        clock = WallClock()
        ctl = FlightController(FlightConfig(lo=(-50, -50, 0), hi=(50, 50, 20)))
        drv = MavlinkDriver(peer.conn_str, lambda: None, ctl,
                            DriverConfig(mocap_stale_s=0.2, failsafe_hold_s=100.0), clock)
        try:
            drv.link.start()  # receive only: the stream is stepped by hand
            drv.wait_heartbeat()
            use_autopilot_pose(drv, EKF, 5.0)
            assert drv.cfg.forward == "none"
            drv.streaming, drv.phase = True, "flying"
            drv._step()
            assert drv.phase == "flying" and drv.stats.sent >= 1
            peer.stream_pose = False
            assert wait_until(lambda: drv.phase == "failsafe_hold", 3.0, poll_s=0.05,
                              poke=drv._step)
            assert drv.failsafe_reason.startswith("newest pose") and drv.stats.forwarded == 0
            peer.stream_pose = True
            assert wait_until(lambda: drv.phase == "flying", 3.0, poll_s=0.05,
                              poke=drv._step)
        finally:
            drv.close()
