"""``viscover simulate --engine agents``: the simulator driving the agents' own decision code
(:mod:`agent.testing.agent_engine`) reaches the simulator's outcome where the simulator's
drivers and the agents decide alike, and writes the same report."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from agent.cli import main
from agent.config.parse import load_scenario
from agent.sim.kinematic import simulate
from agent.testing.agent_engine import simulate_agents
from tests.agent_helpers import thesis
from tests.conftest import scenario_path


@pytest.mark.parametrize("name", ["hexagon_5_3", "cube_6_2", "two_agents_5_2"])
def test_the_agents_engine_makes_the_simulators_trades_and_ends_at_its_partition(
        name: str) -> None:
    """The thesis' scenarios: the same trades (who, with whom, which landmarks, in order),
    the same final partition and coverage; the agents' trades come no earlier than the
    simulator's (they hear a converged peer one state period late)."""
    sc = thesis(name)
    ref, got = simulate(sc), simulate_agents(sc)
    assert got.complete and ref.complete
    assert np.array_equal(got.final_owner, ref.final_owner)
    assert got.coverage[-1] == pytest.approx(ref.coverage[-1], rel=1e-9)
    key = [(t.initiator, t.partner, t.to_partner, t.to_initiator) for t in ref.trades]
    assert [(t.initiator, t.partner, t.to_partner, t.to_initiator) for t in got.trades] == key
    assert all(g.t >= r.t for g, r in zip(got.trades, ref.trades, strict=True))
    assert all(g.gain > 0.0 for g in got.trades)  # Algorithm 7 trades only when it gains
    assert got.times[0] == 0.0 and np.all(np.diff(got.times) > 0)
    assert got.positions.shape == (got.times.size, len(sc.agents), 3)


def test_an_inspection_by_the_agents_engine_captures_what_the_simulator_captures() -> None:
    sc = load_scenario(scenario_path("tower"))
    ref, got = simulate(sc), simulate_agents(sc)
    assert got.inspection is not None and ref.inspection is not None
    assert sorted(got.inspection.captured) == sorted(ref.inspection.captured)
    assert got.inspection.capturable == ref.inspection.capturable == len(got.inspection.captured)
    assert {lid for c in got.captures for lid in c.landmarks} == set(got.inspection.captured)
    assert got.complete


def test_the_command_writes_the_report(tmp_path: Path, capsys: pytest.CaptureFixture[str]
                                       ) -> None:
    out = tmp_path / "r"
    assert main(["simulate", str(scenario_path("hexagon_5_3")), "--out", str(out),
                 "--engine", "agents", "--quiet"]) == 0
    res = json.loads((out / "result.json").read_text())
    assert res["complete"] and len(res["trades"]) == 3
    assert (out / "report.html").is_file()
    assert "report written to" in capsys.readouterr().out


def test_simulate_runs_the_drones_own_code_unless_asked_for_the_lockstep_engine(
        tmp_path: Path) -> None:
    """By default ``viscover simulate`` is the agents' engine (an inspection ends once every
    drone knows it, after the flights home: later than the lockstep engine's last capture);
    ``--engine lockstep`` is chapter 5's simulation."""
    runs = {}
    for name, extra in (("default", []), ("agents", ["--engine", "agents"]),
                        ("lockstep", ["--engine", "lockstep"])):
        out = tmp_path / name
        assert main(["simulate", str(scenario_path("tower")), "--out", str(out), "--quiet",
                     "--no-plots", *extra]) == 0
        runs[name] = json.loads((out / "result.json").read_text())
    assert runs["default"]["captures"] == runs["agents"]["captures"]
    assert runs["default"]["t_complete"] == runs["agents"]["t_complete"]
    assert runs["lockstep"]["t_complete"] < runs["default"]["t_complete"]
    assert len(runs["default"]["inspection"]["captured"]) == \
        len(runs["lockstep"]["inspection"]["captured"])


def test_the_lockstep_engine_refuses_a_strategy_with_moves_in_one_line(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """``potential`` has one simulator, the agents' code: ``--engine lockstep`` names why and
    the fix, with the usage exit status and nothing written."""
    path = tmp_path / "p.toml"
    path.write_text('strategy = "potential"\n' + scenario_path("hexagon_5_3").read_text())
    assert main(["simulate", str(path), "--out", str(tmp_path / "r"), "--quiet",
                 "--engine", "lockstep"]) == 2
    err = capsys.readouterr().err.strip()
    assert err == ("viscover: error: --engine lockstep: strategy 'potential' runs on the "
                   "agents' decision code only; the lockstep engine runs the thesis (chapter "
                   "5) and inspection missions; drop --engine lockstep")
    assert not (tmp_path / "r").exists()
