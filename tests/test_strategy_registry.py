"""The registry of strategies (:mod:`agent.strategy.registry`): every name a scenario may give
is registered once with its moves, the agents carry them out in order, a strategy is its
registration line, and a scenario naming an unknown strategy or one that needs trading without
it gets one line naming the field."""

from __future__ import annotations

import dataclasses
import re
from pathlib import Path
from typing import Any, cast

import pytest

from agent.config.parse import load_scenario
from agent.config.validation import ScenarioError
from agent.protocol.regroup import nothing_moves
from agent.runtime.core.events import Asking
from agent.runtime.moves.drivers import StrategyDriver
from agent.runtime.moves.move import Move, move_class
from agent.runtime.moves.revert import Revert
from agent.runtime.shell.runtime import AgentConfig
from agent.strategy.registry import (
    INSPECTION_MOVES,
    REGISTRY,
    STRATEGIES,
    Moves,
    Strategy,
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


class _Recording(Move):
    """A move that records its calls and answers ``answer``; it claims re-split offers
    (``decide``) and publishes ``fields``."""

    def __init__(self, calls: list[str], name: str, answer: bool, decide: Any = None,
                 fields: dict[str, Any] | None = None) -> None:
        self.calls, self.name, self.answer = calls, name, answer
        self.decide, self.fields = decide, fields or {}

    def step(self, now: float) -> Asking[bool]:
        yield from ()
        self.calls.append(self.name)
        return self.answer

    def terms(self, req: Any) -> Any:
        return self.decide

    def published(self) -> dict[str, Any]:
        return self.fields


def test_the_driver_tries_a_strategys_moves_in_their_registered_order() -> None:
    """Holding moves in order until one is under way; a converged drone's moves in order
    until one takes the tick; none: the thesis' tick (planner step or Algorithm-7 offer)."""
    calls: list[str] = []
    driver = StrategyDriver([_Recording(calls, "team_move", False),
                             _Recording(calls, "revert", True),
                             _Recording(calls, "initial_split", True)],
                            [_Recording(calls, "regroup", False)])
    assert drive(driver.holds(0.0)) is True
    assert calls == ["team_move", "revert"]  # the first under way ends the search
    calls.clear()
    assert drive(driver.converged(0.0)) is False  # nothing took the tick: offer Algorithm 7
    assert calls == ["regroup"]
    thesis = StrategyDriver([], [])
    calls.clear()
    assert (drive(thesis.holds(0.0)), drive(thesis.converged(0.0)), calls) == (False, False, [])


def test_the_first_move_that_claims_a_resplit_judges_it_and_moves_publish_their_fields(
) -> None:
    """A re-split offer is judged by the first move (in registered order) whose ``terms``
    claims it; one no move claims moves nothing. Each move's published fields join."""
    calls: list[str] = []
    def first(*_: Any) -> Any:
        return None

    def second(*_: Any) -> Any:
        return None

    driver = StrategyDriver([_Recording(calls, "a", False, None, {"reverting": True})],
                            [_Recording(calls, "b", False, first, {"stage1_vision": 2.0}),
                             _Recording(calls, "c", False, second)])
    assert driver.terms(cast(Any, None)) is first
    assert StrategyDriver([], [_Recording(calls, "c", False)]).terms(cast(Any, None)) \
        is nothing_moves
    assert driver.published() == {"reverting": True, "stage1_vision": 2.0}


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
    monkeypatch.setitem(REGISTRY, "pairs", Strategy(
        "pairs", "re-splits in pairs and triples", Moves(converged=("regroup",))))
    scene = make_scene("box", "heldout", 1, 4, 9)
    stages = {}
    for name in ("pairs", "potential"):
        sc = dataclasses.replace(scene.scenario(), strategy=name, lost_after=0.0)
        m = MemoryMission(sc, tmp_path / name, None, seed=1,
                          config=AgentConfig(mission="registry", seed=1))
        try:
            assert m.run(sc.duration), name
            assert m.violations == [] and m.final_violations() == []
            rts = list(m.agents.values())
            stages[name] = {rt.core.moves.final_stage for rt in rts}
            if name == "pairs":
                assert all(rt.core.shared.stage == rt.core.moves.final_stage == 3 for rt in rts)
                assert all(rt.core.moves.started[4] == 0 and rt.core.driver.find(Revert) is None
                           for rt in rts)
        finally:
            m.close()
    assert stages == {"pairs": {3}, "potential": {5}}


def test_every_move_a_strategy_names_is_a_module_of_its_kind() -> None:
    """Each move a registered strategy (or an inspection) names is the ``MOVE`` of module
    ``agent.runtime.moves.<name>``, of the kind the strategy tries it as; a name without
    one is refused in one line."""
    for moves in (*(s.moves for s in REGISTRY.values()), INSPECTION_MOVES):
        assert [move_class(n).kind for n in moves.holding] == ["holding"] * len(moves.holding)
        assert [move_class(n).kind for n in moves.converged] == ["taking"] * len(moves.converged)
    with pytest.raises(LookupError, match=r"^move 'hover': no module agent.runtime.moves.hover$"):
        move_class("hover")
    with pytest.raises(LookupError, match=r"^move 'drivers': agent.runtime.moves.drivers has "
                       "no MOVE class$"):
        move_class("drivers")
