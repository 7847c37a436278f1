"""The benchmark's runs of both strategies on its scenes, in virtual time:

- ``thesis``: the lockstep simulator of chapter 5 (:func:`agent.sim.kinematic.simulate`, the
  thesis' own sequential ticks);
- ``potential``: the agents' own decision code (one
:class:`~agent.runtime.shell.runtime.AgentRuntime`
  per drone on the in-memory network: :mod:`agent.runtime.moves.coverage`,
  :mod:`agent.runtime.moves.revert`),
  which is also ``viscover simulate``'s; the scene's boxes are the scenario's ``keepout``.
"""

from __future__ import annotations

import dataclasses
import tempfile
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from agent.core.vision import coverage_score
from agent.net.faults import FaultConfig
from agent.runtime.shell.runtime import AgentConfig
from agent.sim.kinematic import simulate
from agent.strategy.potential import TEAM_MOVES, TRIPLES
from agent.strategy.registry import StrategyName
from agent.testing.memsim import MemoryMission
from bench.quality.structures import Scene

Array = NDArray[np.float64]

STRATEGY = "potential"  #: the coverage-move strategy's name in the benchmark's rows


@dataclass(frozen=True)
class RunResult:
    """Outcome of one run: final poses P, V (n, 3) [m; world ENU], owners, score (eq. 3.10),
    simulated time [s], counters."""

    P: Array
    V: Array
    owner: NDArray[np.intp]
    score: float
    t: float
    complete: bool
    trades: int
    pair_moves: int
    relocations: int


def run_thesis(scene: Scene) -> RunResult:
    """The thesis strategy (gradient ascent + Algorithm 7), lockstep, until complete or the
    scene's duration."""
    r = simulate(scene.scenario())
    P, V, owner = r.positions[-1], r.directions[-1], r.final_owner
    score = coverage_score(P, V, scene.structure.q, scene.structure.u, owner, scene.d_opt)
    return RunResult(P, V, owner, score, float(r.times[-1]), r.complete, len(r.trades), 0, 0)


def run_strategy(scene: Scene, strategy: StrategyName = "potential", drop: float = 0.0,
                 seed: int = 1, triples: bool = TRIPLES, team_moves: int = TEAM_MOVES
                 ) -> RunResult:
    """``strategy`` (default ``potential``) run by the agents' code, one agent per drone until
    complete or the scene's duration (``drop``: share of messages lost; ``triples``,
    ``team_moves``: the ablations of :class:`~agent.runtime.core.shared.AgentConfig`)."""
    sc = dataclasses.replace(scene.scenario(), strategy=strategy, lost_after=0.0)
    config = AgentConfig(mission="quality", seed=seed, triples=triples, team_moves=team_moves)
    with tempfile.TemporaryDirectory(prefix="viscover-quality-") as d:
        m = MemoryMission(sc, d, FaultConfig(drop_default=drop) if drop else None, seed=seed,
                          config=config)
        try:
            complete = m.run(sc.duration)
            P, V, owner = m.final_state()
            regroups = sum(rt.core.moves.regroups for rt in m.agents.values())
            relocations = sum(rt.core.planning.relocations for rt in m.agents.values())
            trades = sum(rt.core.machine.ok for rt in m.agents.values())
            t = m.net.now
        finally:
            m.close()
    score = float(coverage_score(P, V, sc.q, sc.u, owner, sc.d_opt))
    return RunResult(P, V, owner, score, t, complete, trades, regroups, relocations)
