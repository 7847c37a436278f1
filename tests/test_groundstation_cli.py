"""``viscover groundstation``: flight settings, one-line user errors, and a real run through a
Zenoh router with an observer counting the published poses and following the clock."""

from __future__ import annotations

import collections
import subprocess
import sys
import time
from pathlib import Path

import pytest

from agent.cli import main
from agent.config.flight import drone_ports, flight_path_for, load_flight, parse_flight
from agent.config.scenario import ScenarioError
from agent.net.clocksync import RemoteClock
from agent.net.router import client_config, start_router_process, stop_router_process
from agent.net.transport import ZenohTransport
from agent.wire.ground import MOCAP_CODEC
from tests.conftest import reap, repo_env, scenario_path

CUBE = scenario_path("cube_6_2")


def test_flight_file_defaults_and_overrides(tmp_path: Path) -> None:
    assert flight_path_for("a/b/cube.toml") == Path("a/b/cube.flight.toml")
    sec = load_flight(tmp_path / "none.toml")  # no sibling file: defaults
    assert sec.autopilot == "ardupilot" and sec.rate == 100.0
    sec = parse_flight(
        '[flight]\nautopilot = "px4"\nbase_port = 15000\n[flight.vehicle]\nmass = 2.0\n'
        '[flight.drones.B]\nport = 16000\n[flight.mocap]\nbodies = { cf2 = "B" }\n', "x")
    assert sec.autopilot == "px4" and sec.vehicle.mass == 2.0
    assert drone_ports(sec, ["A", "B", "C"]) == {"A": 15000, "B": 16000, "C": 15002}
    assert sec.mocap.bodies == {"cf2": "B"}


@pytest.mark.parametrize(("text", "match"), [
    ("[flight]\nautopilot = 'inav'\n", "autopilot"),
    ("[flight]\nrat = 5\n", "unknown field"),
    ("[flight.vehicle]\nmass = 'heavy'\n", "Expected `float`"),
    ("[flight\n", "not valid TOML"),
])
def test_flight_file_errors(text: str, match: str) -> None:
    with pytest.raises(ScenarioError, match=match):
        parse_flight(text, "f.toml")


def _run(argv: list[str]) -> int:
    return main(argv)


def test_user_mistakes_are_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert _run(["groundstation", "--source", "sim", "--scenario",
                 str(tmp_path / "missing.toml")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("viscover: error:") and "\n" not in err and "Traceback" not in err
    bad = tmp_path / "bad.flight.toml"
    bad.write_text("[flight]\nautopilot = 'inav'\n")
    assert _run(["groundstation", "--source", "sim", "--scenario", str(CUBE), "--flight",
                 str(bad)]) == 2
    assert "autopilot" in capsys.readouterr().err
    assert _run(["groundstation", "--scenario", str(CUBE), "--source", "motioncapture",
                 "--mocap-type", "vicon"]) == 2
    assert "--mocap-host is required" in capsys.readouterr().err
    assert _run(["groundstation", "--source", "sim", "--scenario", str(CUBE), "--ports",
                 "Z=1234"]) == 2
    assert "Z not agents" in capsys.readouterr().err


def test_groundstation_process_publishes_poses_and_clock() -> None:
    router, endpoint = start_router_process()
    env = repo_env()
    gs = subprocess.Popen(
        [sys.executable, "-m", "agent.cli", "groundstation", "--source", "sim", "--scenario",
         str(CUBE), "--connect", endpoint, "--time-scale", "3", "--duration", "60",
         "--ports", "A=0,B=0,C=0"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    obs = None
    clock = None
    try:
        assert gs.stdout is not None
        ready = gs.stdout.readline()
        assert ready.startswith("viscover-groundstation ready mission=cube_6_2 time_scale=3")
        assert all(f"{d}=udp:127.0.0.1:" in ready for d in "ABC")
        # One ground station (one clock) per mission: a second one is refused in one line.
        second = subprocess.run(
            [sys.executable, "-m", "agent.cli", "groundstation", "--source", "sim", "--scenario",
             str(CUBE), "--connect", endpoint, "--ports", "A=0,B=0,C=0"],
            capture_output=True, text=True, env=env, timeout=60)
        assert second.returncode == 2, second.stderr
        assert second.stderr == ("viscover: error: a ground station is already running for "
                                 "mission cube_6_2 (its clock is on viscover/cube_6_2/clock): "
                                 "stop it first, or use another --mission\n")
        obs = ZenohTransport(client_config(endpoint), None, "observer")
        counts: collections.Counter[str] = collections.Counter()

        def on_pose(k: str, p: bytes) -> None:
            msg = MOCAP_CODEC.decode(p, k)
            if msg is not None:
                counts[msg.drone] += 1

        obs.subscribe("viscover/cube_6_2/mocap/*", on_pose)
        clock = RemoteClock(obs, "cube_6_2")
        assert clock.wait_synced(5.0)
        t0, w0 = clock.now(), time.monotonic()
        time.sleep(1.0)
        sim_elapsed = clock.now() - t0
        # 3× asked; slower only when an overloaded machine dilates simulated time.
        assert 1.0 < sim_elapsed / (time.monotonic() - w0) < 3.1
        # About 100 Hz of simulation time per drone (slack for a shared, loaded machine; the
        # bench measures the rate on a quiet one).
        assert all(counts[d] >= 0.6 * 100 * sim_elapsed for d in "ABC"), counts
        gs.terminate()
        assert gs.wait(10) == 0
    finally:
        if clock is not None:
            clock.close()
        if obs is not None:
            obs.close()
        reap([gs])
        stop_router_process(router)
