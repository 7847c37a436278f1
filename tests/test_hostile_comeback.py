"""Issue 33, comebacks, with real processes on a TLS router: drone C is killed before its
journal's first write (here: it never started), so its team never heard it; A and B fence it
after ``lost_after``, adopt its landmarks and finish. C then starts on a new journal, from the
scenario's sets (the adopted landmarks): its first life hears the router's fence record,
which proves the fence, with no team member live; within the final word's bound (30 s) it
takes the proof and leaves holding nothing, exit 0, told by the record. Before issue 33 a
first life ignored the record's proofs and kept the adopted landmarks (for its whole
``--timeout``, never told it was fenced).

Long (the final word's 30 s): the same property, on cores stepped by hand with a record
answered in memory, is checked in ``make test`` by
``tests/test_hostile_offers.py::test_a_comeback_on_a_new_journal_after_its_team_finished_is_told_it_was_fenced``.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from agent.config.parse import load_scenario
from agent.net.pki import TeamPlan, make_team
from agent.net.router import start_router_process, stop_router_process
from agent.net.security import TeamDir
from agent.protocol.machine import TradeMachine
from agent.storage.journal import Journal
from tests.conftest import reap, repo_env, scenario_path

pytestmark = [pytest.mark.long, pytest.mark.serial]


def spawn(aid: str, scene: Path, endpoint: str, state: Path, team: TeamDir,
          *extra: str) -> subprocess.Popen[str]:
    cmd = [sys.executable, "-m", "agent.cli", "agent", "--id", aid, "--scenario", str(scene),
           "--connect", endpoint, "--state-dir", str(state / aid), "--rate-scale", "10",
           "--request-timeout", "0.15", "--timeout", "120", "--tls-dir", str(team.path), *extra]
    return subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env=repo_env())


def test_a_drone_back_on_a_new_journal_after_its_team_finished_is_told_it_was_fenced(
        tmp_path: Path) -> None:
    team = make_team(TeamPlan(tmp_path / "team", ["A", "B", "C"]))
    scene = tmp_path / "scene.toml"
    scene.write_text("lost_after = 20.0\n" + scenario_path("hexagon_5_3").read_text())
    sc = load_scenario(scene)
    router, ep = start_router_process(team=team)
    procs: list[subprocess.Popen[str]] = []
    try:
        procs = [spawn(a, scene, ep, tmp_path, team, "--exit-on-complete") for a in "AB"]
        for p in procs:
            assert p.wait(90) == 0, reap(procs)
        c = spawn("C", scene, ep, tmp_path, team)
        procs.append(c)
        assert c.wait(90) == 0
        err = reap([c])[c.pid]
        assert "fence-record" in err, err[-2000:]
        m = TradeMachine("C", list(sc.landmark_ids))
        j = Journal(tmp_path / "C")
        try:
            for rec in j.replay():
                m.apply(rec)
        finally:
            j.close()
        assert not m.owned and m.fenced_out is not None
    finally:
        reap(procs)
        stop_router_process(router)
