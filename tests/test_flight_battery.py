"""The battery state (agent.flight.battery) from BATTERY_STATUS and SYS_STATUS: MAVLink's
units and unknown markers, the pack voltage from cell voltages, SYS_STATUS filling gaps,
out-of-range values refused, and the hand-over rule."""

from __future__ import annotations

import json
from collections.abc import Iterator

import pytest

from agent.clock import WallClock
from agent.flight.battery import BatteryReader, BatteryState, hand_over_needed
from agent.flight.driver_types import DriverConfig
from agent.flight.link import VehicleLink
from agent.wire.mavlink import mavlink
from tests.conftest import wait_until
from tests.flight_peer import Peer, decoded

U16 = 65535


def _battery(pct: int = 60, cells: list[int] | None = None, ca: int = 2150, mah: int = 1800,
             left: int = 0, state: int = 1, ext: list[int] | None = None, bid: int = 0) -> object:
    cells = cells or [4100, 4100, 4050, 4050] + [U16] * 6
    return mavlink.MAVLink_battery_status_message(bid, 0, 0, 2500, cells, ca, mah, -1, pct,
                                                  left, state, ext or [0, 0, 0, 0], 0, 0)


def _sys(mv: int = 16000, ca: int = 2000, pct: int = 61) -> object:
    return mavlink.MAVLink_sys_status_message(0, 0, 0, 0, mv, ca, pct, 0, 0, 0, 0, 0, 0)


@pytest.fixture
def reader() -> Iterator[tuple[VehicleLink, BatteryReader]]:
    # A link to a silent address: every message is fed by hand.
    link = VehicleLink("udpout:127.0.0.1:9", DriverConfig(target_system=1), WallClock())
    r = BatteryReader(link, prefer_s=60.0)
    yield link, r
    r.close()
    link.close()


def test_battery_status_in_si_units(reader: tuple[VehicleLink, BatteryReader]) -> None:
    link, r = reader
    assert r.state == BatteryState() and r.state.summary() == "? %"
    link.on_message(decoded(_battery()))
    s = r.state
    assert (s.remaining_pct, s.voltage_v, s.current_a, s.consumed_mah) == (60, 16.3, 21.5, 1800)
    assert s.source == "BATTERY_STATUS" and s.charge_state == 1 and s.time_remaining_s is None
    assert s.summary() == "60 %, 16.30 V, 21.5 A"
    json.dumps(s.to_dict())
    # Cells 11-14 in voltages_ext; a pack above 65.534 V continues in cell 1.
    link.on_message(decoded(_battery(cells=[4000] * 10, ext=[4000, 4000, 0, 0])))
    assert r.state.voltage_v == pytest.approx(48.0)
    link.on_message(decoded(_battery(cells=[65534, 4466] + [U16] * 8)))
    assert r.state.voltage_v == pytest.approx(70.0)
    link.on_message(decoded(_battery(bid=1, pct=5)))  # another battery: not this one
    assert r.state.remaining_pct == 60


def test_unknowns_and_sys_status_fallback(reader: tuple[VehicleLink, BatteryReader]) -> None:
    link, r = reader
    link.on_message(decoded(_sys(mv=U16, ca=-1, pct=-1)))
    assert r.state == BatteryState(source="SYS_STATUS", t=r.state.t)  # all unknown
    link.on_message(decoded(_sys()))
    assert (r.state.remaining_pct, r.state.voltage_v, r.state.current_a) == (61, 16.0, 20.0)
    link.on_message(decoded(_battery(pct=-1, ca=-1, cells=[U16] * 10)))
    s = r.state  # BATTERY_STATUS knows only the consumed charge: SYS_STATUS fills the rest
    assert (s.remaining_pct, s.voltage_v, s.current_a, s.consumed_mah) == (61, 16.0, 20.0, 1800)
    assert s.source == "BATTERY_STATUS+SYS_STATUS"


def test_out_of_range_values_are_refused(reader: tuple[VehicleLink, BatteryReader]) -> None:
    link, r = reader
    link.on_message(decoded(_battery(pct=120)))
    link.on_message(decoded(_sys(pct=101)))
    assert r.rejected == 2 and r.state.remaining_pct is None
    link.on_message(decoded(_battery(), comp=100))  # a camera's battery is not the vehicle's
    assert r.state.remaining_pct is None


def test_endurance_and_hand_over() -> None:
    s = BatteryState(remaining_pct=50.0, current_a=20.0)
    assert s.endurance_s() is None
    assert s.endurance_s(capacity_mah=5000.0) == pytest.approx(450.0)  # 2.5 Ah at 20 A
    assert BatteryState(time_remaining_s=300.0).endurance_s(5000.0) == 300.0
    assert not hand_over_needed(s, needed_s=300.0, capacity_mah=5000.0)  # 360 s usable
    assert hand_over_needed(s, needed_s=400.0, capacity_mah=5000.0)
    assert hand_over_needed(BatteryState(remaining_pct=25.0), needed_s=10.0)  # floor 30 %
    assert not hand_over_needed(BatteryState(), needed_s=1e9)  # unknown: no decision


def test_from_a_vehicle() -> None:
    with Peer("px4") as peer, VehicleLink(peer.conn_str, DriverConfig(autopilot="px4"),
                                          WallClock()) as link:
        link.wait_heartbeat()
        r = BatteryReader(link)
        assert wait_until(lambda: r.state.source == "BATTERY_STATUS", 3.0)
        assert r.state.summary() == "80 %, 15.80 V, 12.0 A"
        peer.battery["pct"] = 20
        assert wait_until(lambda: r.state.remaining_pct == 20, 3.0)
        r.close()
