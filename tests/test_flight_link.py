"""The MAVLink link (agent.flight.link) against a scripted autopilot on loopback UDP: target
adoption, routing by kind, the command protocol (ACKs per component, ours only, retried),
and hostile input that is counted, never raised; resources released on close."""

from __future__ import annotations

import threading
from collections.abc import Iterator
from typing import Any

import pytest

from agent.clock import WallClock
from agent.flight.driver_types import DriverConfig, FlightError
from agent.flight.link import VehicleLink
from agent.wire.mavlink import mavlink
from tests.conftest import wait_until
from tests.flight_peer import Peer, decoded

CFG = DriverConfig(ack_timeout_s=0.3, heartbeat_timeout_s=2.0, retries=3)


@pytest.fixture
def rig() -> Iterator[tuple[Peer, VehicleLink]]:
    with Peer() as peer, VehicleLink(peer.conn_str, CFG, WallClock()) as link:
        link.wait_heartbeat()
        yield peer, link


def test_adopts_the_vehicle_and_routes_by_kind(rig: tuple[Peer, VehicleLink]) -> None:
    peer, link = rig
    assert link.target_system == 1 and link.own_system == 1
    assert link.vehicle.autopilot == mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA
    assert link.flavour.name == "ardupilot"
    got: list[str] = []
    unsub = link.subscribe(("BATTERY_STATUS", "SYS_STATUS"), lambda m: got.append(m.get_type()))
    assert wait_until(lambda: {"BATTERY_STATUS", "SYS_STATUS"} <= set(got), 3.0)
    unsub()
    n = len(got)
    assert wait_until(lambda: link.stats.received > 60, 3.0)
    assert len(got) == n  # unsubscribed
    assert wait_until(lambda: len(peer.received("HEARTBEAT")) >= 1)  # our 1 Hz heartbeat
    hb = peer.received("HEARTBEAT")[0]
    assert hb.type == mavlink.MAV_TYPE_ONBOARD_CONTROLLER and hb.get_srcComponent() == 191


def test_command_retried_until_its_ack(rig: tuple[Peer, VehicleLink]) -> None:
    peer, link = rig
    peer.drop_acks[mavlink.MAV_CMD_COMPONENT_ARM_DISARM] = 2
    assert link.command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1.0) == mavlink.MAV_RESULT_ACCEPTED
    sent = peer.commands(mavlink.MAV_CMD_COMPONENT_ARM_DISARM)
    assert [m.confirmation for m in sent] == [0, 1, 2]
    peer.drop_acks[mavlink.MAV_CMD_COMPONENT_ARM_DISARM] = 5
    with pytest.raises(FlightError, match="no COMMAND_ACK for command 400 after 3 tries"):
        link.command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1.0)


def test_acks_are_kept_per_component_and_only_ours(rig: tuple[Peer, VehicleLink]) -> None:
    _peer, link = rig
    cmd = mavlink.MAV_CMD_IMAGE_START_CAPTURE
    camera_ack = mavlink.MAVLink_command_ack_message(cmd, 0, 0, 0, 1, 191)
    link.on_message(decoded(camera_ack, comp=100))
    assert link.ack_of(cmd, 100) == 0 and link.ack_of(cmd, 1) is None
    gcs_ack = mavlink.MAVLink_command_ack_message(mavlink.MAV_CMD_DO_SET_MODE, 0, 0, 0, 255, 190)
    link.on_message(decoded(gcs_ack))
    assert link.ack_of(mavlink.MAV_CMD_DO_SET_MODE) is None  # a ground station's ACK


def test_hostile_input_is_counted_never_raised(rig: tuple[Peer, VehicleLink]) -> None:
    peer, link = rig

    def boom(_msg: Any) -> None:
        raise RuntimeError("subscriber bug")

    link.subscribe("ATTITUDE", boom)
    assert wait_until(lambda: link.stats.handler_errors > 3, 3.0)

    class Broken:
        def get_type(self) -> str:
            raise ValueError("undecodable")

    link.on_message(Broken())
    bad_before = link.stats.bad
    # Garbage on the wire: a MAVLink 2 start byte with a broken frame, and random bytes.
    sock, addr = peer.conn.port, next(iter(peer.conn.clients))
    for junk in (b"\xfd\x09\x00\x00\x07\x01\x01\x00\x00\x00" + b"\x55" * 11,
                 bytes(range(256)) * 4):
        sock.sendto(junk, addr)
    assert wait_until(lambda: link.stats.bad > bad_before, 3.0)
    n = link.stats.received
    assert wait_until(lambda: link.stats.received > n + 20, 3.0)  # still receiving
    other = mavlink.MAVLink_heartbeat_message(2, 3, 0, 0, 0, 3)
    link.on_message(decoded(other, src=9))
    assert link.stats.foreign >= 1 and link.target_system == 1


def test_close_releases_threads_and_socket() -> None:
    with Peer() as peer:
        before = threading.active_count()
        link = VehicleLink(peer.conn_str, CFG, WallClock()).start()
        link.wait_heartbeat()
        link.close()
        link.close()  # idempotent
        assert link.closed and threading.active_count() <= before
        assert not link.wait(lambda: False, 5.0)  # returns at once once closed


def test_bad_connection_string_is_one_line() -> None:
    with pytest.raises(FlightError, match="bad baud rate"):
        VehicleLink("/dev/ttyAMA0,fast", CFG)
