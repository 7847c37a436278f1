"""The benchmark's drivers for both strategies on its scenes: the "potential" strategy is
:class:`agent.sim.strategy.StrategySim` (the same code as ``strategy = "potential"`` in a
scenario), whose candidate viewpoints avoid the scene's own boxes (the scenario's
``keepout``, which the agents get too); the thesis strategy is the kinematic simulator of
chapter 5."""

from __future__ import annotations

from typing import Any

import numpy as np

from agent.core.vision import coverage_score
from agent.sim.kinematic import simulate
from agent.sim.strategy import STRATEGY, RunResult
from agent.sim.strategy import StrategySim as _ScenarioSim
from bench.quality.structures import Scene

__all__ = ["STRATEGY", "RunResult", "StrategySim", "run_strategy", "run_thesis"]


class StrategySim(_ScenarioSim):
    """The strategy on a benchmark scene (its scenario, whose ``keepout`` is the structure's
    boxes: the agents get the same)."""

    def __init__(self, scene: Scene, **kwargs: Any) -> None:
        self.scene = scene
        super().__init__(scene.scenario(), **kwargs)


def run_strategy(scene: Scene, triples: bool = True, after_thesis: bool = True,
                 team_moves: int = 2) -> RunResult:
    """Run the coverage-move strategy on a scene until done or the scene's duration."""
    sim = StrategySim(scene, triples=triples, after_thesis=after_thesis, team_moves=team_moves)
    for _ in range(int(np.ceil(scene.duration / scene.params.dt))):
        sim.tick()
        if sim.done:
            break
    return sim.result()


def run_thesis(scene: Scene) -> RunResult:
    """Run the thesis strategy (gradient ascent + Algorithm 7) with the kinematic simulator."""
    r = simulate(scene.scenario())
    P, V, owner = r.positions[-1], r.directions[-1], r.final_owner
    score = coverage_score(P, V, scene.structure.q, scene.structure.u, owner, scene.d_opt)
    return RunResult(P, V, owner, score, float(r.times[-1]), r.complete, len(r.trades), 0, 0)
