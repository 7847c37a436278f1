"""One battery per simulated vehicle: ``viscover groundstation --battery-capacity ID=MAH,...``
gives the named vehicles their own pack (the others keep the flight file's), down to the
physics and each autopilot's battery monitor; a bad entry is one line naming it."""

from __future__ import annotations

import argparse
from pathlib import Path

import pytest

from agent.cli import main
from agent.clock import ManualClock
from agent.config.flight import load_flight
from agent.config.parse import load_scenario
from groundstation.cli import _sim_fleet
from tests.conftest import scenario_path

CUBE = scenario_path("cube_6_2")


def _args(packs: str, ports: str = "A=0,B=0,C=0") -> argparse.Namespace:
    return argparse.Namespace(battery_capacity=packs, origin=None, gnss=None,
                              ports={p.split("=")[0]: 0 for p in ports.split(",")})


@pytest.mark.parametrize("autopilot", ["ardupilot", "px4"])
def test_each_vehicle_draws_on_its_own_pack(tmp_path: Path, autopilot: str) -> None:
    """A with 1200 mAh, the others the flight file's 5000 mAh: the same charge drawn leaves A
    with 5000 / 1200 times the others' fraction used, and each autopilot's monitor sees it
    (ArduPilot counts against its BATT_CAPACITY, the pack's; PX4 reads the cell voltage)."""
    flight_file = tmp_path / "cube.flight.toml"
    flight_file.write_text(f'[flight]\nautopilot = "{autopilot}"\n[flight.vehicle]\n'
                           'battery_mah = 5000\n', encoding="utf-8")
    scenario = load_scenario(CUBE)
    flight = load_flight(CUBE, flight_file)
    fleet = _sim_fleet(_args("A=1200"), scenario, flight, ManualClock())
    try:
        assert [p.battery_mah for p in fleet.params] == [1200.0, 5000.0, 5000.0]
        assert list(fleet.physics.battery_mah) == [1200.0, 5000.0, 5000.0]
        if autopilot == "ardupilot":
            assert [q.params_table["BATT_CAPACITY"] for q in fleet.quads] == [1200, 5000, 5000]
        fleet.dt = 0.05  # disarmed on the ground: coarse steps are exact enough
        fleet.step_to(600.0)  # ten minutes of the idle current
        used = [float(fleet.state.consumed[q.i]) for q in fleet.quads]
        assert used[0] > 50.0 and used == pytest.approx([used[0]] * 3)  # same current drawn
        soc = [q.battery_reading().soc for q in fleet.quads]
        assert (1.0 - soc[0]) / (1.0 - soc[1]) == pytest.approx(5000.0 / 1200.0, rel=1e-6)
        fleet.state.consumed += 400.0  # as after a flight: A's small pack is a third gone
        readings = [q.battery_reading() for q in fleet.quads]
        remaining = [r.remaining for r in readings if r.remaining is not None]
        assert len(remaining) == len(readings)  # every pack reports it
        assert remaining[0] < 0.75 < remaining[1] == remaining[2]
        assert readings[0].voltage < readings[1].voltage
    finally:
        fleet.close()


@pytest.mark.parametrize(("packs", "needle"), [
    ("A=x", "'A=x': expected ID=MAH"),
    ("A=0", "'A=0': expected ID=MAH"),
    ("A=-5", "'A=-5': expected ID=MAH"),
    ("A=nan", "'A=nan': expected ID=MAH"),
    ("=500", "'=500': expected ID=MAH"),
    ("A", "'A': expected ID=MAH"),
    ("Z=1000", "'Z=1000': Z is not an agent of the scenario (A, B, C)"),
    ("A=1000,A=2000", "'A=2000': A is given twice"),
])
def test_bad_entries_are_one_line_naming_them(capsys: pytest.CaptureFixture[str], packs: str,
                                              needle: str) -> None:
    assert main(["groundstation", "--source", "sim", "--scenario", str(CUBE),
                 "--battery-capacity", packs]) == 2
    err = capsys.readouterr().err.strip()
    assert needle in err and "\n" not in err and "Traceback" not in err


def test_real_drones_carry_their_own_packs(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["groundstation", "--source", "motioncapture", "--scenario", str(CUBE),
                 "--mocap-type", "mock", "--battery-capacity", "A=1200"]) == 2
    err = capsys.readouterr().err.strip()
    assert "--battery-capacity applies to the simulator only" in err and "\n" not in err
