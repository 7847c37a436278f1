"""``strategy = "potential"`` with real agent processes on a real Zenoh router, 30 % loss of
every message: the L-shaped building from the start where the thesis leaves a face unseen
(score 8.72); the agents make their coverage moves asynchronously and end where the
simulator's strategy does (14.30), complete, with every landmark owned once."""

from __future__ import annotations

from pathlib import Path

import pytest

from agent.config.scenario import load_scenario
from bench.quality.strategy_sim import run_strategy, run_thesis
from bench.quality.structures import make_scene
from tests.agent_helpers import scenario_toml
from tests.test_agent_processes import InTestObserver, router_box, spawn_agent, wait_all

pytestmark = [pytest.mark.slow, pytest.mark.serial]
__all__ = ["router_box"]


def test_agent_processes_make_the_coverage_moves_under_loss(router_box, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    scene = make_scene("lshape", "tuning", 1, 3, 1)
    path = tmp_path / "lshape.toml"
    path.write_text(scenario_toml(scene.scenario(), strategy="potential", lost_after=0.0))
    sc = load_scenario(path)
    ob = InTestObserver(router_box["endpoint"], sc, sc.name)
    try:
        outs = wait_all([spawn_agent(a.id, path, router_box["endpoint"], tmp_path, "--drop",
                                     "0.3", "--fault-seed", str(i), timeout=150.0)
                         for i, a in enumerate(sc.agents)], timeout=200)
        assert ob.wait(20.0)
        rep = ob.obs.snapshot()
        assert rep.violations == [] and rep.complete
        assert sorted(rep.owners) == sorted(sc.landmark_ids)
        thesis, ref = run_thesis(scene).score, run_strategy(scene).score
        assert rep.coverage > thesis + 1.0, (rep.coverage, thesis, outs)
        assert rep.coverage == pytest.approx(ref, rel=1e-3)
    finally:
        ob.close()
