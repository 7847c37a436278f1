"""A ground station presenting a certificate the router does not let publish (issue "No single
peer, disk or file can lose a landmark", item 10): it says so in one line and exits 2 instead
of printing "ready" and publishing into the void."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from agent.net.pki import TeamPlan, make_team
from agent.net.router import start_router_process, stop_router_process
from tests.conftest import repo_env, scenario_path

CUBE = scenario_path("cube_6_2")  # drones A, B, C


@pytest.mark.serial
def test_a_ground_station_whose_publications_are_denied_exits_2(tmp_path: Path) -> None:
    team = make_team(TeamPlan(tmp_path / "team", ["A", "B", "C"]))
    router, endpoint = start_router_process(team=team)
    try:
        gs = subprocess.run(
            [sys.executable, "-m", "agent.cli", "groundstation", "--source", "sim",
             "--scenario", str(CUBE), "--connect", endpoint, "--tls-dir", str(team.path),
             "--identity", "drone-A", "--ports", "A=0,B=0,C=0", "--time-scale", "5",
             "--duration", "10"],
            capture_output=True, text=True, env=repo_env(), timeout=60)
    finally:
        stop_router_process(router)
    assert gs.returncode == 2, (gs.stdout, gs.stderr)
    assert "ready" not in gs.stdout
    lines = gs.stderr.strip().splitlines()
    assert len(lines) == 1 and "drone-A" in lines[0] and "--identity ground" in lines[0], lines
