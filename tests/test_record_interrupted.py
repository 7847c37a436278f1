"""``viscover report`` of a flight interrupted before any agent published a state: the
recording (made here by the recorder on an in-memory network) holds the ground station's
motion capture and events only; the report is written from those, saying what is missing."""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np
import pytest

from agent.cli import main
from agent.config.parse import load_scenario
from agent.mission import scene
from agent.mission.recorder import Recorder, line_event
from agent.net.memory import MemoryNetwork
from agent.sim.replay import mocap_doc, read_recording
from agent.storage import recording as fmt
from agent.wire import keys
from agent.wire.ground import MOCAP_CODEC, MocapPose
from tests.conftest import scenario_path

MISSING = "interrupted before any agent state: no partition, no coverage"


def _record_takeoff(out: Path) -> None:
    """hexagon_5_3: A and B climb on the mocap (10 samples each), a phase line, then the
    recorder is stopped (Ctrl-C) before any agent state or pose."""
    sc = load_scenario(str(scenario_path("hexagon_5_3")))
    net = MemoryNetwork()
    rec = Recorder(net.transport("rec"), sc, "m", out, pose_hz=1e6, scene_hz=1e6)
    tp = net.transport("groundstation")
    for k in range(10):
        for aid, x in (("A", 0.0), ("B", 1.0)):
            tp.publish(keys.mocap_key("m", aid), MOCAP_CODEC.encode(MocapPose(
                drone=aid, seq=k, t=0.1 * k, p=[x, 0.0, 0.1 * k], q=[1.0, 0.0, 0.0, 0.0],
                v=[0.0, 0.0, 1.0])))
        time.sleep(0.002)  # distinct reception times
    armed = line_event("A", "viscover-flight-agent A: armed")
    assert armed is not None
    rec.event(armed)
    rec.close()


def test_mocap_pose_in_frame_decodes() -> None:
    yaw = 0.7  # a body turned 0.7 rad about z: its x axis is (cos, sin, 0)
    q = np.array([0.0, 0.0, np.sin(yaw / 2), np.cos(yaw / 2)])  # (x, y, z, w)
    msg = scene.pose_in_frame(np.array([1.5, -2.0, 0.25]), q, 12.0)
    doc = mocap_doc(msg.encode(), 12.0)
    assert doc["p"] == [1.5, -2.0, 0.25] and doc["t"] == 12.0
    assert doc["v"] == pytest.approx([np.cos(yaw), np.sin(yaw), 0.0])


def test_interrupted_flight_is_reported_from_what_was_recorded(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    _record_takeoff(tmp_path)
    rec = read_recording(tmp_path)
    assert not rec.states and not rec.poses and set(rec.mocap) == {"A", "B"}
    assert main(["report", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert MISSING in out
    report = tmp_path / "report"
    assert sorted(p.name for p in report.iterdir()) == ["report.html", "result.json",
                                                        "trajectories.png"]
    doc = json.loads((report / "result.json").read_text())
    assert doc["missing"].startswith(MISSING) and "motion capture" in doc["missing"]
    assert doc["coverage"] == [] and doc["final_partition"] is None and doc["trades"] == []
    # The trajectories are the mocap's: A climbed to 0.9 m, B flew at x = 1; C never seen
    # stays at its scenario pose.
    final = doc["final_poses"]
    assert final["A"]["position"] == pytest.approx([0.0, 0.0, 0.9])
    assert final["B"]["position"][0] == pytest.approx(1.0)
    assert doc["initial_poses"]["A"]["position"] == pytest.approx([0.0, 0.0, 0.0])
    page = (report / "report.html").read_text()
    assert MISSING in page and "armed" not in page.split("<h2>Events</h2>")[0]
    assert fmt.mocap_topic("A") in page


def test_empty_recording_is_one_line(tmp_path: Path,
                                     capsys: pytest.CaptureFixture[str]) -> None:
    sc = load_scenario(str(scenario_path("hexagon_5_3")))
    Recorder(MemoryNetwork().transport("rec"), sc, "m", tmp_path).close()
    assert main(["report", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"viscover: error: {tmp_path}: the recording holds no agent state, pose or "
                   "motion capture (was the mission running on this mission name?)"]
    (tmp_path / fmt.MCAP_NAME).write_bytes(b"\x89MCAP0\r\nnot an mcap")
    assert main(["report", str(tmp_path)]) == 2
    assert len(capsys.readouterr().err.strip().splitlines()) == 1
