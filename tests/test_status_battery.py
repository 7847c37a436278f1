"""``viscover status`` shows each drone's battery (issue 23): a flying agent publishes what
its autopilot reports (BATTERY_STATUS / SYS_STATUS, :class:`agent.flight.battery.
BatteryReader`) in its state (:class:`agent.wire.peer.Battery`, a defaulted field: older
peers still decode, and a state without it decodes as no battery), and the status table and
``launch:`` lines show it ("unknown" for a kinematic agent); the recording keeps it. The
flow is checked end to end in memory: a scripted autopilot's battery, the driver's link, the
reader, the vehicle pose source, the agent runtime's state, the mission watch, the plain
status table."""

from __future__ import annotations

import math
import time
from pathlib import Path

import msgspec
import numpy as np

from agent.clock import ManualClock, WallClock
from agent.config.parse import load_scenario
from agent.flight.battery import BatteryReader
from agent.flight.controllers import FlightController
from agent.flight.driver_types import DriverConfig, PoseSample
from agent.flight.mavlink_driver import MavlinkDriver
from agent.flight.vehicle_pose import MavlinkPoseSource
from agent.mission.status import HEADERS, battery_cell, render_plain, status_lines
from agent.mission.watch import DroneRow, MissionView, MissionWatch
from agent.net.memory import MemoryNetwork
from agent.runtime.shell.runtime import AgentConfig, AgentRuntime
from agent.storage.journal import Journal
from agent.storage.recording import state_document
from agent.wire import keys
from agent.wire.peer import AgentState, Battery
from tests.conftest import scenario_path, wait_until
from tests.flight_peer import Peer
from tests.test_status_identity import PUB, state


def _row(drone: str, battery: Battery | None) -> DroneRow:
    return DroneRow(id=drone, phase="optimising", owned=2, vision=0.5, trades="0 / 0",
                    link="ok", heard="0.1 s ago", mocap="-", fault="-", done=False,
                    battery=battery)


def test_the_status_line_shows_the_battery() -> None:
    assert Battery(pct=74.0, voltage_v=15.314).summary() == "74 %, 15.31 V"
    assert Battery(pct=74.4).summary() == "74 %" and Battery(voltage_v=11.1).summary() == \
        "11.10 V"
    assert Battery().summary() == "unknown" and battery_cell(None) == "unknown"
    view = MissionView(mission="m", rows=[_row("A", Battery(pct=74.0, voltage_v=15.314)),
                                          _row("B", None)],
                       coverage=1.0, seen=4, not_seen=0, unowned=0, elapsed_s=3.0,
                       mission_t=3.0, complete=False, violations=[], rejected=0)
    lines = render_plain(view).splitlines()
    col = lines[0].index("battery")
    assert "battery" in HEADERS and lines[0].split()[:2] == ["drone", "phase"]
    assert lines[1].startswith("A") and lines[1][col:].startswith("74 %, 15.31 V")
    assert lines[2].startswith("B") and lines[2][col:].startswith("unknown")
    said = status_lines(view, "launch: ")
    assert "mocap - battery 74 %, 15.31 V fault -" in said[0]
    assert "battery unknown fault" in said[1]


def test_the_battery_on_the_wire_for_old_and_new_peers() -> None:
    st = msgspec.structs.replace(state("A", 1, 0.0, {3: 0}),
                                 battery=Battery(pct=61.0, voltage_v=16.0))
    got = PUB.decode(PUB.encode(st), keys.state_key("m", "A"))
    assert isinstance(got, AgentState) and got.battery == Battery(pct=61.0, voltage_v=16.0)
    # A state from a build before the field: no battery.
    old = msgspec.msgpack.decode(PUB.encode(st))
    del old["battery"]
    got = PUB.decode(msgspec.msgpack.encode(old), keys.state_key("m", "A"))
    assert isinstance(got, AgentState) and got.battery is None

    class OlderState(msgspec.Struct, tag_field="kind", tag="state"):  # a build without it
        sender: str
        vision: float

    assert msgspec.msgpack.decode(PUB.encode(st), type=OlderState).vision == 0.5
    # Out of range: the state is refused and counted, never raised.
    for bad in ({"pct": 120.0}, {"pct": -1.0}, {"voltage_v": 0.0}, {"pct": math.nan}):
        raw = msgspec.msgpack.decode(PUB.encode(st))
        raw["battery"] = bad
        before = PUB.counter.total
        assert PUB.decode(msgspec.msgpack.encode(raw), keys.state_key("m", "A")) is None
        assert PUB.counter.total == before + 1
    # The recording's state document keeps it (null without one).
    doc = state_document(st, [3], [])
    assert (doc["battery_pct"], doc["battery_v"]) == (61.0, 16.0)
    assert state_document(state("B", 1, 0.0, {}), [], [])["battery_pct"] is None


def test_the_battery_flows_from_the_autopilot_to_viscover_status(tmp_path: Path) -> None:
    """A scripted ArduPilot reports 80 % and 15.8 V, later 42 %: the flying agent's state
    carries it and the status table shows it against its drone; a kinematic agent's row
    says unknown."""
    sc = load_scenario(scenario_path("hexagon_5_3"))
    net = MemoryNetwork()
    watch = MissionWatch(net.transport("status"), "m", sc)
    clock = ManualClock()
    spec = sc.agents[0]
    wall = WallClock()

    def pose() -> PoseSample:  # the vehicle on station at A's initial pose
        return PoseSample(clock.now(), np.asarray(spec.p0, dtype=np.float64), np.zeros(3),
                          np.array([1.0, 0.0, 0.0, 0.0]), time.monotonic())

    journals = [Journal(tmp_path / "A"), Journal(tmp_path / "B")]
    with Peer("ardupilot") as peer, MavlinkDriver(
            peer.conn_str, pose, FlightController(), DriverConfig(ack_timeout_s=0.3,
                                                                  forward="none"),
            wall) as drv:
        drv.wait_heartbeat()
        reader = BatteryReader(drv.link)
        src = MavlinkPoseSource(drv, pose, battery=reader)
        flying = AgentRuntime("A", sc, net.transport("A"), journals[0], clock, pose=src,
                              config=AgentConfig(mission="m"))
        kinematic = AgentRuntime("B", sc, net.transport("B"), journals[1], clock,
                                 config=AgentConfig(mission="m"))
        try:
            assert wait_until(lambda: reader.state.remaining_pct == 80.0, 5.0)
            flying.start()
            kinematic.start()
            rows = {r.id: r for r in watch.view().rows}
            assert rows["A"].battery == Battery(pct=80.0, voltage_v=15.8)
            text = render_plain(watch.view()).splitlines()
            col = text[0].index("battery")
            line = {ln.split()[0]: ln for ln in text[1:4]}
            assert line["A"][col:].startswith("80 %, 15.80 V")
            assert line["B"][col:].startswith("unknown") and line["C"][col:].startswith(
                "unknown")
            peer.battery = {**peer.battery, "pct": 42, "mv": 14900}
            assert wait_until(lambda: reader.state.remaining_pct == 42.0, 5.0)
            clock.advance(1.0)  # past the state period: the next tick publishes
            flying.tick()
            text = render_plain(watch.view()).splitlines()
            assert next(ln for ln in text if ln.startswith("A "))[col:].startswith(
                "42 %, 14.90 V")
        finally:
            flying.stop()
            kinematic.stop()
            reader.close()
            for j in journals:
                j.close()
    watch.close()

