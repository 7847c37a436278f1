"""The coverage-move strategy (``potential``, run by the agents' own code: the simulator's only
run of it) never ends below the thesis strategy from the same start, its thesis stage is the
thesis' run, and on a mesh it keeps clear of the structure."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from agent.config.scenario import Scenario
from agent.runtime.shell.runtime import AgentConfig
from agent.sim.kinematic import simulate
from agent.strategy.registry import StrategyName
from agent.testing.agent_engine import simulate_agents
from agent.testing.memsim import MemoryMission
from bench.bench_quality import AGENTS_TOL
from bench.quality.runs import run_strategy, run_thesis
from bench.quality.structures import make_scene
from tests.agent_helpers import revert_of

#: A fixed seeded set of starts: (kind, split, structure index, team size, start).
STARTS = [
    ("box", "tuning", 0, 2, 0),
    ("box", "heldout", 1, 4, 9),
    ("lshape", "tuning", 1, 3, 1),
    ("lshape", "heldout", 0, 4, 3),
    ("pier", "heldout", 0, 2, 2),
    ("pier", "tuning", 0, 5, 4),
    ("bridge", "heldout", 1, 3, 0),
    ("bridge", "tuning", 0, 4, 2),
]


@pytest.mark.parametrize("case", STARTS, ids=["-".join(map(str, c)) for c in STARTS])
def test_strategy_is_never_below_thesis(case: tuple[str, str, int, int, int]) -> None:
    """Against chapter 5's lockstep run: never below it beyond the benchmark's tolerance
    (asynchronous agents declare convergence at another instant, within 1e-6 of the lockstep
    optimum; :data:`bench.bench_quality.AGENTS_TOL`)."""
    scene = make_scene(*case)
    thesis, mine = run_thesis(scene), run_strategy(scene)
    assert mine.complete
    assert mine.score >= thesis.score * (1.0 - AGENTS_TOL)


def _mission(tmp_path: Path, sc: Scenario, strategy: StrategyName) -> MemoryMission:
    m = MemoryMission(dataclasses.replace(sc, strategy=strategy, lost_after=0.0),
                      tmp_path / strategy, seed=1, config=AgentConfig(mission="q", seed=1))
    assert m.run(sc.duration), strategy
    return m


def test_the_thesis_stage_is_the_thesis_run(tmp_path: Path) -> None:
    """Each agent's record of its thesis stage (set, pose) is where the agents of
    ``strategy = "thesis"`` end from the same start, and its sum is their score."""
    sc = make_scene("box", "heldout", 0, 3, 1).scenario()
    thesis, mine = _mission(tmp_path, sc, "thesis"), _mission(tmp_path, sc, "potential")
    try:
        P, _V, owner = thesis.final_state()
        for i, a in enumerate(sc.agents):  # a loop over the drones
            rec = revert_of(mine.agents[a.id]).record
            assert rec is not None
            rows = thesis.agents[a.id].core.shared.geo.rows(rec.ids)
            assert np.array_equal(np.sort(rows), np.flatnonzero(owner == i))
            assert np.allclose(rec.p, P[i], atol=1e-9)
        assert sum(revert_of(rt).stage1_vision for rt in mine.agents.values()) == pytest.approx(
            thesis.coverage(), rel=1e-9)
    finally:
        thesis.close()
        mine.close()


def test_the_scenario_field_runs_the_potential_strategy(tmp_path: Path) -> None:
    """``strategy = "potential"`` in the two-agent scenario of section 5.2 (with trading):
    ``viscover simulate``'s run ends at least as high as the thesis' lockstep run from the
    same start, complete, and with no landmark unseen by its owner; the lockstep engine
    refuses it."""
    from agent.config.parse import load_scenario
    from tests.conftest import scenario_path

    src = scenario_path("two_agents_5_2").read_text().replace("trading = false",
                                                                "trading = true")
    (tmp_path / "thesis.toml").write_text(src)
    path = tmp_path / "two.toml"
    path.write_text('strategy = "potential"\n' + src)
    potential, thesis = load_scenario(path), load_scenario(tmp_path / "thesis.toml")
    assert (potential.strategy, thesis.strategy) == ("potential", "thesis")
    a, b = simulate(thesis), simulate_agents(potential)
    assert b.strategy == "potential" and b.complete
    assert float(b.coverage[-1]) >= float(a.coverage[-1]) * (1.0 - AGENTS_TOL)
    assert b.seen_by_owner().all()
    with pytest.raises(ValueError, match="strategy 'potential' runs on the agents' decision "
                       "code only; the lockstep engine runs the thesis"):
        simulate(potential)


def test_the_potential_strategy_on_a_mesh_keeps_clear_of_it() -> None:
    """The L-shaped building (facing visibility): over the whole run no drone comes closer to
    the mesh than structure.margin, and the final score is at least the thesis' one."""
    from agent.config.parse import load_scenario
    from agent.world.structure import structure_model
    from tests.conftest import scenario_path

    sc = dataclasses.replace(load_scenario(scenario_path("l_building")), visibility="facing",
                             inspection=None)  # its coverage mission
    a, b = simulate(sc), simulate_agents(dataclasses.replace(sc, strategy="potential"))
    assert sc.structure is not None
    model = structure_model(sc.structure)
    assert float(model.distance(b.positions.reshape(-1, 3)).min()) >= sc.structure.margin - 1e-6
    assert float(b.coverage[-1]) >= float(a.coverage[-1]) * (1.0 - AGENTS_TOL)
