"""No Zenoh router at the endpoint: every network command says what it waits for, then fails
in one line with the fix (exit 2): no traceback, no Rust source path, no run folder left by
``launch``. And ``launch`` tells how to reach its mission from another terminal."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from agent.net.router import free_tcp_port
from tests.conftest import repo_env, scenario_path

HEX = str(scenario_path("hexagon_5_3"))


def _viscover(*args: str, cwd: Path, timeout: float = 60.0) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "agent.cli", *args], capture_output=True,
                          text=True, env=repo_env(), cwd=cwd, timeout=timeout, check=False)


def _no_router_lines(ep: str, wait: str, option: str) -> list[str]:
    return [f"viscover: waiting up to {wait} s for the Zenoh router at {ep} ...",
            f"viscover: error: no Zenoh router answered at {ep} within {wait} s: start one "
            "(viscover router --config broker_config/router.json5) or give the right endpoint "
            f"with {option} tcp/HOST:PORT"]


@pytest.mark.parametrize("argv", [
    ["status", "--scenario", HEX, "--once"],
    ["land", "--all", "--scenario", HEX],
    ["stop", "--id", "A", "--scenario", HEX],
    ["observe", "--scenario", HEX],
])
def test_a_command_with_no_router_says_what_it_waits_for_then_one_line(
        argv: list[str], tmp_path: Path) -> None:
    ep = f"tcp/127.0.0.1:{free_tcp_port()}"
    done = _viscover(*argv, "--connect", ep, "--connect-wait", "1", cwd=tmp_path)
    assert done.returncode == 2, done.stderr
    assert done.stderr.splitlines() == _no_router_lines(ep, "1", "--connect")


def test_launch_with_no_router_leaves_no_run_folder(tmp_path: Path) -> None:
    ep = f"tcp/127.0.0.1:{free_tcp_port()}"
    done = _viscover("launch", HEX, "--router", ep, "--connect-wait", "1", "--runs",
                     str(tmp_path / "runs"), cwd=tmp_path)
    assert done.returncode == 2, done.stdout + done.stderr
    assert done.stderr.splitlines() == _no_router_lines(ep, "1", "--router")
    assert list((tmp_path / "runs").glob("*")) == []


def test_launch_prints_and_records_the_commands_of_its_mission(tmp_path: Path) -> None:
    done = _viscover("launch", HEX, "--runs", str(tmp_path / "runs"), "--timeout", "2",
                     "--no-record", cwd=tmp_path, timeout=90)
    assert done.returncode in (0, 3), done.stdout + done.stderr
    (run,) = (tmp_path / "runs").iterdir()
    doc = json.loads((run / "launch.json").read_text())
    ep = doc["router"]
    assert ep.startswith("tcp/127.0.0.1:")
    tail = f"--scenario {HEX} --mission hexagon_5_3 --connect {ep}"
    assert doc["commands"] == {"status": f"viscover status {tail}",
                               "land": f"viscover land --all {tail}",
                               "stop": f"viscover stop --all {tail}"}
    for name, cmd in doc["commands"].items():
        assert f"launch: {name}: {cmd}" in done.stdout.splitlines()
