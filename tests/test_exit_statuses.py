"""Exit statuses of ``viscover launch`` and a kinematic ``viscover agent`` when the operator
ends the mission (``land --all`` / ``stop --all``), on Ctrl-C and on SIGTERM: what the README's
"Command line" section says, in the process's status, ``launch.json`` and the events."""

from __future__ import annotations

import json
import shlex
import signal
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

from agent.mission.operator import live_agents
from agent.net.router import client_config
from agent.net.transport import ZenohTransport
from tests.conftest import reap, repo_env, scenario_path, wait_until

pytestmark = [pytest.mark.slow, pytest.mark.serial]

CUBE = str(scenario_path("cube_6_2"))


def _launch_until_flying(tmp_path: Path) -> tuple[subprocess.Popen[str], list[str]]:
    """A kinematic cube mission in real time, read until every agent's state was shown:
    the process and the lines read so far."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "agent.cli", "launch", CUBE, "--runs", str(tmp_path / "runs"),
         "--timeout", "60", "--rate-scale", "1"],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=repo_env(),
        cwd=tmp_path)
    assert proc.stdout is not None
    lines: list[str] = []
    shown: set[str] = set()
    while shown != {"A", "B", "C"}:
        lines.append(line := proc.stdout.readline())
        if not line:
            reap([proc])
            pytest.fail("".join(lines))
        words = line.split()
        if words[:1] == ["launch:"] and words[1] in "ABC" and words[2] != "-":
            shown.add(words[1])
    return proc, lines


def _ended(tmp_path: Path) -> tuple[dict[str, Any], dict[str, Any]]:
    """``launch.json`` and the launcher's last event of the one run folder (parsed JSON)."""
    (run,) = (tmp_path / "runs").iterdir()
    doc = json.loads((run / "launch.json").read_text())
    events = [json.loads(x) for x in (run / "events.jsonl").read_text().splitlines()]
    (end,) = [e for e in events if e["kind"] == "launch_end"]
    return doc, end


@pytest.mark.parametrize("order", ["land", "stop"])
def test_an_operator_ending_the_mission_is_exit_0_and_says_so(tmp_path: Path,
                                                               order: str) -> None:
    proc, lines = _launch_until_flying(tmp_path)
    try:
        (cmd,) = [x.split(": ", 2)[2] for x in lines if x.startswith(f"launch: {order}: ")]
        argv = [sys.executable, "-m", "agent.cli", *shlex.split(cmd)[1:]]
        sent = subprocess.run(argv, capture_output=True, text=True, env=repo_env(), timeout=60)
        assert sent.returncode == 0, sent.stdout + sent.stderr
        out, _ = proc.communicate(timeout=60)
    finally:
        reap([proc])
    how = f"ended by the operator ({order} --all)"
    (run,) = (tmp_path / "runs").iterdir()
    assert proc.returncode == 0, out
    assert out.splitlines()[-1] == f"launch: {how}; logs and journals in {run}"
    doc, end = _ended(tmp_path)
    assert (doc["exit_status"], doc["ended"]) == (0, how)
    assert (end["status"], end["text"]) == (0, f"launch: {how} (exit status 0)")


def test_ctrl_c_is_130_in_the_status_launch_json_and_events(tmp_path: Path) -> None:
    proc, _lines = _launch_until_flying(tmp_path)
    try:
        proc.send_signal(signal.SIGINT)
        out, _ = proc.communicate(timeout=60)
    finally:
        reap([proc])
    assert proc.returncode == 130, out
    doc, end = _ended(tmp_path)
    assert (doc["exit_status"], doc["ended"]) == (130, "interrupted by SIGINT")
    assert (end["status"], end["text"]) == (130, "launch: interrupted by SIGINT (exit status "
                                                 "130)")
    # the launcher stops its agents with SIGTERM: a service manager's orderly stop, status 0
    assert {a: doc["processes"][a]["exit_code"] for a in "ABC"} == {
        "A": 0, "B": 0, "C": 0}


def test_a_kinematic_agent_stopped_by_ctrl_c_exits_130(router: str, tmp_path: Path) -> None:
    """SIGINT: 130, as shells report it (SIGTERM, the stop of systemd and of the launcher, is
    a clean 0: the previous test)."""
    agent = subprocess.Popen(
        [sys.executable, "-m", "agent.cli", "agent", "--id", "A", "--scenario", CUBE,
         "--connect", router, "--state-dir", str(tmp_path / "A")],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=repo_env())
    tp = ZenohTransport(client_config([router]), None, "probe")
    try:
        assert wait_until(lambda: "A" in live_agents(tp, "cube_6_2", 0.2), 30.0)
        agent.send_signal(signal.SIGINT)
        out, err = agent.communicate(timeout=30)
    finally:
        tp.close()
        reap([agent])
    assert agent.returncode == 130, out + err
