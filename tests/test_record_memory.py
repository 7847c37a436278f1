"""The recorder (:mod:`agent.mission.recorder`) on an in-memory mission: what lands in
``events.jsonl`` and ``recording.mcap`` (read back with the ``mcap`` reader), bad payloads
counted, and the recording read back as a result (:mod:`agent.sim.replay`)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader

from agent.cli import main
from agent.config.parse import load_scenario
from agent.mission import scene
from agent.mission.recorder import Recorder, line_event
from agent.net.memory import MemoryNetwork
from agent.sim.replay import read_recording, to_result
from agent.storage import recording as fmt
from agent.wire import keys
from agent.wire.ground import MOCAP_CODEC, MocapPose
from agent.wire.peer import Pose
from tests.conftest import scenario_path
from tests.test_status_identity import PUB, state


def _record(out: Path) -> Recorder:
    """hexagon_5_3 for 2 s of mission time (10 state rounds, 5 poses each), one trade of
    landmark 6 from A to B in round 5; mocap, a landmark set, and two bad payloads."""
    sc = load_scenario(str(scenario_path("hexagon_5_3")))
    net = MemoryNetwork()
    rec = Recorder(net.transport("rec"), sc, "m", out, pose_hz=1e6, scene_hz=1e6)
    tp = net.transport("agents")
    owned = {"A": {3: 0, 6: 0}, "B": {2: 0, 4: 0}, "C": {1: 0, 5: 0}}
    for k in range(10):
        if k == 5:
            owned["A"], owned["B"] = {3: 0}, {2: 0, 4: 0, 6: 1}
        for aid in "ABC":
            tw = {"B": 1} if aid == "A" and k >= 5 else {"A": 1} if aid == "B" and k >= 5 \
                else {}
            tp.publish(keys.state_key("m", aid), PUB.encode(state(
                aid, k + 1, 0.2 * k, owned[aid], ok=len(tw), trades_with=tw,
                complete=k == 9, phase="converged" if k >= 7 else "optimising")))
            for j in range(5):
                tp.publish(keys.pose_key("m", aid), PUB.encode(Pose(
                    sender=aid, seq=5 * k + j, t=0.2 * k + 0.04 * j, p=(0.1 * k, 0.0, 0.0),
                    v=(0.0, 1.0, 0.0))))
        tp.publish(keys.mocap_key("m", "A"), MOCAP_CODEC.encode(MocapPose(
            drone="A", seq=k, t=0.2 * k, p=[0.0, 0.0, 1.0], q=[1.0, 0.0, 0.0, 0.0],
            v=[0.0, 0.0, 0.0])))
    tp.publish(keys.pose_key("m", "A"), b"not msgpack")
    tp.publish(keys.pose_key("m", "B"), PUB.encode(Pose(sender="A", seq=1, t=0.0,
                                                        p=(0, 0, 0), v=(1, 0, 0))))
    lost = line_event("A", "viscover-flight-agent A: mocap lost: level hover")
    assert lost is not None
    rec.event(lost)
    rec.close()
    return rec


def test_the_recording_holds_every_message_and_counts_bad_payloads(tmp_path: Path) -> None:
    rec = _record(tmp_path)
    with (tmp_path / fmt.MCAP_NAME).open("rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None and summary.statistics is not None
    counts = {summary.channels[c].topic: n
              for c, n in summary.statistics.channel_message_counts.items()}
    schemas = {summary.channels[c].topic: summary.schemas[summary.channels[c].schema_id].name
               for c in summary.channels}
    for aid in "ABC":
        assert counts[fmt.state_topic(aid)] == 10 and counts[fmt.track_topic(aid)] == 50
        assert counts[fmt.pose_topic(aid)] == 50
        assert schemas[fmt.pose_topic(aid)] == "foxglove.PoseInFrame"
    assert counts[fmt.mocap_topic("A")] == 10 and counts[fmt.INFO_TOPIC] == 1
    # at the start (no owner heard yet), on each first state, on each side of the trade
    assert counts[fmt.LANDMARKS_TOPIC] == 1 + 3 + 2
    assert counts[fmt.COVERAGE_TOPIC] == 30 and counts[fmt.MISSION_TOPIC] == 1
    assert schemas[fmt.DRONES_TOPIC] == "foxglove.SceneUpdate"
    assert schemas[fmt.LANDMARKS_TOPIC] == "foxglove.PointCloud"
    events = [json.loads(x) for x in (tmp_path / fmt.EVENTS_NAME).read_text().splitlines()]
    assert counts[fmt.EVENTS_TOPIC] == len(events) == rec.counts[fmt.EVENTS_TOPIC]
    assert all({"time", "t", "source", "kind", "level", "text"} <= set(e) for e in events)
    kinds = [e["kind"] for e in events]
    assert kinds[0] == "recording" and kinds[-1] == "recording_end"
    assert kinds.count("trade") == 2 and kinds.count("failsafe") == 1
    assert events[-1]["rejected"] == 2
    assert events[-1]["messages"] == {**counts, fmt.EVENTS_TOPIC: len(events) - 1}


def test_the_recording_reads_back_as_a_result_and_a_report(tmp_path: Path) -> None:
    _record(tmp_path)
    result = to_result(read_recording(tmp_path))
    assert result.agent_ids == ["A", "B", "C"] and result.landmark_ids == [1, 2, 3, 4, 5, 6]
    (trade,) = result.trades  # both sides showed it in the same round: A is taken first
    assert (trade.initiator, trade.partner, trade.to_partner, trade.to_initiator) == (
        "A", "B", [6], [])
    assert result.complete and result.times[-1] >= 1.8
    final = {aid: sorted(np.asarray(result.landmark_ids)[result.final_owner == i].tolist())
             for i, aid in enumerate(result.agent_ids)}
    assert final == {"A": [3], "B": [2, 4, 6], "C": [1, 5]}
    np.testing.assert_allclose(result.positions[-1, :, 0], 0.9)
    assert main(["report", str(tmp_path), "--no-plots"]) == 0
    page = (tmp_path / "report" / "report.html").read_text()
    assert "viscover report: hexagon_5_3" in page and "mocap lost" in page


def test_scene_geometry() -> None:
    """Camera quaternions turn +x onto v; frusta open around v; the cloud's fields match its
    packed layout."""
    v = np.array([[0.0, 1.0, 0.0], [0.6, 0.0, -0.8], [0.0, 0.0, 1.0]])
    qx, qy, qz, qw = scene.camera_quaternions(v).T
    x_axis = np.stack([1 - 2 * (qy**2 + qz**2), 2 * (qx * qy + qw * qz),
                       2 * (qx * qz - qw * qy)], axis=1)  # first column of R(q)
    np.testing.assert_allclose(x_axis, v, atol=1e-12)
    seg = scene.frustum_segments(np.zeros((3, 3)), v, 2.0)
    assert seg.shape == (3, 16, 3)
    np.testing.assert_allclose(seg[:, 8:].mean(axis=1), 2.0 * v, atol=1e-12)
    cloud = scene.landmark_cloud(np.eye(3), np.array([7, 8, 9]), np.array([0, -1, 1]), 0.0)
    assert cloud is not None
    fields, names = scene._CLOUD.fields, scene._CLOUD.names
    assert fields is not None and names is not None  # a structured dtype
    assert [(n, off) for n, off, _t in scene._FIELDS] == [(n, fields[n][1]) for n in names]


def test_a_recording_cut_short_is_still_read(tmp_path: Path) -> None:
    """The MCAP of a recorder killed outright (flushed, no summary) streams what was
    flushed; the report says it was cut short."""
    sc = load_scenario(str(scenario_path("hexagon_5_3")))
    net = MemoryNetwork()
    rec = Recorder(net.transport("rec"), sc, "m", tmp_path / "live", flush_s=0.0)
    tp = net.transport("agents")
    for k in range(5):
        for aid, lm in (("A", {3: 0, 6: 0}), ("B", {2: 0, 4: 0}), ("C", {1: 0, 5: 0})):
            tp.publish(keys.state_key("m", aid), PUB.encode(state(aid, k + 1, 0.2 * k, lm)))
    cut = tmp_path / "cut"
    cut.mkdir()
    (cut / fmt.MCAP_NAME).write_bytes((tmp_path / "live" / fmt.MCAP_NAME).read_bytes())
    rec.close()
    got = read_recording(cut)
    assert not got.complete_file and got.counts[fmt.state_topic("A")] >= 4
    assert to_result(got).agent_ids == ["A", "B", "C"]
    assert main(["report", str(cut), "--no-plots"]) == 0
    assert "recorded, cut short" in (cut / "report" / "report.html").read_text()


def test_report_mistakes_are_one_line(tmp_path: Path,
                                      capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["report", str(tmp_path / "nothing")]) == 2
    assert main(["report", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"viscover: error: {tmp_path / 'nothing'}: no such run folder",
                   f"viscover: error: {tmp_path}: no recording (no recording.mcap inside); "
                   "record one with viscover launch or viscover record --out DIR"]


def test_a_drone_that_joined_is_recorded_too(tmp_path: Path) -> None:
    """S1 joins hexagon_5_3 (not in the scenario): its states and poses get their own
    channels, nothing is counted as a bad payload, the recording still reads back."""
    sc = load_scenario(str(scenario_path("hexagon_5_3")))
    net = MemoryNetwork()
    rec = Recorder(net.transport("rec"), sc, "m", tmp_path, pose_hz=1e6, scene_hz=1e6)
    tp = net.transport("agents")
    owned = {"A": {3: 0}, "B": {2: 0, 4: 0}, "C": {1: 0, 5: 0}, "S1": {6: 1}}
    for k in range(4):
        for aid in ("A", "B", "C", "S1"):
            tp.publish(keys.state_key("m", aid), PUB.encode(state(aid, k + 1, 0.2 * k,
                                                                  owned[aid])))
            tp.publish(keys.pose_key("m", aid), PUB.encode(Pose(
                sender=aid, seq=k, t=0.2 * k, p=(0.1 * k, 0.0, 0.0), v=(0.0, 1.0, 0.0))))
    rec.close()
    with (tmp_path / fmt.MCAP_NAME).open("rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None and summary.statistics is not None
    counts = {summary.channels[c].topic: n
              for c, n in summary.statistics.channel_message_counts.items()}
    assert counts[fmt.state_topic("S1")] == 4 and counts[fmt.track_topic("S1")] == 4
    events = [json.loads(x) for x in (tmp_path / fmt.EVENTS_NAME).read_text().splitlines()]
    assert events[-1]["rejected"] == 0
    result = to_result(read_recording(tmp_path))
    assert result.agent_ids[:3] == ["A", "B", "C"]
