"""``strategy = "potential"`` with real agent processes on a real Zenoh router, 30 % loss of
every message, complete, with every landmark owned once: the L-shaped building from the start
where the thesis leaves a face unseen (score 8.72), where the agents' pair re-splits end where
the simulator's strategy does (14.30); and a pier whose best partition needs a whole-team
re-split (four drones), carried out leg by leg over Zenoh queries."""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np
import pytest

from agent.config.parse import load_scenario
from agent.core.vision import per_landmark
from agent.mission.observer import print_report
from bench.quality.runs import run_strategy, run_thesis
from bench.quality.structures import Scene, make_scene
from tests.agent_helpers import scenario_toml
from tests.test_agent_processes import InTestObserver, RouterBox, router_box, spawn_agent, wait_all

pytestmark = [pytest.mark.slow, pytest.mark.serial]
__all__ = ["router_box"]


def run_processes(router_box: RouterBox, tmp_path: Path, scene: Scene, same_partition: bool
                  ) -> float:
    """Run one agent process per drone of ``scene`` at 30 % loss; the observer's final
    coverage score (eq. 3.10) after checking completion and ownership, that it reports the
    score the thesis stage ended with and the moves ended above it (no revert), and (with
    ``same_partition``) that the landmarks the simulator's owners see are split into the
    same blocks here (one nobody sees scores 0 with any owner)."""
    path = tmp_path / "scene.toml"
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
        assert sorted(rep.owners) == sorted(sc.landmark_ids), outs
        # The asynchronous thesis stage may end elsewhere than the simulator's (under loss
        # the trades come in another order); the moves never end below it.
        assert rep.thesis_stage_coverage is not None and not rep.reverted
        assert rep.coverage >= rep.thesis_stage_coverage - 1e-6
        text = io.StringIO()
        print_report(rep, text)
        assert (f"coverage when the thesis stage ended {rep.thesis_stage_coverage:.4g}; with "
                f"the coverage moves {rep.coverage:.4g}") in text.getvalue()
        if not same_partition:
            return float(rep.coverage)
        ref = run_strategy(scene)
        ids = [a.id for a in sc.agents]
        seen = np.zeros(len(sc.landmark_ids), dtype=bool)
        for i in range(len(ids)):  # a loop over the drones
            mine = ref.owner == i
            seen[mine] = per_landmark(ref.P[i], ref.V[i], sc.q[mine], sc.u[mine],
                                      sc.d_opt) > 0.0
        assert seen.sum() >= 20
        got = np.array([rep.owners[lid] for lid in sc.landmark_ids])  # the observer's dict
        want = np.array(ids)[ref.owner]
        lids = np.asarray(sc.landmark_ids)
        # The same partition: the same blocks of landmarks. Which drone holds a block may
        # differ (asynchronous moves under loss can swap two drones' roles, same score).
        assert {frozenset(lids[seen & (got == a)].tolist()) for a in ids} == \
            {frozenset(lids[seen & (want == a)].tolist()) for a in ids}, (got, want)
        return float(rep.coverage)
    finally:
        ob.close()


@pytest.mark.long  # make test: the processes' moves in the whole-team test below, the pair
# moves' partition in memory at 30 % loss in
# test_potential_agents.py::test_agents_reach_the_simulators_partition_where_pair_moves_suffice
def test_agent_processes_make_the_coverage_moves_under_loss(router_box: RouterBox,
                                                            tmp_path: Path) -> None:
    scene = make_scene("lshape", "tuning", 1, 3, 1)
    coverage = run_processes(router_box, tmp_path, scene, same_partition=True)
    thesis, ref = run_thesis(scene).score, run_strategy(scene).score
    assert coverage > thesis + 1.0, (coverage, thesis)
    assert coverage == pytest.approx(ref, rel=1e-3)


# make test-long: make test checks the same whole-team re-split with the agents' own code in
# test_potential_agents.py::test_agents_make_the_whole_team_resplit_the_simulator_needs[0.3],
# and potential's process seam (re-split legs over Zenoh at 30 % loss) in the L-building test above
@pytest.mark.long
def test_agent_processes_make_a_whole_team_resplit_under_loss(router_box: RouterBox,
                                                              tmp_path: Path) -> None:
    """Pier, 4 drones, held-out start 3: without the team move the simulator ends at 13.49,
    with it at 14.25; the processes reach the latter. The pier is round: its best partitions
    are rotations of one another, so the score is compared, not the blocks (one run in 8
    ended at a partition rotated by one column of landmarks)."""
    scene = make_scene("pier", "heldout", 0, 4, 3)
    coverage = run_processes(router_box, tmp_path, scene, same_partition=False)
    without, ref = run_strategy(scene, team_moves=0).score, run_strategy(scene).score
    assert coverage > without + 0.5, (coverage, without)
    assert coverage == pytest.approx(ref, rel=1e-3)
