"""``viscover ros2-bridge`` says so once and exits when the mission's router goes away
(status 1: the mission had not completed), and announces a drone's mocap topic only once a
mocap pose of it came: a kinematic mission has none."""

from __future__ import annotations

import subprocess
import sys

from agent.config.parse import load_scenario
from agent.net.router import start_router_process, stop_router_process
from groundstation.ros2.model import MissionRos
from groundstation.ros2.names import Names
from tests.conftest import ROOT, repo_env, scenario_path

HEX = str(scenario_path("hexagon_5_3"))


def test_no_mocap_topic_until_mocap_is_heard() -> None:
    model = MissionRos(load_scenario(HEX), Names())
    topics = dict(model.topics())
    assert [t for t in topics if t.endswith("/mocap")] == []
    assert {"/viscover/A/pose", "/viscover/B/pose", "/viscover/C/pose"} <= set(topics)
    model.mocap("B", (0.0, 0.0, 1.0), (1.0, 0.0, 0.0, 0.0), 1)
    assert [t for t, _ in model.topics() if t.endswith("/mocap")] == ["/viscover/B/mocap"]


def test_the_bridge_says_once_and_exits_when_its_router_is_gone() -> None:
    router, endpoint = start_router_process()
    bridge = subprocess.Popen(
        [sys.executable, "-m", "agent.cli", "ros2-bridge", "--scenario", HEX, "--connect",
         endpoint], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=repo_env(),
        cwd=ROOT)
    try:
        assert bridge.stdout is not None
        ready = bridge.stdout.readline()
        assert ready.startswith("viscover-ros2-bridge ready: mission hexagon_5_3 -> 8 topics")
        stop_router_process(router)
        out, err = bridge.communicate(timeout=40)
    finally:
        stop_router_process(router)
        if bridge.poll() is None:
            bridge.kill()
            bridge.communicate()
    assert bridge.returncode == 1, err
    lines = err.splitlines()
    assert lines.count("viscover-ros2-bridge: mesh gone: no router/peers heard for 10 s; "
                       "stopping (the mission had not completed)") == 1, err
    assert "Traceback" not in err and out == ""
