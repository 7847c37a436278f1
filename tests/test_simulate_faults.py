"""``viscover simulate --drop P --dup P --jitter S --lose ID@T --fault-seed N``: a whole mission
rehearsed under seeded faults with the agents' own code, watched by an observer as a process
mission is (agent.testing.rehearsal): it completes with its invariants holding, the lost drone
fenced out and its landmarks adopted; the same seed gives the same run; bad values are one
line and exit 2."""

from __future__ import annotations

import dataclasses
import json
import re
from pathlib import Path
from typing import Any

import pytest

from agent.cli import main
from agent.config.parse import load_scenario
from agent.strategy.registry import STRATEGIES
from agent.testing.agent_engine import rehearse
from agent.testing.rehearsal import MissionFaults, faults_of
from tests.conftest import scenario_path


def _with(tmp_path: Path, name: str, **fields: float) -> Path:
    """Shipped scenario ``name`` with top-level ``fields`` replaced or added."""
    text = scenario_path(name).read_text(encoding="utf-8")
    for key, value in fields.items():
        text, n = re.subn(rf"^{key} = .*$", f"{key} = {value}", text, count=1, flags=re.M)
        if not n:
            text = re.sub(r"^(name = .*)$", rf"\1\n{key} = {value}", text, count=1, flags=re.M)
    path = tmp_path / f"{name}.toml"
    path.write_text(text, encoding="utf-8")
    return path


def _simulate(path: Path, out: Path, *flags: str) -> tuple[int, dict[str, Any], dict[str, Any]]:
    code = main(["simulate", str(path), "--out", str(out), "--no-plots", *flags])
    return (code, json.loads((out / "result.json").read_text()),
            json.loads((out / "rehearsal.json").read_text()))


FLAGS = ("--drop", "0.3", "--dup", "0.1", "--jitter", "0.05", "--lose", "C@5",
         "--fault-seed", "3")


def test_a_lossy_mission_with_a_lost_drone_completes_with_its_invariants_holding(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    sc = _with(tmp_path, "hexagon_5_3", lost_after=5.0)
    code, result, rehearsal = _simulate(sc, tmp_path / "a", *FLAGS)
    assert code == 0 and result["complete"]
    assert rehearsal["complete"] and rehearsal["violations"] == []
    assert rehearsal["lost"] == {"C": 5.0}
    assert rehearsal["faults"] == {"drop": 0.3, "dup": 0.1, "jitter_s": 0.05,
                                   "lose": [{"id": "C", "t": 5.0}], "seed": 3}
    seen = rehearsal["observer"]
    assert set(seen["fenced"]) == {"C"} and seen["orphaned"] == {}
    assert seen["violations"] == [] and seen["complete"]
    # every landmark ends with a survivor, and those C held were adopted
    owners = {int(k): v for k, v in seen["owners"].items()}
    assert sorted(owners) == result["landmark_ids"] and set(owners.values()) <= {"A", "B"}
    assert set(seen["adopted"].values()) <= {"A", "B"} and seen["adopted"]
    out = capsys.readouterr().out.splitlines()
    assert "rehearsal: drop 0.3, dup 0.1, jitter 0.05 s, C lost at t = 5 s, fault seed 3" in out
    assert any(x.startswith("states ") and ", complete after " in x and x.endswith(
        "violations 0") for x in out)
    assert out[-2:] == ["lost: C at t = 5 s (fenced out, round "
                        f"{seen['fenced']['C']['epoch']})", "invariants: hold"]


def test_the_same_seed_gives_the_same_run_and_another_seed_another(tmp_path: Path) -> None:
    sc = _with(tmp_path, "hexagon_5_3", lost_after=5.0)
    _simulate(sc, tmp_path / "a", *FLAGS)
    _simulate(sc, tmp_path / "b", *FLAGS)
    for name in ("result.json", "rehearsal.json"):
        assert (tmp_path / "a" / name).read_bytes() == (tmp_path / "b" / name).read_bytes()
    _simulate(sc, tmp_path / "c", *FLAGS[:-1], "4")
    assert (tmp_path / "a" / "result.json").read_bytes() != \
        (tmp_path / "c" / "result.json").read_bytes()


def test_an_inspection_under_loss_with_a_lost_drone_captures_everything() -> None:
    """The l_building inspection (three drones, occlusion): C lost at 3 s under 30 % loss;
    A and B adopt its work and capture every capturable landmark."""
    sc = dataclasses.replace(load_scenario(scenario_path("l_building")), lost_after=5.0)
    result, outcome = rehearse(sc, faults_of(drop="0.3", lose=["C@3"], seed="1"))
    assert outcome.ok and outcome.complete, outcome.violations[:5]
    assert outcome.lost == {"C": 3.0} and set(outcome.report.fenced) == {"C"}
    assert result.inspection is not None and result.inspection.complete
    assert result.inspection.capturable == len(result.inspection.captured)
    assert not any(c.agent == "C" and c.t > 3.0 for c in result.captures)


@pytest.mark.parametrize(("flags", "why"), [
    (["--drop", "1.5"], "--drop 1.5: must be a probability in [0, 1]"),
    (["--dup", "-0.1"], "--dup -0.1: must be a probability in [0, 1]"),
    (["--drop", "x"], "--drop x: not a number"),
    (["--jitter", "-1"], "--jitter -1: must be a non-negative number of seconds"),
    (["--lose", "B"], "--lose B: write ID@T, e.g. --lose B@20 (drone B lost for good at "
                      "mission time 20 s)"),
    (["--lose", "Z@3"], "--lose Z: not a drone of hexagon_5_3 (drones: A, B, C)"),
    (["--lose", "C@-1"], "--lose C@-1: the time must be a non-negative number of mission "
                         "seconds"),
    (["--lose", "C@1", "--lose", "C@2"], "--lose C: given twice (a drone is lost once)"),
    (["--fault-seed", "-2"], "--fault-seed -2: must be a non-negative integer"),
    (["--engine", "lockstep", "--drop", "0.1"],
     "--engine lockstep: faults are rehearsed with the agents' own code over their network; "
     "drop --engine lockstep"),
])
def test_a_bad_fault_value_is_one_line_and_exit_2(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], flags: list[str], why: str) -> None:
    out = tmp_path / "out"
    assert main(["simulate", str(scenario_path("hexagon_5_3")), "--out", str(out),
                 "--quiet", *flags]) == 2
    assert capsys.readouterr().err == f"viscover: error: {why}\n"
    assert not out.exists()


def test_faults_in_words_and_as_the_transports_take_them() -> None:
    f = MissionFaults(drop=0.3, jitter=0.05, losses=(("B", 20.0),), seed=7)
    assert f.describe() == "drop 0.3, jitter 0.05 s, B lost at t = 20 s, fault seed 7"
    cfg = f.network()
    assert cfg is not None and (cfg.drop_default, cfg.duplicate, cfg.jitter_s) == (0.3, 0.0, 0.05)
    assert MissionFaults().describe() == "no faults" and MissionFaults().network() is None


@pytest.mark.parametrize("strategy", STRATEGIES)
def test_every_strategy_is_rehearsed_with_a_lost_drone(strategy: str) -> None:
    """The thesis' cube (section 6.2) under 30 % loss, C lost at 4 s: fenced out, its
    landmarks adopted, complete, nothing violated, whatever the strategy."""
    sc = dataclasses.replace(load_scenario(scenario_path("cube_6_2")), strategy=strategy,
                             lost_after=5.0)
    result, outcome = rehearse(sc, faults_of(drop="0.3", lose=["C@4"], seed="2"))
    assert outcome.ok and outcome.complete and result.complete, outcome.violations[:5]
    assert set(outcome.report.fenced) == {"C"} and outcome.report.orphaned == {}
    assert set(outcome.report.owners.values()) <= {"A", "B"}
    assert sorted(outcome.report.owners) == sorted(sc.landmark_ids)


def test_a_violation_seen_in_a_rehearsal_is_exit_1(
        tmp_path: Path, capsys: pytest.CaptureFixture[str],
        monkeypatch: pytest.MonkeyPatch) -> None:
    """The command's end when the ledgers break the ownership invariant (a rehearsal whose
    outcome says so, the run itself a real one)."""
    import agent.testing.agent_engine as engine

    real = engine.rehearse

    def broken(sc: Any, faults: MissionFaults, progress: Any = None) -> Any:
        result, outcome = real(sc, faults, progress)
        outcome.violations.append("landmark 3: owned by 2 agents: [(1, 'A', 'owned'), "
                                  "(1, 'B', 'owned')]")
        return result, outcome

    monkeypatch.setattr(engine, "rehearse", broken)
    out = tmp_path / "out"
    assert main(["simulate", str(scenario_path("hexagon_5_3")), "--out", str(out),
                 "--no-plots", "--drop", "0.1"]) == 1
    lines = capsys.readouterr().out.splitlines()
    assert lines[-2:] == ["VIOLATION landmark 3: owned by 2 agents: [(1, 'A', 'owned'), "
                          "(1, 'B', 'owned')]", "invariants: 1 violation(s)"]
    assert json.loads((out / "rehearsal.json").read_text())["violations"] != []
