"""Autopilot flavours (agent.flight.flavours): modes, the exact MAV_CMD_DO_SET_MODE
parameters, engage and land of each autopilot against a scripted peer (PX4 refuses OFFBOARD
without a live set-point stream, as its commander does), and no string branch on the
autopilot's name left in the flight code."""

from __future__ import annotations

import re
import time
from collections.abc import Iterator

import numpy as np
import pytest

from agent.clock import WallClock
from agent.flight.controllers import FlightConfig, FlightController
from agent.flight.driver_types import DriverConfig, PoseSample
from agent.flight.flavours import PX4, ArduPilot, flavour, flavour_of_heartbeat
from agent.flight.mavlink_driver import MavlinkDriver
from agent.flight.monitor import VehicleMonitor, mode_name
from agent.wire.mavlink import mavlink, px4_custom_mode
from tests.conftest import ROOT, wait_until
from tests.flight_peer import Peer


def test_names_and_heartbeat_ids() -> None:
    assert isinstance(flavour("ardupilot"), ArduPilot) and isinstance(flavour("px4"), PX4)
    with pytest.raises(ValueError, match="autopilot must be one of ardupilot, px4, got 'inav'"):
        flavour("inav")
    assert flavour_of_heartbeat(mavlink.MAV_AUTOPILOT_PX4) is flavour("px4")
    assert flavour_of_heartbeat(mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA) is flavour("ardupilot")
    assert flavour_of_heartbeat(mavlink.MAV_AUTOPILOT_GENERIC) is None
    with pytest.raises(ValueError, match="got 'inav'"):
        DriverConfig(autopilot="inav")


def test_modes() -> None:
    ap, px = flavour("ardupilot"), flavour("px4")
    assert ap.mode_name(20) == "GUIDED_NOGPS" and ap.mode_name(99) == "MODE_99"
    land = px4_custom_mode(4, 6)
    assert px.mode_name(land) == "AUTO.LAND" and mode_name("px4", land | 0x1234) == "AUTO.LAND"
    assert px.in_control_mode(px4_custom_mode(6) | 0x00FF) and not px.in_control_mode(land)
    assert ap.in_control_mode(20) and not ap.in_control_mode(4)
    assert ap.set_mode_params(20) == ([1.0, 20.0], 20)
    assert px.set_mode_params(4, 6) == ([1.0, 4.0, 6.0], land)
    mon = VehicleMonitor(px, px.control_modes(), 1)
    assert mon.autopilot == "px4"


def _driver(peer: Peer, autopilot: str) -> MavlinkDriver:
    clock = WallClock()

    def pose() -> PoseSample:  # a vehicle standing still at 1 m, stamped now
        return PoseSample(clock.now(), np.array([0.0, 0.0, 1.0]), np.zeros(3),
                          np.array([1.0, 0.0, 0.0, 0.0]), time.monotonic())

    cfg = DriverConfig(autopilot=autopilot, ack_timeout_s=0.3, heartbeat_timeout_s=2.0,
                       prestream_s=0.6, forward="none")
    return MavlinkDriver(peer.conn_str, pose, FlightController(FlightConfig()), cfg, clock)


@pytest.fixture(params=["ardupilot", "px4"])
def flown(request: pytest.FixtureRequest) -> Iterator[tuple[Peer, MavlinkDriver]]:
    with Peer(request.param) as peer, _driver(peer, request.param) as drv:
        yield peer, drv


def test_engage_and_land_speak_each_autopilots_dialect(flown: tuple[Peer, MavlinkDriver]
                                                       ) -> None:
    peer, drv = flown
    drv.engage()
    assert peer.armed and drv.phase == "flying" and drv.streaming
    modes = peer.commands(mavlink.MAV_CMD_DO_SET_MODE)
    arm = peer.commands(mavlink.MAV_CMD_COMPONENT_ARM_DISARM)[0]
    names = [k for k, _ in peer.log]
    if peer.px4:
        assert [(m.param1, m.param2, m.param3) for m in modes] == [(1, 6, 0)]
        assert peer.custom_mode == px4_custom_mode(6)
        first_sp = names.index("SET_ATTITUDE_TARGET")  # streamed before the switch
        assert first_sp < names.index("COMMAND_LONG")
    else:
        assert peer.params["GUID_OPTIONS"] == 8  # bit 3: thrust is thrust
        assert [(m.param1, m.param2) for m in modes] == [(1, 20)]
        assert names.index("PARAM_SET") < peer.log.index(("COMMAND_LONG", modes[0]))
    assert peer.log.index(("COMMAND_LONG", modes[0])) < peer.log.index(("COMMAND_LONG", arm))
    assert drv.land(wait=False)
    last = peer.commands(mavlink.MAV_CMD_DO_SET_MODE)[-1]
    assert (last.param2, last.param3) == ((4, 6) if peer.px4 else (9, 0))
    assert drv.phase == "landing" and not drv.streaming


def test_px4_without_a_stream_refuses_offboard() -> None:
    with Peer("px4") as peer, _driver(peer, "px4") as drv:
        drv.wait_heartbeat()
        with pytest.raises(Exception, match="refused"):
            drv.set_mode(6)
        assert wait_until(lambda: drv.vehicle.custom_mode == 0)


def test_no_string_branches_on_the_autopilot_left() -> None:
    """The autopilot kind is no longer compared as a string in the flight code (the
    flavours, and the rule tables keyed by flavour name, are the only places names live)."""
    branch = re.compile(r"""(==|!=|\bin\b)\s*\(?\s*["'](ardupilot|px4)["']""")
    found = [f"{p.name}:{n}" for p in sorted((ROOT / "agent" / "flight").glob("*.py"))
             for n, line in enumerate(p.read_text().splitlines(), 1) if branch.search(line)]
    assert found == []
