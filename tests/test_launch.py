"""``viscover launch``: a whole mission from one command, its run folder, and a clean stop."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest
from mcap.reader import make_reader

from agent.cli import main
from tests.conftest import repo_env, scenario_path


def _launch(tmp_path: Path, *args: str) -> subprocess.Popen[str]:
    return subprocess.Popen([sys.executable, "-m", "agent.cli", "launch", *args, "--runs",
                             str(tmp_path / "runs")], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env=repo_env(), cwd=tmp_path)


def _run_dir(tmp_path: Path) -> Path:
    (run,) = (tmp_path / "runs").iterdir()
    return run


def _all_gone(doc: dict[str, Any]) -> list[int]:
    """Pids of the run (``launch.json``, as parsed) that still exist."""
    pids: list[int] = [p for c in doc["processes"].values() for p in c["pids"]]
    if doc["router_pid"] is not None:
        pids.append(doc["router_pid"])
    alive = []
    for pid in pids:
        try:
            os.kill(pid, 0)
            alive.append(pid)
        except ProcessLookupError:
            pass
    return alive


def test_kinematic_mission_completes_with_a_run_folder(tmp_path: Path) -> None:
    proc = _launch(tmp_path, str(scenario_path("hexagon_5_3")), "--timeout", "60")
    out, err = proc.communicate(timeout=120)
    assert proc.returncode == 0, out + err
    run = _run_dir(tmp_path)
    assert "launch: complete" in out
    assert any(line.startswith("launch: ") and "coverage" in line for line in out.splitlines())
    doc = json.loads((run / "launch.json").read_text())
    assert doc["exit_status"] == 0 and doc["ended"] == "complete"
    assert {n: c["exit_code"] for n, c in doc["processes"].items()} == {"A": 0, "B": 0, "C": 0}
    rep = json.loads((run / "observer.json").read_text())
    assert rep["complete"] and rep["violations"] == []
    assert sorted(rep["owners"]) == ["1", "2", "3", "4", "5", "6"]
    for aid in "ABC":
        assert (run / "state" / aid / "journal.bin").stat().st_size > 0
        log = (run / "logs" / f"{aid}.log").read_text()
        results = [json.loads(x) for x in log.splitlines() if x.startswith("{")]
        assert len(results) == 1 and results[0]["complete"] is True, log
    assert _all_gone(doc) == []


def test_ctrl_c_lands_every_drone_and_leaves_no_process(tmp_path: Path) -> None:
    proc = _launch(tmp_path, str(scenario_path("cube_6_2")), "--flight", "--time-scale", "2")
    assert proc.stdout is not None
    hovering: set[str] = set()
    deadline = time.monotonic() + 90.0
    while len(hovering) < 3 and time.monotonic() < deadline:
        line = proc.stdout.readline()
        if not line:
            break
        if "viscover-flight-agent hovering" in line:
            hovering.add(line.split("]")[0].lstrip("["))
    assert hovering == {"A", "B", "C"}
    proc.send_signal(signal.SIGINT)  # what Ctrl-C sends to the launcher
    out, err = proc.communicate(timeout=150)
    assert proc.returncode == 130, out + err
    doc = json.loads((_run_dir(tmp_path) / "launch.json").read_text())
    # A flying agent exits 0 only once its landing is confirmed by the vehicle.
    assert {a: doc["processes"][a]["exit_code"] for a in "ABC"} == {"A": 0, "B": 0, "C": 0}, out
    assert _all_gone(doc) == []
    # The recording was finalised after the landings: mocap and the flight phases (the agents
    # may not have published a pose yet when interrupted right after hovering).
    run = _run_dir(tmp_path)
    with (run / "recording.mcap").open("rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None and summary.statistics is not None
    topics = {summary.channels[c].topic: n
              for c, n in summary.statistics.channel_message_counts.items()}
    assert all(topics.get(f"/drones/{a}/mocap", 0) > 0 for a in "ABC"), topics
    events = [json.loads(x) for x in (run / "events.jsonl").read_text().splitlines()]
    landed = {e["source"] for e in events if e["kind"] == "flight" and e["text"].endswith(
        ": landed")}
    assert landed == {"A", "B", "C"} and events[-1]["kind"] == "recording_end"


def _launch_refused(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                    monkeypatch: pytest.MonkeyPatch, *args: str) -> str:
    """``viscover launch ARGS`` called in-process (the function the command runs: these are
    checks of its arguments, refused before any process starts): exit 2; its stderr."""
    monkeypatch.chdir(tmp_path)
    assert main(["launch", *args, "--runs", str(tmp_path / "runs")]) == 2
    return capsys.readouterr().err


@pytest.mark.parametrize(("args", "message"), [
    (["--only", "agents,lunch"], "--only: unknown role lunch; choose from router, "
                                 "groundstation, agents"),
    (["--id", "A,Z"], "--id: Z not agents of"),
    (["--only", "agents"], "--only without router: give the mission's router with --router"),
    (["--router", "127.0.0.1:7447"], "is not a Zenoh endpoint; write it as tcp/HOST:PORT"),
    (["--battery-capacity", "A=150"], "--battery-capacity gives simulated vehicles their "
                                      "packs: add --flight"),
    (["--flight", "--battery-capacity", "Z=150"], "--battery-capacity 'Z=150': Z is not an "
                                                  "agent of the scenario (A, B, C)"),
    (["--flight", "--battery-capacity", "A=-1"], "--battery-capacity 'A=-1': expected ID=MAH"),
    # no abbreviations: "--out" was silently "--outdoor"
    (["--out", "runs2"], "viscover: error: unrecognized arguments: --out runs2"),
])
def test_mistakes_are_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                               monkeypatch: pytest.MonkeyPatch, args: list[str], message: str
                               ) -> None:
    err = _launch_refused(tmp_path, capsys, monkeypatch, str(scenario_path("hexagon_5_3")),
                          *args)
    assert message in err and "Traceback" not in err


def test_resume_needs_a_run_folder(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                   monkeypatch: pytest.MonkeyPatch) -> None:
    err = _launch_refused(tmp_path, capsys, monkeypatch, str(scenario_path("hexagon_5_3")),
                          "--resume", str(tmp_path / "nothing"))
    assert err.strip() == (f"viscover: error: --resume {tmp_path / 'nothing'}: not a run folder "
                           "(no state/ inside)")
