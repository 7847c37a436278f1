"""The coverage-move strategy never ends below the thesis strategy from the same start."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from bench.quality.strategy_sim import StrategySim, run_strategy, run_thesis
from bench.quality.structures import make_scene

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
    scene = make_scene(*case)
    thesis, mine = run_thesis(scene), run_strategy(scene)
    assert mine.complete
    assert mine.score >= thesis.score - 1e-9


def test_phase_one_reproduces_the_thesis_run() -> None:
    scene = make_scene("box", "heldout", 0, 3, 1)
    thesis = run_thesis(scene)
    sim = StrategySim(scene)
    while sim.thesis_score is None:
        sim.tick()
    assert sim.thesis_score == pytest.approx(thesis.score, abs=1e-9)
    assert np.array_equal(sim.owner, thesis.owner)
    assert np.allclose(np.array([a.p for a in sim.agents]), thesis.P)


def test_the_scenario_field_runs_the_potential_strategy(tmp_path: Path) -> None:
    """``strategy = "potential"`` in the two-agent scenario of section 5.2 (with trading):
    simulate ends at
    least as high as the thesis' run from the same start, complete, and with no landmark
    unseen by its owner."""
    from agent.config.scenario import load_scenario
    from agent.sim.kinematic import simulate
    from tests.conftest import scenario_path

    src = scenario_path("two_agents_5_2").read_text().replace("trading = false",
                                                                "trading = true")
    (tmp_path / "thesis.toml").write_text(src)
    path = tmp_path / "two.toml"
    path.write_text('strategy = "potential"\n' + src)
    potential, thesis = load_scenario(path), load_scenario(tmp_path / "thesis.toml")
    assert (potential.strategy, thesis.strategy) == ("potential", "thesis")
    a, b = simulate(thesis), simulate(potential)
    assert b.strategy == "potential" and b.complete
    assert float(b.coverage[-1]) >= float(a.coverage[-1]) - 1e-9
    assert b.seen_by_owner().all()


def test_the_potential_strategy_on_a_mesh_keeps_clear_of_it() -> None:
    """The L-shaped building (facing visibility): over the whole run no drone comes closer to
    the mesh than structure.margin, and the final score is at least the thesis' one."""
    import dataclasses

    from agent.config.scenario import load_scenario
    from agent.sim.kinematic import simulate
    from agent.world.structure import structure_model
    from tests.conftest import scenario_path

    sc = dataclasses.replace(load_scenario(scenario_path("l_building")), visibility="facing",
                             inspection=None)  # its coverage mission
    a, b = simulate(sc), simulate(dataclasses.replace(sc, strategy="potential"))
    assert sc.structure is not None
    model = structure_model(sc.structure)
    assert float(model.distance(b.positions.reshape(-1, 3)).min()) >= sc.structure.margin - 1e-6
    assert float(b.coverage[-1]) >= float(a.coverage[-1]) - 1e-9
