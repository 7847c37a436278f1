"""The whole protocol on the in-process MemoryNetwork under seeded faults.

Every ledger change is checked against the ownership invariant on the (consistent, single
thread) ledgers of all agents; runs must terminate with every pending transfer resolved.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import pytest

from agent.config.scenario import Scenario
from agent.net.faults import FaultConfig
from agent.runtime.shell.runtime import AgentConfig, MotionFn
from agent.sim.kinematic import simulate
from agent.testing.memsim import MemoryMission
from tests.agent_helpers import fixed_motion, random_scene, thesis


class CoverageProbe:
    """Coverage at quiet points (nothing pending anywhere) must never decrease."""

    def __init__(self) -> None:
        self.last: float | None = None
        self.drops: list[tuple[float, float]] = []

    def __call__(self, m: MemoryMission) -> None:
        if any(rt.core.machine.pending_ids for rt in m.agents.values()):
            return
        cov = m.coverage()
        if self.last is not None and cov < self.last - 1e-9:
            self.drops.append((self.last, cov))
        self.last = cov


def run_mission(tmp_path: Path, sc: Scenario, faults: FaultConfig | None, seed: int,
                max_time: float = 300.0, motion: Callable[[str], MotionFn] | None = None
                ) -> MemoryMission:
    probe = CoverageProbe()
    m = MemoryMission(sc, tmp_path / f"s{seed}", faults, seed=seed, motion=motion,
                      check=probe, config=AgentConfig(mission="mem", seed=seed))
    cov0 = m.coverage()
    done = m.run(max_time)
    try:
        assert done, f"not complete after {m.net.now:.1f} s"
        assert m.violations == []
        assert m.final_violations() == []
        assert all(not rt.core.machine.pending_ids for rt in m.agents.values())
        assert probe.drops == []
        assert m.coverage() >= cov0 - 1e-9
        return m
    finally:
        m.close()


@pytest.mark.parametrize("name", ["hexagon_5_3", "cube_6_2", "two_agents_5_2"])
def test_loss_free_matches_kinematic_simulator(tmp_path: Path, name: str) -> None:
    sc = thesis(name)
    ref = simulate(sc)
    m = run_mission(tmp_path, sc, None, 0)
    ids = sc.landmark_ids
    ref_owner = {ids[j]: sc.agents[i].id for j, i in enumerate(ref.final_owner)}
    assert m.owner_of() == ref_owner
    assert m.coverage() == pytest.approx(float(ref.coverage[-1]), rel=1e-9)


@pytest.mark.parametrize("drop", [0.1, 0.3, 0.5])
@pytest.mark.parametrize("name", ["hexagon_5_3", "cube_6_2"])
@pytest.mark.parametrize("seed", [1])
def test_thesis_scenarios_under_loss(tmp_path: Path, name: str, drop: float, seed: int) -> None:
    sc = thesis(name)
    run_mission(tmp_path, sc, FaultConfig(drop_default=drop), seed)


FAULTS = {
    "dup": FaultConfig(duplicate=0.3),
    "delay_beyond_timeout": FaultConfig(drop_default=0.1, delay_s=0.05, jitter_s=0.3),
    "reorder": FaultConfig(jitter_s=0.25, duplicate=0.2),
    "everything": FaultConfig(drop_default=0.3, duplicate=0.2, jitter_s=0.25),
    "trade_only_50": FaultConfig(drop_out={"trade": 0.5, "trade.reply": 0.5}),
}


@pytest.mark.parametrize("fault", sorted(FAULTS))
@pytest.mark.parametrize("seed", range(2))
def test_random_scenes_fixed_poses(tmp_path: Path, fault: str, seed: int) -> None:
    """Six agents, fixed poses: many trades quickly, every fault kind."""
    sc = random_scene(6, 30, seed)
    run_mission(tmp_path, sc, FAULTS[fault], seed, motion=fixed_motion(seed))


def test_loss_costs_time_not_coverage_on_fixed_poses(tmp_path: Path) -> None:
    """With fixed poses every landmark ends with an agent that sees it best among all
    agents it was compared with; loss-free and 50 % loss reach the same coverage here."""
    sc = random_scene(4, 24, 7)
    a = run_mission(tmp_path / "a", sc, None, 7, motion=fixed_motion(7, max_ticks=0))
    b = run_mission(tmp_path / "b", sc, FaultConfig(drop_default=0.5), 7,
                    motion=fixed_motion(7, max_ticks=0))
    assert b.coverage() == pytest.approx(a.coverage(), rel=1e-9)


def test_partition_heals_and_pending_transfers_resolve(tmp_path: Path) -> None:
    """N0 cannot reach N2 (both ways) for 30 s: trades between them can get stuck in doubt
    (a blocked two-phase commit); once the partition heals everything resolves."""
    sc = random_scene(3, 12, 3)
    m = MemoryMission(sc, tmp_path, None, motion=fixed_motion(3), check=CoverageProbe())
    m.crash("N0")
    m.faults = FaultConfig(partition=["N2"])
    m.start("N0")
    m.faults = None
    m.run(30.0, until=lambda _m: False)
    assert m.violations == []
    m.transports["N0"].faults = None  # heal
    assert m.run(400.0)
    assert m.violations == [] and m.final_violations() == []
    m.close()


def test_exit_sends_the_final_state_again_once_completion_has_lingered(tmp_path: Path) -> None:
    """An exiting agent repeats its final (complete) state so that a lossy link delivers it."""
    from agent.runtime.shell.runtime import AgentRuntime
    from agent.wire import keys
    from agent.wire.peer import AgentState, Publication

    sc = thesis("hexagon_5_3")
    m = MemoryMission(sc, tmp_path, None, config=AgentConfig(mission="mem"))
    try:
        assert m.run(300.0)
        rt: AgentRuntime = m.agents["A"]
        assert rt.completed_at is not None
        linger = rt.cfg.exit_linger_periods * rt.cfg.state_period_s
        heard: list[Publication | None] = []
        probe = m.net.transport("probe", None)
        codec = rt.core.c_pub
        probe.subscribe(keys.state_key("mem", "A"), lambda _k, b: heard.append(codec.decode(b)))
        assert not rt.exit_due(rt.completed_at + 0.5 * linger)
        now = rt.completed_at + linger + 1e-6
        assert rt.exit_due(now)
        assert rt.exit_due(now)  # the burst goes out once
        m.net.advance(1.0)
        assert len(heard) == rt.cfg.final_repeats
        assert all(isinstance(s, AgentState) and s.complete for s in heard)
    finally:
        m.close()
