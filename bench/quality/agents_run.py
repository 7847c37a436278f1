"""The coverage-move strategy run by agents (:mod:`agent.runtime.moves`): every drone an
:class:`~agent.runtime.agent.AgentRuntime` on the in-process MemoryNetwork (virtual time,
the same trade protocol and journals as the processes), for the quality benchmark."""

from __future__ import annotations

import dataclasses
import tempfile

from agent.core.vision import coverage_score
from agent.net.faults import FaultConfig
from agent.runtime.agent import AgentConfig
from agent.sim.strategy import RunResult
from agent.testing.memsim import MemoryMission
from bench.quality.structures import Scene

AGENTS = "agents"  #: the strategy's name in the benchmark's rows


def run_agents(scene: Scene, drop: float = 0.0, seed: int = 1) -> RunResult:
    """Run ``strategy = "potential"`` with one agent per drone until complete or the scene's
    duration; final poses, owners and score (eq. 3.10)."""
    sc = dataclasses.replace(scene.scenario(), strategy="potential", lost_after=0.0)
    with tempfile.TemporaryDirectory(prefix="viscover-quality-") as d:
        m = MemoryMission(sc, d, FaultConfig(drop_default=drop) if drop else None, seed=seed,
                          config=AgentConfig(mission="quality", seed=seed))
        try:
            complete = m.run(sc.duration)
            P, V, owner = m.final_state()
            regroups = sum(rt.moves.regroups for rt in m.agents.values())
            relocations = sum(rt.planning.relocations for rt in m.agents.values())
            trades = sum(rt.machine.ok for rt in m.agents.values())
            t = m.net.now
        finally:
            m.close()
    score = coverage_score(P, V, sc.q, sc.u, owner, sc.d_opt)
    return RunResult(P, V, owner, float(score), t, complete, trades, regroups, relocations)
