"""``viscover ros2-bridge`` as a user runs it: a recording-only run writes a bag that rosbags'
reader opens with the counts the bridge reported; user mistakes are one line and exit 2."""

from __future__ import annotations

import re
import subprocess
import sys
import time
from pathlib import Path

import pytest
from rosbags.rosbag2 import Reader
from rosbags.typesys import Stores, get_typestore

from agent.commands.extras import missing_extra
from agent.config.parse import load_scenario
from tests.conftest import ROOT, repo_env, scenario_path
from tests.test_ros2_bridge import Agents, M

SCENARIO = str(scenario_path("hexagon_5_3"))


def bridge(*args: str, timeout: float = 60.0) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "agent.cli", "ros2-bridge", *args],
                          capture_output=True, text=True, timeout=timeout, env=repo_env(),
                          cwd=ROOT)


def test_a_recording_only_run_writes_a_bag(router: str, tmp_path: Path) -> None:
    agents = Agents(router, load_scenario(SCENARIO))
    bag = tmp_path / "bag"
    proc = subprocess.Popen(
        [sys.executable, "-m", "agent.cli", "ros2-bridge", "--scenario", SCENARIO,
         "--mission", M, "--connect", router, "--no-publish", "--bag", str(bag),
         "--duration", "3"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        env=repo_env(), cwd=ROOT)
    try:
        assert proc.stdout is not None
        assert "viscover-ros2-bridge ready" in proc.stdout.readline()
        while proc.poll() is None:
            agents.tick()
            time.sleep(0.05)
        _out, err = proc.communicate(timeout=30)
    finally:
        agents.close()
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert proc.returncode == 0, err
    found = re.search(r"bag \S+ \((\d+) messages\)", err)
    assert found is not None, err
    total = int(found.group(1))
    assert total > 20
    store = get_typestore(Stores.ROS2_JAZZY)
    with Reader(bag) as reader:
        assert reader.message_count == total
        topics = {c.topic for c in reader.connections}
        assert {"/tf", "/viscover/A/pose", "/viscover/A/mocap", "/viscover/landmarks",
                "/viscover/status", "/viscover/events", "/viscover/frusta"} <= topics
        n = 0
        for conn, _stamp, raw in reader.messages():
            store.deserialize_cdr(raw, conn.msgtype)
            n += 1
        assert n == total


@pytest.mark.parametrize(("args", "says"), [
    (["--namespace", "viscover"], "--namespace: namespace 'viscover' must start with /"),
    (["--no-publish"], "--no-publish without --bag would do nothing"),
    (["--bag", "{tmp}"], "exists; a bag is written into a new folder"),
    (["--connect", "tcp/127.0.0.1:9", "--connect-wait", "0"], "no Zenoh router answered"),
])
def test_user_mistakes_are_one_line(args: list[str], says: str, tmp_path: Path) -> None:
    r = bridge("--scenario", SCENARIO, *[a.replace("{tmp}", str(tmp_path)) for a in args])
    assert r.returncode == 2
    assert r.stderr.count("\n") == 1 and says in r.stderr, r.stderr
    assert not (tmp_path / "bag").exists()


def test_the_extra_is_named_when_missing() -> None:
    assert missing_extra(ModuleNotFoundError("no rosbags", name="rosbags")) == ("rosbags", "ros2")
    assert missing_extra(ModuleNotFoundError("no", name="xxhash.x")) == ("xxhash", "ros2")
    r = subprocess.run([sys.executable, "-m", "agent.cli", "--help"], capture_output=True,
                       text=True, timeout=60, env=repo_env(), cwd=ROOT)
    assert "ros2-bridge" in r.stdout


def test_a_recorded_run_converts_to_a_bag(router: str, tmp_path: Path) -> None:
    """A run folder written by the recorder becomes a bag: every recorded pose a PoseStamped,
    every event a log line, the landmarks and /tf; a run of another scenario is refused."""
    from agent.mission.recorder import Recorder
    from agent.net.router import client_config
    from agent.net.transport import ZenohTransport
    from agent.sim.replay import read_recording

    sc = load_scenario(SCENARIO)
    agents = Agents(router, sc)
    tp = ZenohTransport(client_config(router), node_id="recorder")
    run = tmp_path / "run"
    rec = Recorder(tp, sc, M, run)
    try:
        deadline = time.monotonic() + 2.0
        while time.monotonic() < deadline:
            agents.tick()
            time.sleep(0.05)
    finally:
        rec.close()
        tp.close()
        agents.close()
    recorded = read_recording(run)
    bag = tmp_path / "bag"
    r = bridge("--scenario", SCENARIO, "--from-recording", str(run), "--bag", str(bag))
    assert r.returncode == 0, r.stderr
    store = get_typestore(Stores.ROS2_JAZZY)
    with Reader(bag) as reader:
        counts = {c.topic: c.msgcount for c in reader.connections}
        for conn, _stamp, raw in reader.messages():
            store.deserialize_cdr(raw, conn.msgtype)
    for aid in ("A", "B", "C"):
        assert counts[f"/viscover/{aid}/pose"] == len(recorded.poses[aid].docs)
    assert counts["/viscover/events"] == len(recorded.events) > 0
    assert counts["/viscover/landmarks"] >= 1 and counts["/tf"] >= 3
    assert counts.get("/viscover/A/mocap", 0) == len(recorded.mocap["A"].docs)
    other = bridge("--scenario", str(scenario_path("cube_6_2")), "--from-recording", str(run),
                   "--bag", str(tmp_path / "bag2"))
    assert other.returncode == 2 and "recorded with other landmarks" in other.stderr
    assert other.stderr.count("\n") == 1 and not (tmp_path / "bag2").exists()
