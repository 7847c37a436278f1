"""End to end: ``viscover launch`` records its mission into the run folder (events.jsonl and an
MCAP file the ``mcap`` reader opens), ``viscover record`` records the same mission from the
side and finalises its file on SIGINT, ``viscover status`` shows it, and ``viscover report``
builds the report from the run folder."""

from __future__ import annotations

import json
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest
from mcap.reader import make_reader

from agent.cli import main
from agent.storage import recording as fmt
from tests.conftest import reap, repo_env, scenario_path

SCENARIO = str(scenario_path("hexagon_5_3"))


def _viscover(*args: str) -> subprocess.Popen[str]:
    return subprocess.Popen([sys.executable, "-m", "agent.cli", *args], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env=repo_env())


def _topics(path: Path) -> dict[str, int]:
    """Messages per topic, from the MCAP summary (which only a finalised file has)."""
    with path.open("rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None and summary.statistics is not None, f"{path}: no summary"
    return {summary.channels[c].topic: n
            for c, n in summary.statistics.channel_message_counts.items()}


def test_launch_records_status_shows_and_report_replays(
        tmp_path: Path, router: str, capsys: pytest.CaptureFixture[str]) -> None:
    side = tmp_path / "side"
    net = ["--scenario", SCENARIO, "--connect", router]
    recorder = _viscover("record", *net, "--out", str(side), "--live", "0")
    launch = None
    try:
        assert recorder.stdout is not None
        ready = recorder.stdout.readline()
        assert ready.startswith("viscover-record ready: mission hexagon_5_3"), ready
        port = int(ready.split("live on ws://127.0.0.1:")[1].split()[0])
        socket.create_connection(("127.0.0.1", port), timeout=5).close()  # Foxglove's way in
        launch = subprocess.Popen(
            [sys.executable, "-m", "agent.cli", "launch", SCENARIO, "--router", router,
             "--runs", str(tmp_path / "runs"), "--timeout", "90"], stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT, text=True, env=repo_env(), cwd=tmp_path)
        capsys.readouterr()
        code = main(["status", *net, "--once", "--wait", "30"])  # until all heard; a pipe
        s_out = capsys.readouterr().out
        l_out, _ = launch.communicate(timeout=90)
        assert launch.returncode == 0, l_out
        recorder.send_signal(signal.SIGINT)  # Ctrl-C: the recorder finalises its file
        assert recorder.wait(timeout=30) == 130
    finally:
        reap([recorder] if launch is None else [recorder, launch])
    # status: one row per drone, the last state each showed, and the mission line
    assert code == 0, s_out
    rows = {ln.split()[0]: ln.split() for ln in s_out.splitlines()[1:4]}
    assert set(rows) == {"A", "B", "C"}, s_out
    assert all(r[1] in ("optimising", "converged", "trading", "in_doubt") for r in rows.values())
    assert "mission hexagon_5_3:" in s_out and "landmarks seen by their owner" in s_out
    (run,) = (tmp_path / "runs").iterdir()
    for folder in (run, side):
        topics = _topics(folder / fmt.MCAP_NAME)
        events = [json.loads(x) for x in (folder / fmt.EVENTS_NAME).read_text().splitlines()]
        for aid in "ABC":  # a state every 0.2 s for several seconds, poses while moving
            assert topics[fmt.state_topic(aid)] >= 10 and topics[fmt.track_topic(aid)] >= 10
            assert topics[fmt.pose_topic(aid)] >= 1
        assert topics[fmt.INFO_TOPIC] == 1 and topics[fmt.LANDMARKS_TOPIC] >= 4
        assert topics[fmt.DRONES_TOPIC] >= 3 and topics[fmt.COVERAGE_TOPIC] >= 30
        assert topics[fmt.EVENTS_TOPIC] == len(events)
        kinds = {e["kind"] for e in events}
        assert {"recording", "first_state", "phase", "complete", "recording_end"} <= kinds
        assert events[-1]["rejected"] == 0
    launched = [json.loads(x) for x in (run / fmt.EVENTS_NAME).read_text().splitlines()]
    assert {(e["source"], e["kind"]) for e in launched} >= {
        ("A", "process"), ("A", "exit"), ("launch", "launch_end")}
    # the report of the launched run, as viscover simulate writes it, plus the page
    assert main(["report", str(run)]) == 0
    rep = run / "report"
    for name in ("result.json", "trajectories.png", "coverage.png", "partition.png",
                 "report.html"):
        assert (rep / name).stat().st_size > 0, name
    doc = json.loads((rep / "result.json").read_text())
    assert doc["complete"] and doc["agents"] == ["A", "B", "C"]
    assert sorted(x for ids in doc["final_partition"].values() for x in ids) == [1, 2, 3, 4, 5, 6]
    trades = sum(e["kind"] == "trade" for e in launched)  # seen by both sides of each
    assert len(doc["trades"]) == trades // 2 or trades % 2, (doc["trades"], trades)
    page = (rep / "report.html").read_text()
    assert page.count("data:image/png;base64,") == 3 and "first_state" in page
    t0 = time.monotonic()
    assert main(["report", str(side), "--no-plots"]) == 0
    assert time.monotonic() - t0 < 20
