"""The registry of strategies (:mod:`agent.strategy.registry`): every name a scenario may give
is registered once, the drivers read its flags, and a scenario naming an unknown strategy or
one that needs trading without it gets one line naming the field."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from agent.config.scenario import load_scenario
from agent.config.validation import ScenarioError
from agent.strategy.registry import REGISTRY, STRATEGIES, strategy_of
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
