"""A flying agent as a process (router, ground station with simulated vehicles, one
``viscover agent --mavlink``): its phase lines, a pilot taking the vehicle over (the agent
stops commanding, says why in one line, its liveliness token vanishes, it exits 1 and the
vehicle stays in the pilot's mode), and a pre-flight refusal on a wrongly configured
autopilot (one line, exit 2, never armed); the operator's ``land`` (home, then land) and
``stop`` (land where it is) obeyed by flying agents, each departure announced on the mesh."""

from __future__ import annotations

import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from agent.net.router import client_config, start_router_process, stop_router_process
from agent.net.transport import ZenohTransport
from agent.wire.departure import DEPARTURE_CODEC
from agent.wire.ground import MOCAP_CODEC
from agent.wire.mavlink import ARDUPILOT_MODES, mavlink, mavutil
from tests.conftest import repo_env, scenario_path, stop_process, wait_until

CUBE = scenario_path("cube_6_2")


@pytest.fixture
def ground(tmp_path: Path, request: pytest.FixtureRequest) -> Iterator[dict[str, Any]]:
    """Router and ground station (3× real time); ``request.param`` is an optional flight
    file text for the ground station's vehicles."""
    router, endpoint = start_router_process()
    flight = getattr(request, "param", None)
    extra: list[str] = []
    if flight is not None:
        (tmp_path / "f.toml").write_text(flight)
        extra = ["--flight", str(tmp_path / "f.toml")]
    gs = subprocess.Popen(
        [sys.executable, "-m", "agent.cli", "groundstation", "--source", "sim", "--scenario",
         str(CUBE), "--connect", endpoint, "--time-scale", "3", "--ports", "A=0,B=0,C=0",
         *extra],
        stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True, env=repo_env())
    try:
        assert gs.stdout is not None
        ready = gs.stdout.readline()
        ports = {d: int(ready.split(f"{d}=udp:")[1].split()[0].rsplit(":", 1)[1])
                 for d in "ABC"}
        yield {"endpoint": endpoint, "port": ports["A"], "ports": ports, "extra": extra}
    finally:
        stop_process(gs, grace_s=20.0)
        stop_router_process(router)


def _agent(g: dict[str, Any], tmp_path: Path, aid: str = "A") -> subprocess.Popen[str]:
    return subprocess.Popen(
        [sys.executable, "-m", "agent.cli", "agent", "--id", aid, "--scenario", str(CUBE),
         "--connect", g["endpoint"], "--mavlink", f"udpout:127.0.0.1:{g['ports'][aid]}",
         "--state-dir", str(tmp_path / aid), "--mocap-stale", "0.6", "--timeout", "60",
         *g["extra"]],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=repo_env())


def test_pilot_takes_over_and_the_agent_leaves(ground: dict[str, Any], tmp_path: Path) -> None:
    obs = ZenohTransport(client_config(ground["endpoint"]), None, "observer")
    departures: list[Any] = []
    obs.subscribe("viscover/cube_6_2/departure/*",
                  lambda k, p: departures.append(DEPARTURE_CODEC.decode(p, k)))
    alive: list[tuple[float, str]] = []
    obs.watch_liveliness("viscover/cube_6_2/alive/*",
                         lambda k: alive.append((time.monotonic(), "join " + k)),
                         lambda k: alive.append((time.monotonic(), "leave " + k)))
    agent = _agent(ground, tmp_path)
    gcs = None
    try:
        assert agent.stdout is not None and agent.stderr is not None
        line = agent.stdout.readline()
        assert line.startswith("viscover-flight-agent hovering id=A"), agent.stderr.read()
        time.sleep(1.0)
        assert ("join viscover/cube_6_2/alive/A" in [a for _, a in alive])
        gcs = mavutil.mavlink_connection(f"udpout:127.0.0.1:{ground['port']}",
                                         source_system=255, source_component=190)
        t_switch = time.monotonic()
        gcs.mav.command_long_send(1, 1, mavlink.MAV_CMD_DO_SET_MODE, 0,
                                  mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED,
                                  ARDUPILOT_MODES["LOITER"], 0, 0, 0, 0, 0)
        assert agent.wait(30) == 1
        err = agent.stderr.read()
        phases = [x.split(": ", 1)[1] for x in err.splitlines()
                  if x.startswith("viscover-flight-agent A: ")]
        # a loaded machine may starve the mocap for a moment: "mocap lost ... / mocap back"
        # lines then come between the phases, which are what this test is about
        phases = [p for p in phases if not p.startswith("mocap ")]
        names = [p.split(" ")[0] for p in phases]
        assert names[:6] == ["connected", "pre-flight", "armed", "took", "on", "left"], phases
        assert phases[5].startswith("left the mission: mode changed to LOITER (5)")
        assert "landing" not in names  # no LAND commanded over the pilot
        leave = [t for t, a in alive if a == "leave viscover/cube_6_2/alive/A"]
        assert leave and leave[0] - t_switch < 5.0  # 1 s HEARTBEAT + a tick at 3x, with slack
        assert [(d.sender, d.reason) for d in departures[:1]] == [("A", "pilot")]
        assert departures[0].detail.startswith("mode changed to LOITER (5)")
        # The vehicle stays where the pilot put it: LOITER, armed, flying.
        hb: list[Any] = []
        end = time.monotonic() + 3.0
        while time.monotonic() < end and len(hb) < 2:
            m = gcs.recv_match(type="HEARTBEAT", blocking=True, timeout=1.0)
            if m is not None and m.get_srcSystem() == 1 and m.autopilot != 8:
                hb.append(m)
        assert hb and all(m.custom_mode == 5 and m.base_mode & 128 for m in hb)
    finally:
        if gcs is not None:
            gcs.close()
        stop_process(agent, grace_s=20.0)
        obs.close()


@pytest.mark.parametrize("ground", ['[flight.vehicle]\nparams = { VISO_TYPE = 0 }\n'],
                         indirect=True)
def test_preflight_refuses_before_take_off(ground: dict[str, Any], tmp_path: Path) -> None:
    agent = _agent(ground, tmp_path)
    try:
        assert agent.wait(30) == 2
        assert agent.stdout is not None and agent.stderr is not None
        assert agent.stdout.read() == ""
        errors = [x for x in agent.stderr.read().splitlines() if x.startswith("viscover: error")]
        assert len(errors) == 1
        assert errors[0].startswith("viscover: error: A: pre-flight: VISO_TYPE = 0, needs "
                                    "non-zero (1 MAVLink): set VISO_TYPE 1 (MAVLink) and reboot")
    finally:
        stop_process(agent, grace_s=20.0)




def _mocap_track(obs: ZenohTransport) -> dict[str, list[tuple[float, float, float]]]:
    """Every mocap position [m; world ENU] per drone, as it arrives."""
    track: dict[str, list[tuple[float, float, float]]] = {"A": [], "B": []}

    def on_pose(k: str, p: bytes) -> None:
        msg = MOCAP_CODEC.decode(p, k)
        if msg is not None and msg.drone in track:
            track[msg.drone].append((msg.p[0], msg.p[1], msg.p[2]))

    obs.subscribe("viscover/cube_6_2/mocap/*", on_pose)
    return track


def test_operator_land_goes_home_and_stop_lands_where_it_is(ground: dict[str, Any],
                                                           tmp_path: Path) -> None:
    """Mid-mission, once B flew away from its launch point: ``land`` to B (it flies home,
    then lands) and ``stop`` to A (it lands where it is); both exit 0 and announce why they
    left."""
    obs = ZenohTransport(client_config(ground["endpoint"]), None, "observer")
    track = _mocap_track(obs)
    departures: list[Any] = []
    obs.subscribe("viscover/cube_6_2/departure/*",
                  lambda k, p: departures.append(DEPARTURE_CODEC.decode(p, k)))
    agents = {a: _agent(ground, tmp_path, a) for a in "AB"}
    try:
        for a, proc in agents.items():
            assert proc.stdout is not None
            line = proc.stdout.readline()
            assert line.startswith(f"viscover-flight-agent hovering id={a}"), line
        home = {a: np.array(track[a][0][:2]) for a in "AB"}

        def away(a: str) -> float:
            return float(np.linalg.norm(np.array(track[a][-1][:2]) - home[a]))

        # B travels far in the cube mission (about 1 m); A stays near its launch point.
        assert wait_until(lambda: away("B") > 0.6, 40.0), away("B")
        at_stop = np.array(track["A"][-1][:2])
        for verb, aid in (("stop", "A"), ("land", "B")):
            res = subprocess.run([sys.executable, "-m", "agent.cli", verb, "--id", aid,
                                  "--scenario", str(CUBE), "--connect", ground["endpoint"]],
                                 capture_output=True, text=True, env=repo_env(), timeout=60)
            assert res.returncode == 0, res.stdout + res.stderr
        errs = {}
        for a, proc in agents.items():
            _out, errs[a] = proc.communicate(timeout=60)
            assert proc.returncode == 0, errs[a]
        final = {a: np.array(track[a][-1]) for a in "AB"}
        assert final["A"][2] < 0.05 and final["B"][2] < 0.05  # both on the ground
        assert np.linalg.norm(final["B"][:2] - home["B"]) < 0.15, (final["B"], home["B"])
        assert np.linalg.norm(final["A"][:2] - at_stop) < 0.3, (final["A"], at_stop)
        assert "emergency stop: landing where it is" in errs["A"]
        assert "emergency stop" not in errs["B"] and "landed" in errs["B"]
        reasons = {(d.sender, d.reason) for d in departures}
        assert reasons == {("A", "operator_stop"), ("B", "operator_land")}, reasons
    finally:
        for proc in agents.values():
            stop_process(proc, grace_s=20.0)
        obs.close()
