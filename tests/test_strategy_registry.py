"""The registry of strategies (:mod:`agent.strategy.registry`): every name a scenario may give
is registered once with its moves, the agents carry them out in order, a strategy is its
registration line, and a scenario naming an unknown strategy or one that needs trading without
it gets one line naming the field."""

from __future__ import annotations

import dataclasses
import re
from pathlib import Path
from types import SimpleNamespace
from typing import Any, cast, get_args

import pytest

from agent.config.parse import load_scenario
from agent.config.validation import ScenarioError
from agent.runtime.agent import AgentConfig
from agent.runtime.drivers import MoveStep, StrategyDriver, strategy_driver
from agent.runtime.events import Asking
from agent.strategy.registry import (
    INSPECTION_MOVES,
    REGISTRY,
    STRATEGIES,
    HoldingMove,
    Moves,
    Strategy,
    StrategyName,
    TakingMove,
    strategy_of,
)
from agent.testing.memsim import MemoryMission
from bench.quality.structures import make_scene
from tests.conftest import ROOT


def test_every_name_is_registered_once_under_its_own_name() -> None:
    assert set(STRATEGIES) == set(REGISTRY)
    assert all(strategy_of(name).name == name for name in STRATEGIES)


def test_no_driver_compares_a_strategy_name() -> None:
    """The simulator, the agents and the world read the registry's flags: no module outside
    the registry compares ``strategy`` with a name."""
    pattern = re.compile(r"strategy\s*[!=]=\s*[\"'](thesis|potential)[\"']")
    found = [f"{p.relative_to(ROOT)}:{n}" for p in sorted((ROOT / "agent").rglob("*.py"))
             for n, line in enumerate(p.read_text(encoding="utf-8").splitlines(), 1)
             if pattern.search(line)]
    assert found == []


def _scenario(tmp_path: Path, extra: str) -> Path:
    src = (ROOT / "scenarios" / "hexagon_5_3.toml").read_text(encoding="utf-8")
    path = tmp_path / "s.toml"
    path.write_text(extra + src)
    return path


def test_an_unknown_strategy_is_one_line_naming_the_field(tmp_path: Path) -> None:
    with pytest.raises(ScenarioError) as e:
        load_scenario(_scenario(tmp_path, 'strategy = "greedy"\n'))
    assert str(e.value) == (f"{tmp_path / 's.toml'}: strategy: unknown strategy 'greedy'; "
                            "use one of 'thesis', 'potential'")


def test_a_strategy_that_moves_landmarks_needs_trading(tmp_path: Path) -> None:
    with pytest.raises(ScenarioError) as e:
        load_scenario(_scenario(tmp_path, 'strategy = "potential"\ntrading = false\n'))
    assert "strategy: 'potential' moves landmarks between agents; set trading = true" \
        in str(e.value)
    assert strategy_of(load_scenario(_scenario(tmp_path, 'strategy = "potential"\n'))
                       .strategy).coverage_moves


def _recording_move(calls: list[str], name: str, answer: bool) -> MoveStep:
    def move(now: float) -> Asking[bool]:
        yield from ()
        calls.append(name)
        return answer
    return move


def test_the_driver_tries_a_strategys_moves_in_their_registered_order() -> None:
    """Holding moves in order until one is under way; a converged drone's moves in order
    until one takes the tick; none: the thesis' tick (planner step or Algorithm-7 offer)."""
    calls: list[str] = []
    holding: dict[HoldingMove, MoveStep] = {
        "team_move": _recording_move(calls, "team_move", False),
        "revert": _recording_move(calls, "revert", True),
        "initial_split": _recording_move(calls, "initial_split", True)}
    taking: dict[TakingMove, MoveStep] = {"regroup": _recording_move(calls, "regroup", False),
                                          "take_work": _recording_move(calls, "take_work", True)}
    driver = StrategyDriver(Moves(("team_move", "revert", "initial_split"), ("regroup",)),
                            holding, taking)
    assert drive(driver.holds(0.0)) is True
    assert calls == ["team_move", "revert"]  # the first under way ends the search
    calls.clear()
    assert drive(driver.converged(0.0)) is False  # nothing took the tick: offer Algorithm 7
    assert calls == ["regroup"]
    thesis = StrategyDriver(strategy_of("thesis").moves, holding, taking)
    calls.clear()
    assert (drive(thesis.holds(0.0)), drive(thesis.converged(0.0)), calls) == (False, False, [])


def drive(steps: Asking[bool]) -> bool:
    """The result of a move that asks nothing."""
    try:
        next(steps)
    except StopIteration as done:
        return bool(done.value)
    raise AssertionError("the move asked something")


def test_a_strategy_is_its_registration_line(tmp_path: Path,
                                             monkeypatch: pytest.MonkeyPatch) -> None:
    """A strategy registered with one line and nothing else runs on the agents with exactly
    its moves: "pairs" (the potential strategy's pair and triple re-splits without the
    whole-team re-splits or the revert) on four drones completes, with the coverage stage and
    no team stage, where "potential" on the same start has two team stages."""
    monkeypatch.setitem(REGISTRY, cast(StrategyName, "pairs"), Strategy(
        cast(StrategyName, "pairs"), "re-splits in pairs and triples",
        Moves(converged=("regroup",))))
    scene = make_scene("box", "heldout", 1, 4, 9)
    stages = {}
    for name in ("pairs", "potential"):
        sc = dataclasses.replace(scene.scenario(), strategy=cast(StrategyName, name),
                                 lost_after=0.0)
        m = MemoryMission(sc, tmp_path / name, None, seed=1,
                          config=AgentConfig(mission="registry", seed=1))
        try:
            assert m.run(sc.duration), name
            assert m.violations == [] and m.final_violations() == []
            rts = list(m.agents.values())
            stages[name] = {rt.shared.final_stage for rt in rts}
            if name == "pairs":
                assert all(rt.shared.stage == rt.shared.final_stage == 3 for rt in rts)
                assert all(rt.moves.started[4] == 0 and rt.revert.pulls == 0 for rt in rts)
        finally:
            m.close()
    assert stages == {"pairs": {3}, "potential": {5}}


def test_every_move_a_strategy_may_name_has_its_part_in_the_agent() -> None:
    """Each holding and taking move has its part in :func:`strategy_driver` (a strategy
    naming any of them builds), with and without an inspection mission."""
    part = SimpleNamespace(maybe_team_move=None, maybe_regroup=None, step=None,
                           initial_split=None, tick=None)
    every = Moves(get_args(HoldingMove), get_args(TakingMove))
    for name in STRATEGIES:
        assert strategy_driver(name, cast(Any, part), cast(Any, part), None).moves \
            == strategy_of(name).moves
    assert strategy_driver("thesis", cast(Any, part), cast(Any, part), cast(Any, part)).moves \
        == INSPECTION_MOVES
    with pytest.MonkeyPatch.context() as mp:
        mp.setitem(REGISTRY, "thesis", Strategy("thesis", "every move", every))
        with pytest.raises(KeyError, match="initial_split"):  # an inspection's only
            strategy_driver("thesis", cast(Any, part), cast(Any, part), None)
