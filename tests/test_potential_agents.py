"""``strategy = "potential"`` run by agents (:mod:`agent.runtime.moves`,
:mod:`agent.protocol.regroup`) on the in-process MemoryNetwork: the re-split protocol rejects
what was not made for the responder's set; from the quality benchmark's fixed starts the
agents end at least as high as the thesis' agents, complete, with every ledger change checked;
where the simulator's strategy needs only pair moves and relocations the agents reach its
final partition and score, under loss too."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import msgspec
import numpy as np
import pytest

from agent.config.scenario import Scenario
from agent.core.coverage_moves import Goal, GroupProposal
from agent.core.vision import coverage_score, per_landmark
from agent.net.faults import FaultConfig
from agent.protocol.machine import TradeMachine
from agent.protocol.records import GenesisRec
from agent.protocol.regroup import nothing_moves, regroup_decision, regroup_terms
from agent.runtime.agent import AgentConfig
from agent.runtime.memsim import MemoryMission
from agent.wire.peer import Offer, Regroup, pack_arrays
from bench.quality.strategy_sim import run_strategy
from bench.quality.structures import make_scene
from tests.test_adoption_memory import assert_every_landmark_owned_once

I64 = np.int64


def proposal(a_after: list[int], b_after: list[int], b_before: list[int]) -> GroupProposal:
    g = Goal(np.array([1.0, 2.0, 3.0]), np.array([0.0, 1.0, 0.0]), 1.0)
    return GroupProposal(members=("A", "B"), goals=(g, g),
                         sets=(np.array(a_after, I64), np.array(b_after, I64)),
                         sets_before=(np.array([1, 2, 3], I64), np.array(b_before, I64)),
                         gain=0.5)


def test_a_resplit_moves_exactly_what_it_names_and_only_for_the_set_it_was_made_for() -> None:
    """A {1,2,3}, B {4,5}: A keeps 1 and takes 4, B gets 2, 3 and keeps 5."""
    a_ids, b_ids = np.array([1, 2, 3], I64), np.array([4, 5], I64)
    terms = regroup_terms(proposal([1, 4], [2, 3, 5], [4, 5]), a_ids, np.zeros(3, I64),
                          b_ids, np.array([7, 8], I64))
    p = (0.0, 0.0, 0.0)
    m_ir, m_ri = regroup_decision(terms)(p, p, a_ids, p, p, b_ids)
    assert a_ids[m_ir].tolist() == [2, 3] and b_ids[m_ri].tolist() == [4]
    # B's set changed since (it traded 5 away): nothing moves.
    m_ir, m_ri = regroup_decision(terms)(p, p, a_ids, p, p, np.array([4], I64))
    assert not m_ir.any() and not m_ri.any()
    # A no longer offers 3: nothing moves.
    m_ir, m_ri = regroup_decision(terms)(p, p, np.array([1, 2], I64), p, p, b_ids)
    assert not m_ir.any() and not m_ri.any()
    # A hostile goal (not finite, not unit): nothing moves.
    for bad in ((float("nan"), 0.0, 0.0), (0.0, 2.0, 0.0)):
        hostile = msgspec.structs.replace(terms, goal_v=bad)
        m_ir, m_ri = regroup_decision(hostile)(p, p, a_ids, p, p, b_ids)
        assert not m_ir.any() and not m_ri.any()
    assert not nothing_moves(p, p, a_ids, p, p, b_ids)[0].any()


def test_the_machine_prepares_a_resplit_with_the_named_sets() -> None:
    """Through :class:`TradeMachine`: B prepares the transfer the re-split names; a re-split
    made for another set gets NoTrade."""
    universe = np.arange(1, 6, dtype=I64)
    b = TradeMachine("B", universe)
    b.apply(GenesisRec(agent="B", owned=pack_arrays(np.array([4, 5], I64), np.zeros(2, I64))))
    terms = regroup_terms(proposal([1, 4], [2, 3, 5], [4, 5]), np.array([1, 2, 3], I64),
                          np.zeros(3, I64), np.array([4, 5], I64), np.zeros(2, I64))
    offer = Offer(sender="A", trade_id="A:1:1", p=(0.0, 0.0, 0.0), v=(1.0, 0.0, 0.0),
                  owned=pack_arrays(np.array([1, 2, 3], I64), np.zeros(3, I64)), regroup=terms)
    step = b.on_offer(offer, (0.0, 0.0, 1.0), (1.0, 0.0, 0.0), None, regroup_decision(terms))
    assert step.outcome == "prepared"
    stale = msgspec.structs.replace(terms, before=pack_arrays(np.array([4], I64), np.zeros(1, I64)))
    offer2 = Offer(sender="A", trade_id="A:1:2", p=(0.0, 0.0, 0.0), v=(1.0, 0.0, 0.0),
                   owned=offer.owned, regroup=stale)
    b2 = TradeMachine("B", universe)
    b2.apply(GenesisRec(agent="B", owned=pack_arrays(np.array([4, 5], I64), np.zeros(2, I64))))
    assert b2.on_offer(offer2, (0.0, 0.0, 1.0), (1.0, 0.0, 0.0), None,
                       regroup_decision(stale)).outcome == "no_trade"
    assert isinstance(terms, Regroup)


def final(m: MemoryMission, sc: Scenario) -> tuple[np.ndarray, float]:
    """Owner row of each landmark (scenario order) and the score of eq. 3.10 at the agents'
    final poses."""
    owner = np.full(len(sc.landmark_ids), -1, dtype=np.intp)
    for i, a in enumerate(sc.agents):  # a loop over the drones
        rt = m.agents[a.id]
        owner[rt.shared.geo.rows(rt.machine.owned_arrays()[0])] = i
    P = np.array([m.agents[a.id].pose.current()[0] for a in sc.agents])
    V = np.array([m.agents[a.id].pose.current()[1] for a in sc.agents])
    return owner, float(coverage_score(P, V, sc.q, sc.u, owner, sc.d_opt))


def run(tmp_path: Path, sc: Scenario, strategy: str, drop: float) -> tuple[np.ndarray, float]:
    s2 = dataclasses.replace(sc, strategy=strategy, lost_after=0.0)
    m = MemoryMission(s2, tmp_path / strategy, FaultConfig(drop_default=drop) if drop else None,
                      seed=1, config=AgentConfig(mission="mem", seed=1))
    try:
        assert m.run(s2.duration), f"{strategy}: not complete after {m.net.now:.0f} s"
        assert m.violations == [] and m.final_violations() == []
        assert_every_landmark_owned_once(m)
        return final(m, s2)
    finally:
        m.close()


#: Fixed starts of the quality benchmark: (kind, split, structure, team size, start).
STARTS = [("lshape", "tuning", 1, 3, 1), ("pier", "tuning", 0, 5, 4),
          ("box", "heldout", 1, 4, 9), ("bridge", "tuning", 0, 4, 2)]


@pytest.mark.parametrize("drop", [0.0, 0.3])
@pytest.mark.parametrize("case", STARTS, ids=["-".join(map(str, c)) for c in STARTS])
def test_agents_with_coverage_moves_end_at_least_as_high_as_the_thesis_agents(
        tmp_path: Path, case: tuple[str, str, int, int, int], drop: float) -> None:
    sc = make_scene(*case).scenario()
    _o, thesis = run(tmp_path, sc, "thesis", drop)
    _o, mine = run(tmp_path, sc, "potential", drop)
    assert mine >= thesis - 1e-9


@pytest.mark.parametrize("drop", [0.0, 0.3])
def test_agents_reach_the_simulators_partition_where_pair_moves_suffice(
        tmp_path: Path, drop: float) -> None:
    """L-shaped building, 3 drones, start 1: the thesis leaves a face unseen (score 8.72);
    the simulator's strategy gets 14.30 with two pair re-splits and relocations; the agents
    reach the same partition and score, at 0 and 30 % loss."""
    scene = make_scene("lshape", "tuning", 1, 3, 1)
    sc = scene.scenario()
    ref = run_strategy(scene)
    owner, score = run(tmp_path, sc, "potential", drop)
    assert score == pytest.approx(ref.score, rel=1e-6)
    # Every landmark its owner sees has the same owner (one nobody sees scores 0 anywhere).
    seen = np.zeros(len(sc.landmark_ids), dtype=bool)
    for i in range(len(sc.agents)):  # a loop over the drones
        mine = ref.owner == i
        seen[mine] = per_landmark(ref.P[i], ref.V[i], sc.q[mine], sc.u[mine], sc.d_opt) > 0.0
    assert seen.sum() >= 20 and np.array_equal(owner[seen], ref.owner[seen])
