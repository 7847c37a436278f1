"""The camera client (agent.flight.camera) against scripted autopilots: the trigger chosen
from what the vehicle advertises (ArduPilot 4.5 CAMERA_INFORMATION, ArduPilot 4.3 DIGICAM,
a PX4 MAVLink camera at component 100), each capture logged against its landmark ids with
the captured message's index, time and pose, retries on a lost ACK or a lost captured
message, and failures reported."""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Iterator

import pytest

from agent.clock import WallClock
from agent.flight.camera import CameraClient, CameraConfig
from agent.flight.driver_types import DriverConfig
from agent.flight.geodetic import Origin
from agent.flight.link import VehicleLink
from agent.wire.mavlink import mavlink
from tests.conftest import wait_until
from tests.flight_peer import Peer

FAST = CameraConfig(discover_timeout_s=0.5, ack_timeout_s=0.3, captured_timeout_s=0.5)
ORIGIN = Origin(47.397742, 8.545594, 488.0)  # the peer's EKF origin


def _camera(peer: Peer) -> Iterator[CameraClient]:
    cfg = DriverConfig(autopilot="px4" if peer.px4 else "ardupilot", ack_timeout_s=0.3)
    with VehicleLink(peer.conn_str, cfg, WallClock()) as link:
        link.wait_heartbeat()
        cam = CameraClient(link, FAST, ORIGIN)
        try:
            yield cam
        finally:
            cam.close()


def _heard_camera(cam: CameraClient) -> Callable[[], bool]:
    return lambda: 100 in cam.cameras


@pytest.fixture
def ardupilot() -> Iterator[tuple[Peer, CameraClient]]:
    with Peer("ardupilot") as peer:
        for cam in _camera(peer):
            yield peer, cam


@pytest.fixture
def px4() -> Iterator[tuple[Peer, CameraClient]]:
    with Peer("px4") as peer:
        for cam in _camera(peer):
            assert wait_until(_heard_camera(cam), 3.0)  # its HEARTBEAT
            yield peer, cam


def test_ardupilot_45_captures_with_image_start_capture(ardupilot: tuple[Peer, CameraClient]
                                                       ) -> None:
    peer, cam = ardupilot
    choice = cam.discover()
    assert (choice.method, choice.component, choice.camera_id) == ("image_start_capture", 1, 0)
    rec = cam.capture([3, 7]).wait(5.0)
    assert rec is not None and rec.status == "captured" and rec.landmark_ids == (3, 7)
    assert rec.image_index == 1 and rec.attempts == 1  # AP_Camera counts from 1
    assert rec.lat_deg == pytest.approx(47.397742) and rec.alt_m == pytest.approx(489.0)
    assert rec.p_world == pytest.approx((0.0, 0.0, 1.0), abs=1e-3)
    roll, pitch, yaw = -0.0, math.radians(-10.0), math.radians(90.0)
    assert rec.q_ned is not None and rec.q_ned[0] == pytest.approx(
        math.cos(yaw / 2) * math.cos(pitch / 2) * math.cos(roll / 2), abs=1e-6)
    cmd = peer.commands(mavlink.MAV_CMD_IMAGE_START_CAPTURE)[0]
    assert (cmd.param1, cmd.param2, cmd.param3, cmd.param4) == (0, 0, 1, 1)
    assert [r.ticket for r in cam.drain()] == [1] and cam.drain() == []
    json.dumps(rec.to_dict())  # journal-able


def test_ardupilot_43_falls_back_to_digicam() -> None:
    with Peer("ardupilot", ardupilot_version=(4, 3)) as peer:
        for cam in _camera(peer):
            assert cam.discover().method == "digicam_control"
            rec = cam.capture([5]).wait(5.0)
            assert rec is not None and rec.status == "captured" and rec.image_index == 1
            cmd = peer.commands(mavlink.MAV_CMD_DO_DIGICAM_CONTROL)[0]
            assert cmd.param5 == 1 and cmd.target_component == 1


def test_px4_camera_component(px4: tuple[Peer, CameraClient]) -> None:
    peer, cam = px4
    choice = cam.discover()
    assert (choice.method, choice.component) == ("image_start_capture", 100)
    assert "Acme Inspect-1" in choice.why
    tickets = [cam.capture([i]) for i in (1, 2, 3)]  # queued, taken one at a time
    recs = [t.wait(5.0) for t in tickets]
    assert [r.status for r in recs if r] == ["captured"] * 3
    assert [r.image_index for r in recs if r] == [0, 1, 2]
    assert [r.landmark_ids for r in recs if r] == [(1,), (2,), (3,)]
    assert recs[0] is not None and recs[0].file_url == "file:///dcim/0000.jpg"
    seqs = [m.param4 for m in peer.commands(mavlink.MAV_CMD_IMAGE_START_CAPTURE)]
    assert seqs == [1, 2, 3]
    # The camera retransmits an image it already reported: ignored, counted.
    lat, lon, alt = peer.origin
    peer.cam_mav.camera_image_captured_send(0, 0, 1, lat, lon, alt, 0, [1.0, 0, 0, 0], 2, 1,
                                            b"file:///dcim/0002.jpg")
    assert wait_until(lambda: cam.duplicates == 1, 3.0) and cam.pending() == 0


def test_lost_ack_resends_the_same_capture(px4: tuple[Peer, CameraClient]) -> None:
    peer, cam = px4
    cam.discover()
    peer.drop_acks[mavlink.MAV_CMD_IMAGE_START_CAPTURE] = 1
    peer.drop_captured = 1  # the first command's image is lost on the way
    rec = cam.capture([4]).wait(5.0)
    assert rec is not None and rec.status == "captured" and rec.attempts == 2
    seqs = [m.param4 for m in peer.commands(mavlink.MAV_CMD_IMAGE_START_CAPTURE)]
    assert seqs == [1, 1]  # resent with its sequence number: no double capture


def test_lost_captured_message_retries_then_fails(ardupilot: tuple[Peer, CameraClient]
                                                  ) -> None:
    peer, cam = ardupilot
    cam.discover()
    peer.drop_captured = 1
    rec = cam.capture([8]).wait(5.0)
    assert rec is not None and rec.status == "captured" and rec.attempts == 2
    peer.drop_captured = 10
    rec = cam.capture([9]).wait(10.0)
    assert rec is not None and rec.status == "failed" and rec.attempts == 3
    assert rec.reason == "no captured message after 3 attempts"


def test_failed_capture_result_and_no_camera() -> None:
    with Peer("px4") as peer:
        for cam in _camera(peer):
            assert wait_until(_heard_camera(cam), 3.0)
            cam.discover()
            peer.capture_result = 0
            rec = cam.capture([1]).wait(10.0)
            assert rec is not None and rec.status == "failed"
            assert "failed capture" in rec.reason
    with Peer("px4", camera=False) as peer:
        for cam in _camera(peer):
            assert cam.discover().method == "none"
            rec = cam.capture([2]).wait(2.0)
            assert rec is not None and rec.status == "failed"
            assert rec.reason.startswith("no camera advertised")
