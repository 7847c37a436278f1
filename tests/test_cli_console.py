"""The console lines an operator reads are labelled and say which clock they count in: a
drone is "not heard yet" while its process may still be starting (then "never heard"),
trades read "2 ok / 5 failed", the coverage at completion is kept beside the coverage after
the flight home, the two clocks of ``viscover launch``'s lines and the report's
axis are named in one line each, and the embreex warning comes out in the log format of
every other line. (The ground station's clock goes out from its pose tick, after the poses:
``tests/test_groundstation_clock_skew.py``.)"""

from __future__ import annotations

import re
import subprocess
import sys
from dataclasses import replace
from types import SimpleNamespace
from typing import cast

from agent.clock import ManualClock
from agent.commands.report import times_line
from agent.config.parse import load_scenario
from agent.mission.status import clocks_line, status_lines, summary_line
from agent.mission.watch import HEARD_WITHIN_S, MissionWatch
from agent.net.memory import MemoryNetwork
from agent.sim.result import SimResult
from agent.wire import keys
from tests.conftest import ROOT, repo_env, scenario_path
from tests.test_status_identity import PUB, state

HEX = str(scenario_path("hexagon_5_3"))


def test_a_drone_is_not_heard_yet_while_it_may_be_starting() -> None:
    clock = ManualClock()
    net = MemoryNetwork()
    watch = MissionWatch(net.transport("launch"), "m", load_scenario(HEX), clock=clock)
    try:
        clock.advance(2.0)  # the first status lines of a launch
        assert [r.link for r in watch.view().rows] == ["not heard yet"] * 3
        clock.advance(HEARD_WITHIN_S)
        watch.expect("C")  # C's process is (re)started only now
        net.transport("A").publish(keys.state_key("m", "A"), PUB.encode(
            state("A", 1, 0.0, {3: 0, 6: 0}, ok=2)))
        view = watch.view()
        assert [(r.id, r.link) for r in view.rows] == [
            ("A", "ok"), ("B", "never heard"), ("C", "not heard yet")]
        lines = status_lines(view, "launch: ")
        assert lines[0].startswith("launch: A optimising 2 lm vis 0.500 trades 2 ok / 0 "
                                   "failed link ok 0.0 s ago ")
        assert " trades - link never heard - " in lines[1]
        assert re.search(r", \d+\.\d s elapsed \(wall\), mission t 0\.0 s, ",
                         summary_line(view)), summary_line(view)
        home = replace(view, complete=True, coverage=5.959, coverage_complete=9.85,
                       complete_t=17.8, mission_t=35.5)  # a flight, back home
        assert ", mission t 35.5 s, coverage 5.959 (9.85 at completion, mission t 17.8 s), " \
            in summary_line(home)
    finally:
        watch.close()


def test_the_two_clocks_are_named_in_one_line() -> None:
    assert clocks_line(10.0, flight=False) == (
        "times: elapsed (wall) is wall time since the first state heard; mission t is the "
        "drones' mission clock (each agent's own clock, from its start; 10x wall time); "
        "viscover report puts every drone on one mission-time axis τ, 0 at the first "
        "recorded sample")
    assert "(the ground station's simulation clock, which the flying agents follow; 3x " \
        "wall time)" in clocks_line(3.0, flight=True)


def test_the_report_names_its_axis_and_the_drones_clocks() -> None:
    sim = SimpleNamespace(clock_offsets={}, time_scale=1.0, wall_origin=None)
    assert times_line(cast(SimResult, sim)) is None  # a simulation: one clock
    r = SimpleNamespace(clock_offsets={"A": 17.7, "B": 17.7, "C": 2.0}, time_scale=3.0,
                        wall_origin=0.0)  # the fields the line reads of a recorded result
    assert times_line(cast(SimResult, r)) == (
        "times: every t here is mission time τ [s], 0 at the first recorded sample; the "
        "drones' own clocks (the \"mission t\" of viscover launch and status) read τ + 17.7 s "
        "(A, B); τ + 2.0 s (C); wall time: τ / 3 after 1970-01-01 00:00:00 UTC")


def test_the_embreex_warning_is_in_the_log_format() -> None:
    code = ("import sys\nsys.modules['embreex'] = None\nfrom agent.cli import main\n"
            "sys.exit(main(['scenario', 'check', sys.argv[1]]))\n")
    r = subprocess.run([sys.executable, "-c", code, str(scenario_path("tower"))],
                       capture_output=True, text=True, env=repo_env(), timeout=120, cwd=ROOT)
    assert r.returncode == 0, r.stderr
    (line,) = [x for x in r.stderr.splitlines() if "embreex" in x]
    assert re.fullmatch(
        r"\d{4}-\d\d-\d\d \d\d:\d\d:\d\d,\d{3} scenario viscover\.agent\.structure\.occlusion "
        r"WARNING occlusion: embreex is not installed, using trimesh's slower pure-numpy ray "
        r"caster \(pip install 'viscover\[occlusion-fast\]' where a wheel exists\)", line), line
