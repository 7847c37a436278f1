"""An honest end of an inspection mission (agent.protocol.inspection_end): complete only when
every capturable landmark is captured; otherwise, once the team stops or the time runs out,
incomplete, naming every capturable landmark left with why it was given up, the same in the
lockstep simulator, the agents in memory, the observer and ``viscover status``, each agent's
end line, and ``viscover simulate`` (its last line, result.json, the report page, exit 3).

The scenario (inline): drone A owns landmark 1, whose every viewpoint lies inside the safety
sphere (R_s = 4.5 m) of drone B, parked at its start after capturing its own landmark 2 from
there (B stands behind landmark 1's face, so it never images it, and is farther than A from
its viewpoints, so it never takes it over): A's flights towards them stall, it retries them
all MAX_RETRIES times and gives landmark 1 up as unreachable. Landmark 4 faces the ground:
uncapturable, reported apart. With drone C and landmark 3 far away, the 120 s duration runs
out before C gets there: landmark 3 is given up for time."""

from __future__ import annotations

import io
import json
import subprocess
import sys
from pathlib import Path

import msgspec
import numpy as np
import pytest

from agent.clock import ManualClock
from agent.config.parse import parse_scenario
from agent.config.scenario import Scenario
from agent.mission.observer import print_report
from agent.mission.status import summary_line
from agent.mission.watch import MissionWatch
from agent.protocol.inspection_end import (
    BATTERY,
    TIME,
    InspectionEnd,
    end_line,
    given_up_codes,
    given_up_sets,
    inspection_end,
    merge_given_up,
)
from agent.runners.process import result_line
from agent.runners.quality import inspection_end_line
from agent.sim.inspection import InspectionSim
from agent.strategy.inspection import BLOCKED, UNREACHABLE, out_of_work
from agent.testing.memsim import MemoryMission
from agent.wire.codec import Codec
from agent.wire.peer import AgentState, Counters, GivenUp, LmSet, Publication, pack_bits
from tests.conftest import ROOT, repo_env

UNCAPTURABLE = "1 uncapturable (1: every pose that would image it is outside the mission space)"
#: the team stops: A gave landmark 1 up, B captured landmark 2, landmark 4 is uncapturable
BLOCKED_END = (f"captured 1/2 at quality >= 0.99; {UNCAPTURABLE}; "
               "INCOMPLETE: 1 given up (1 unreachable: 1)")
#: ... and C is still flying to landmark 3 when the duration runs out
TIMED_END = (f"captured 1/3 at quality >= 0.99; {UNCAPTURABLE}; "
             "INCOMPLETE: 2 given up (1 unreachable: 1; 1 time: 3)")

LANDMARKS = {
    1: "position = [0.0, 0.0, 2.0]\nnormal = [1.0, 0.0, 0.0]",  # viewpoints at x = 1.8-2
    2: "position = [-3.0, 0.0, 2.0]\nnormal = [1.0, 0.0, 0.0]",  # B images it from its start
    3: "position = [50.0, 0.0, 2.0]\nnormal = [1.0, 0.0, 0.0]",  # C needs ~140 s to get there
    4: "position = [-3.0, 3.0, 0.6]\nnormal = [0.0, 0.0, -1.0]",  # faces the ground
}
AGENTS = {
    "A": ("position = [3.8, 0.0, 2.0]\ndirection = [1.0, 0.0, 0.0]", [1]),
    "B": ("position = [-1.0, 0.0, 2.0]\ndirection = [-1.0, 0.0, 0.0]", [2, 4]),
    "C": ("position = [10.0, 0.0, 2.0]\ndirection = [1.0, 0.0, 0.0]", [3]),
}


def _toml(agents: str, duration: float) -> str:
    """The scenario with drones ``agents`` (of A, B, C) and their landmarks."""
    lms = sorted(lid for a in agents for lid in AGENTS[a][1])
    text = (f'name = "given_up"\ndims = 3\nd_opt = 2.0\nduration = {duration}\n[space]\n'
            "lo = [-10.0, -10.0, 0.5]\nhi = [60.0, 10.0, 10.0]\n[planner]\nr_s = 4.5\n")
    text += "".join(f"[[landmarks]]\nid = {lid}\n{LANDMARKS[lid]}\n" for lid in lms)
    text += "".join(f'[[agents]]\nid = "{a}"\n{AGENTS[a][0]}\nlandmarks = {AGENTS[a][1]}\n'
                    for a in agents)
    return text + "[inspection]\nquality = 0.99\nmax_incidence_deg = 10.0\n"


def _scenario(agents: str, duration: float) -> Scenario:
    return parse_scenario(_toml(agents, duration), "given_up.toml")


def _lockstep(sc: Scenario) -> InspectionSim:
    sim = InspectionSim(sc)
    while not sim.done and sim.t < sc.duration:
        sim.tick()
    return sim


# -- the pure end ------------------------------------------------------------------------


def test_the_end_is_complete_only_with_every_capturable_landmark_captured() -> None:
    ids = np.array([10, 11, 12, 13, 14, 15], dtype=np.int64)
    capturable = np.array([True, True, True, True, True, False])
    codes = np.array([UNREACHABLE, BLOCKED, BATTERY, 0, UNREACHABLE, 0], dtype=np.int8)
    captured = np.array([False, False, False, False, True, False])  # 14: given up, then seen
    end = inspection_end(ids, capturable, captured, codes, t=12.5)
    assert end.given_up == {10: "unreachable", 11: "blocked", 12: "battery", 13: "time"}
    assert not end.complete and end.t is None
    assert end.verdict() == ("INCOMPLETE: 4 given up (1 unreachable: 10; 1 blocked: 11; "
                             "1 battery: 12; 1 time: 13)")
    done = inspection_end(ids, capturable, capturable, codes, t=12.5)
    assert done.complete and done.verdict() == "complete at t = 12.5 s"
    assert end_line("captured 6/6 at quality >= 0.3; 0 uncapturable", done) == \
        "captured 6/6 at quality >= 0.3; 0 uncapturable; complete at t = 12.5 s"
    many = InspectionEnd({i: "time" for i in range(25)})
    assert many.verdict() == ("INCOMPLETE: 25 given up (25 time: " + ", ".join(
        map(str, range(20))) + " ...)")
    published = given_up_codes(given_up_sets(codes), ids.size)
    assert published is not None and published.tolist() == codes.tolist()
    assert given_up_sets(np.array([TIME], np.int8)) == []  # time is never published


def test_drones_merge_given_up_sets_the_same_whatever_the_order() -> None:
    """blocked wins over unreachable, which wins over battery; merging is order-free and
    idempotent, and the published bit sets carry the codes exactly."""
    a = np.array([UNREACHABLE, BATTERY, 0, BLOCKED], dtype=np.int8)
    b = np.array([BLOCKED, UNREACHABLE, BATTERY, 0], dtype=np.int8)
    ab = merge_given_up(a, b)
    assert ab.tolist() == [BLOCKED, UNREACHABLE, BATTERY, BLOCKED]
    assert merge_given_up(b, a).tolist() == ab.tolist()
    assert merge_given_up(ab, ab).tolist() == ab.tolist()
    sets = given_up_sets(ab)
    assert [s.reason for s in sets] == ["unreachable", "blocked", "battery"]
    got = given_up_codes(sets, 4)
    assert got is not None and got.tolist() == ab.tolist()
    assert given_up_codes([GivenUp("blocked", b"\xff")], 4) is None  # bits past the last


def test_a_state_from_a_build_before_given_up_sets_still_decodes() -> None:
    codec: Codec[Publication] = Codec(Publication)
    st = AgentState(sender="A", incarnation=1, seq=1, t=0.0, p=(0.0, 0.0, 0.0),
                    v=(1.0, 0.0, 0.0), phase="converged", owned=LmSet(), held=LmSet(),
                    vision=0.0, counters=Counters(), partners=[], pending=[], trades_with={},
                    capturable=b"\x07", given_up=[GivenUp("unreachable", b"\x01")])
    raw = msgspec.msgpack.decode(codec.encode(st))
    assert raw["given_up"] == [["unreachable", b"\x01"]] and raw["capturable"] == b"\x07"
    old = {k: v for k, v in raw.items() if k not in ("given_up", "capturable")}
    back = codec.decode(msgspec.msgpack.encode(old), "viscover/m/state/A")
    assert isinstance(back, AgentState) and back.given_up == [] and back.capturable == b""
    again = codec.decode(codec.encode(st), "viscover/m/state/A")
    assert isinstance(again, AgentState) and again.given_up == st.given_up


# -- the simulator and the agents --------------------------------------------------------


def test_a_blocked_landmark_is_given_up_and_the_team_ends_incomplete(tmp_path: Path) -> None:
    """A cannot reach landmark 1's viewpoints: the lockstep simulator and the agents in memory
    both give it up as unreachable and stop (every drone home) before the duration; every
    agent's view, its end line and result line, the published states, the observer and
    ``viscover status`` name it the same."""
    sc = _scenario("AB", 400.0)
    sim = _lockstep(sc)
    assert sim.done and sim.t < 150.0 and not sim.complete
    assert sim.summary().end_line(sim.t_complete) == BLOCKED_END

    mm = MemoryMission(sc, tmp_path)
    watch = MissionWatch(mm.net.transport("watch"), "mem", sc, clock=mm.clock)
    try:
        assert mm.run(400.0) and mm.net.now < 150.0  # the team stopped: every drone home
        mm.run(mm.net.now + 1.0, until=lambda _m: False)  # the last states reach the watch
        for rt in mm.agents.values():  # each agent's view
            ins = rt.core.planning.inspecting
            assert ins is not None and rt.complete  # the team's termination
            assert ins.end(rt.completed_at).given_up == {1: "unreachable"}
            assert inspection_end_line(rt) == BLOCKED_END
            doc = json.loads(result_line(rt, ManualClock(), {}))
            assert doc["complete"] is False and doc["given_up"] == {"1": "unreachable"}
            st = rt.state_message()
            assert st.given_up == [GivenUp("unreachable", pack_bits(np.array([True, False,
                                                                              False])))]
            assert st.capturable == pack_bits(np.array([True, True, False]))
        rep = watch.observer.snapshot()
        assert rep.ended and not rep.complete and rep.violations == []
        assert rep.inspection == {"captured": 1, "capturable": 2,
                                  "given_up": {"1": "unreachable"},
                                  "verdict": "INCOMPLETE: 1 given up (1 unreachable: 1)"}
        out = io.StringIO()
        print_report(rep, out)
        assert ", INCOMPLETE: 1 given up (1 unreachable: 1) (after " in out.getvalue()
        line = summary_line(watch.view())
        assert line.startswith("mission mem: INCOMPLETE: 1 given up (1 unreachable: 1), "), line
    finally:
        watch.close()
        mm.close()


def test_time_runs_out_and_the_simulator_and_the_agents_name_the_same_landmarks(
        tmp_path: Path) -> None:
    """With C still on its way to landmark 3 at the 120 s duration: landmark 1 given up as
    unreachable, landmark 3 for time, in the lockstep simulator and in every agent's view;
    the observer says the same of the mission stopped then (what a launch's --timeout
    reports)."""
    sc = _scenario("ABC", 120.0)
    sim = _lockstep(sc)
    assert not sim.done
    assert sim.summary().end_line(sim.t_complete) == TIMED_END

    mm = MemoryMission(sc, tmp_path)
    watch = MissionWatch(mm.net.transport("watch"), "mem", sc, clock=mm.clock)
    try:
        assert not mm.run(sc.duration)
        for rt in mm.agents.values():
            ins = rt.core.planning.inspecting
            assert ins is not None and not rt.complete
            assert ins.end().given_up == {1: "unreachable", 3: "time"}
            assert inspection_end_line(rt) == TIMED_END
        assert watch.observer.unfinished() == \
            "; INCOMPLETE: 2 given up (1 unreachable: 1; 1 time: 3)"
        assert not watch.observer.snapshot().ended
    finally:
        watch.close()
        mm.close()


def test_a_drone_leaving_on_low_battery_gives_its_landmarks_up_for_battery(
        tmp_path: Path) -> None:
    """C gives up what it still owns as it leaves (Inspecting.give_up_rest, as the battery
    hand-over does when nobody took its work): its state says so, its peers merge it, and it
    stays work (it is not out of anyone's work: an adopter would try it)."""
    sc = _scenario("ABC", 120.0)
    mm = MemoryMission(sc, tmp_path)
    try:
        mm.run(5.0)
        c = mm.agents["C"].core.planning.inspecting
        assert c is not None and c.give_up_rest() == 1
        assert c.end().given_up == {1: "time", 3: "battery"}
        assert not out_of_work(c.given_up).any()  # still work for whoever takes it over
        mm.run(7.0)
        a = mm.agents["A"].core.planning.inspecting
        assert a is not None and a.given_up.tolist() == [0, 0, BATTERY, 0]
        assert mm.agents["C"].state_message().given_up == [
            GivenUp("battery", pack_bits(np.array([False, False, True, False])))]
    finally:
        mm.close()


# -- viscover simulate -------------------------------------------------------------------


def _simulate(tmp_path: Path, text: str, *args: str) -> tuple[subprocess.CompletedProcess[str],
                                                               dict[str, object]]:
    path = tmp_path / "given_up.toml"
    path.write_text(text)
    out = tmp_path / f"out{len(list(tmp_path.iterdir()))}"
    run = subprocess.run([sys.executable, "-m", "agent.cli", "simulate", str(path), "--out",
                          str(out), *args], capture_output=True, text=True, env=repo_env(),
                         cwd=ROOT, timeout=300)
    doc = json.loads((out / "result.json").read_text()) if (out / "result.json").is_file() \
        else {}
    if (out / "report.html").is_file():
        doc["_page"] = (out / "report.html").read_text()
    return run, doc


@pytest.mark.parametrize("engine", ["agents", "lockstep"])
def test_viscover_simulate_of_an_incomplete_inspection_exits_3_and_names_what_was_left(
        tmp_path: Path, engine: str) -> None:
    run, doc = _simulate(tmp_path, _toml("ABC", 120.0), "--engine", engine,
                         *(["--no-plots"] if engine == "lockstep" else []))
    assert run.returncode == 3, run.stdout + run.stderr
    assert run.stdout.splitlines()[1] == TIMED_END, run.stdout
    ins = doc["inspection"]
    assert isinstance(ins, dict) and doc["complete"] is False and doc["t_complete"] is None
    assert ins["given_up"] == {"1": "unreachable", "3": "time"}
    assert ins["verdict"] == "INCOMPLETE: 2 given up (1 unreachable: 1; 1 time: 3)"
    if engine == "agents":  # the report page says it too, and why for each landmark
        page = str(doc["_page"])
        assert "<td>INCOMPLETE: 2 given up (1 unreachable: 1; 1 time: 3)</td>" in page
        assert "given up: unreachable" in page and "given up: time" in page


def test_viscover_simulate_of_a_complete_inspection_says_complete_and_exits_0(
        tmp_path: Path) -> None:
    """Drone A alone: nothing in its way, landmark 1 captured."""
    run, doc = _simulate(tmp_path, _toml("A", 120.0), "--no-plots")
    assert run.returncode == 0, run.stdout + run.stderr
    line = run.stdout.splitlines()[1]
    assert line.startswith("captured 1/1 at quality >= 0.99; 0 uncapturable; complete at "
                           "t = "), run.stdout
    ins = doc["inspection"]
    assert isinstance(ins, dict) and doc["complete"] is True and ins["given_up"] == {}
    assert line.endswith(f"; {ins['verdict']}") and ins["verdict"] == \
        f"complete at t = {doc['t_complete']:g} s"


# -- viscover launch ---------------------------------------------------------------------


@pytest.mark.slow
@pytest.mark.serial
def test_viscover_launch_of_an_incomplete_inspection_exits_3_and_says_why(
        tmp_path: Path) -> None:
    """Kinematic agent processes on a router: A gives landmark 1 up, the team ends, and the
    launch, each agent, observer.json and launch.json say it as simulate does (exit 3)."""
    path = tmp_path / "given_up.toml"
    path.write_text(_toml("AB", 400.0))
    run = subprocess.run([sys.executable, "-m", "agent.cli", "launch", str(path), "--runs",
                          str(tmp_path / "runs"), "--timeout", "150"], capture_output=True,
                         text=True, env=repo_env(), cwd=tmp_path, timeout=240)
    assert run.returncode == 3, run.stdout[-3000:] + run.stderr[-2000:]
    (folder,) = (tmp_path / "runs").iterdir()
    verdict = "INCOMPLETE: 1 given up (1 unreachable: 1)"
    assert run.stdout.splitlines()[-1] == f"launch: {verdict}; logs and journals in {folder}"
    for a in "AB":
        assert f"[{a}] viscover: agent {a}: {BLOCKED_END}\n" in run.stdout
        (said,) = [json.loads(x.split("] ", 1)[1]) for x in run.stdout.splitlines()
                   if x.startswith(f"[{a}] {{")]
        assert said["complete"] is False and said["given_up"] == {"1": "unreachable"}
    obs = json.loads((folder / "observer.json").read_text())
    assert (obs["ended"], obs["complete"], obs["violations"]) == (True, False, [])
    assert obs["inspection"]["given_up"] == {"1": "unreachable"}
    doc = json.loads((folder / "launch.json").read_text())
    assert (doc["exit_status"], doc["ended"]) == (3, verdict)
