"""``strategy = "potential"`` run by agents (:mod:`agent.runtime.moves.coverage`,
:mod:`agent.runtime.moves.revert`, :mod:`agent.protocol.regroup`) on the in-process MemoryNetwork:
the re-split protocol rejects what was not made for the responder's set, a group re-split leg
by leg gives each member its new set, a revert pull moves only what it names; from the quality
benchmark's fixed starts the agents end at least as high as the thesis' agents, complete, with
every ledger change checked; they make the pair, triple and whole-team re-splits the simulator
needs and reach its score, under loss too; and a faulty move is undone by the revert."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import msgspec
import numpy as np
import pytest

from agent.config.scenario import Scenario
from agent.core.coverage_moves import Goal, GroupProposal, OwnState
from agent.core.vision import coverage_score, per_landmark
from agent.net.faults import FaultConfig
from agent.protocol.machine import TradeMachine
from agent.protocol.records import GenesisRec
from agent.protocol.regroup import (
    after_leg,
    leg_terms,
    nothing_moves,
    pull_decision,
    pull_terms,
    regroup_decision,
    regroup_terms,
)
from agent.runtime.shell.runtime import AgentConfig
from agent.strategy.registry import StrategyName
from agent.testing.memsim import MemoryMission
from agent.wire.peer import Commit, Offer, Regroup, Reply, pack_arrays
from bench.quality.runs import run_strategy
from bench.quality.structures import make_scene
from tests.agent_helpers import revert_of
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
    P, V, owner = m.final_state()
    return owner, float(coverage_score(P, V, sc.q, sc.u, owner, sc.d_opt))


def run(tmp_path: Path, sc: Scenario, strategy: StrategyName, drop: float
        ) -> tuple[np.ndarray, float]:
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


#: make test: lossless (where the agents' run is run_strategy's: the same code and seeds)
#: the L-shaped building only; at 30 % loss the L-shaped building (pair moves) and the
#: five-drone pier (every move kind, the hardest). The other cases check the same on other
#: structures: make test-long (tests/test_quality_strategy.py keeps every start lossless).
IN_MAKE_TEST = {("lshape", 0.0), ("lshape", 0.3), ("pier", 0.3)}
COVERAGE_CASES = [pytest.param(c, d, id=f"{'-'.join(map(str, c))}-{d}",
                               marks=[] if (c[0], d) in IN_MAKE_TEST else [pytest.mark.long])
                  for d in (0.0, 0.3) for c in STARTS]


@pytest.mark.parametrize(("case", "drop"), COVERAGE_CASES)
def test_agents_with_coverage_moves_end_at_least_as_high_as_the_thesis_agents(
        tmp_path: Path, case: tuple[str, str, int, int, int], drop: float) -> None:
    """From the quality benchmark's fixed starts the agents end at least as high as the
    thesis' agents; lossless they are ``viscover simulate``'s run (the same code, the same
    seeds: the same score); at 30 % loss no more than 0.1 % below it. Under loss the moves
    come in another order, and the same whole-team search from another intermediate state
    may end in another local optimum: measured over three fault seeds each, 0.9997-1.0319
    times the simulator's score (the five-drone pier ends 3.2 % above it in two of three)."""
    scene = make_scene(*case)
    sc = scene.scenario()
    _o, thesis = run(tmp_path, sc, "thesis", drop)
    _o, mine = run(tmp_path, sc, "potential", drop)
    assert mine >= thesis - 1e-9
    sim = run_strategy(scene).score
    if drop == 0.0:
        assert mine == pytest.approx(sim, rel=1e-12)
    assert mine >= sim * (1.0 - 1e-3)


@pytest.mark.parametrize("drop", [
    pytest.param(0.0, marks=pytest.mark.long),  # make test: [0.3], the same at 30 % loss
    0.3])
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


def test_a_three_member_resplit_carried_out_leg_by_leg_gives_each_its_new_set() -> None:
    """A {1,2}, B {3,4}, C {5,6} re-split to A {3}, B {1,5}, C {2,4,6}: A's legs (each a
    real two-phase trade through the machines) end with every member holding its new set,
    and after every leg each landmark has exactly one owner."""
    universe = np.arange(1, 7, dtype=I64)
    before = {"A": [1, 2], "B": [3, 4], "C": [5, 6]}
    after = {"A": [3], "B": [1, 5], "C": [2, 4, 6]}
    m = {}
    for aid, ids in before.items():
        m[aid] = TradeMachine(aid, universe)
        m[aid].apply(GenesisRec(agent=aid, owned=pack_arrays(np.array(ids, I64),
                                                             np.zeros(len(ids), I64))))
    g = Goal(np.zeros(3), np.array([1.0, 0.0, 0.0]), 1.0)
    known = {aid: m[aid].owned_arrays() for aid in ("B", "C")}
    legs = 0
    while True:
        terms = None
        for peer in ("B", "C"):
            terms = leg_terms(np.array(after[peer], I64), g, *m["A"].owned_arrays(),
                              *known[peer])
            if terms is not None:
                break
        if terms is None:
            break
        own = m["A"].owned_arrays()
        step = m["A"].new_offer(peer, (0.0, 0.0, 0.0), (1.0, 0.0, 0.0), regroup=terms)
        assert isinstance(step.message, Offer) and step.trade_id is not None
        reply = m[peer].on_offer(step.message, (0.0, 0.0, 1.0), (1.0, 0.0, 0.0), None,
                                 regroup_decision(terms)).message
        assert isinstance(reply, Reply)
        commit = m["A"].on_offer_reply(step.trade_id, reply)
        assert commit.outcome == "commit" and isinstance(commit.message, Commit)
        assert m[peer].on_commit(commit.message).outcome == "committed"
        known[peer] = after_leg(terms, *own, *known[peer])[2:]
        legs += 1
        owned = np.concatenate([m[a].owned_arrays()[0] for a in m])
        assert np.array_equal(np.sort(owned), universe)
    assert legs <= 4
    for aid, ids in after.items():
        assert m[aid].owned_arrays()[0].tolist() == ids


def moves_run(tmp_path: Path, scene_args: tuple[str, str, int, int, int], drop: float,
              triples: bool) -> tuple[float, float, float, dict[int, int]]:
    """The simulator's score with all moves and without team moves (and without triples
    unless ``triples``), the agents' score and the re-splits they started (by number of
    members)."""
    scene = make_scene(*scene_args)
    full = run_strategy(scene).score
    pairs = run_strategy(scene, triples=triples, team_moves=0).score
    s2 = dataclasses.replace(scene.scenario(), strategy="potential", lost_after=0.0)
    m = MemoryMission(s2, tmp_path / "agents", FaultConfig(drop_default=drop) if drop else None,
                      seed=1, config=AgentConfig(mission="mem", seed=1))
    try:
        assert m.run(s2.duration), f"not complete after {m.net.now:.0f} s"
        assert m.violations == [] and m.final_violations() == []
        assert_every_landmark_owned_once(m)
        started: dict[int, int] = {}
        for rt in m.agents.values():
            for k, c in rt.core.moves.started.items():
                started[k] = started.get(k, 0) + c
        return full, pairs, final(m, s2)[1], started
    finally:
        m.close()


@pytest.mark.parametrize("drop", [
    pytest.param(0.0, marks=pytest.mark.long),  # make test: [0.3], the same at 30 % loss
    0.3])
def test_agents_make_the_three_member_resplit_the_simulator_needs(
        tmp_path: Path, drop: float) -> None:
    """Box, 3 drones, held-out start 0: with pair moves only the simulator ends at 90 % of
    its full strategy; the agents start a 3-member re-split and reach the full strategy's
    score, at 0 and 30 % loss."""
    full, pairs, agents, started = moves_run(tmp_path, ("box", "heldout", 0, 3, 0), drop,
                                             triples=False)
    assert pairs < 0.95 * full
    assert started.get(3, 0) >= 1
    assert agents >= full * (1.0 - 1e-3)


@pytest.mark.parametrize("drop", [
    pytest.param(0.0, marks=pytest.mark.long),  # make test: [0.3], the same at 30 % loss
    0.3])
def test_agents_make_the_whole_team_resplit_the_simulator_needs(
        tmp_path: Path, drop: float) -> None:
    """Pier, 4 drones, held-out start 3: with pair and 3-member moves only the simulator ends
    at 95 % of its full strategy; the agents' leader starts a whole-team re-split and they
    reach the full strategy's score, at 0 and 30 % loss."""
    full, triples, agents, started = moves_run(tmp_path, ("pier", "heldout", 0, 4, 3), drop,
                                               triples=True)
    assert triples < 0.97 * full
    assert started.get(4, 0) >= 1
    assert agents >= full * (1.0 - 1e-3)


def test_a_revert_pull_is_given_only_whole_and_only_what_it_names() -> None:
    """A pull takes back named landmarks from whoever owns them all, whatever else the
    holder owns; one it does not own, or one that gives something back, moves nothing."""
    universe = np.arange(1, 7, dtype=I64)
    b = TradeMachine("B", universe)
    b.apply(GenesisRec(agent="B", owned=pack_arrays(np.array([3, 4, 5], I64),
                                                    np.zeros(3, I64))))
    p = (0.0, 0.0, 0.0)
    ids_a, ids_b = np.array([1, 2], I64), np.array([3, 4, 5], I64)
    stale_view = np.array([4, 5, 6], I64)  # the holder's set as once published: need not match
    terms = pull_terms(np.array([4, 5], I64), np.zeros(2, I64), stale_view, np.zeros(3, I64))
    m_ir, m_ri = pull_decision(terms)(p, p, ids_a, p, p, ids_b)
    assert not m_ir.any() and ids_b[m_ri].tolist() == [4, 5]
    offer = Offer(sender="A", trade_id="A:1:1", p=p, v=(1.0, 0.0, 0.0),
                  owned=pack_arrays(ids_a, np.zeros(2, I64)), regroup=terms)
    step = b.on_offer(offer, p, (1.0, 0.0, 0.0), None, pull_decision(terms))
    assert step.outcome == "prepared"
    not_all = pull_terms(np.array([5, 6], I64), np.zeros(2, I64), ids_b, np.zeros(3, I64))
    assert not pull_decision(not_all)(p, p, ids_a, p, p, ids_b)[1].any()
    greedy = msgspec.structs.replace(terms, give=pack_arrays(np.array([1], I64),
                                                             np.zeros(1, I64)))
    assert not any(x.any() for x in pull_decision(greedy)(p, p, ids_a, p, p, ids_b))


@pytest.mark.parametrize("drop", [
    pytest.param(0.0, marks=pytest.mark.long),  # make test: [0.3], the same at 30 % loss
    0.3])
def test_agents_revert_to_the_thesis_stage_when_the_moves_end_below_it(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, drop: float) -> None:
    """A faulty relocation (D0 flies to a pose looking away from everything, its predicted
    vision a lie) leaves the team below its thesis-stage score with no move left; entering
    the last stage the agents see it, all revert, and end at the thesis' score, at 0 and 30 %
    loss."""
    import agent.runtime.moves.planning as planning

    scene = make_scene("lshape", "tuning", 1, 3, 1)
    sc = dataclasses.replace(scene.scenario(), lost_after=0.0)
    lo, hi = sc.space.lo + 0.5, sc.space.hi - 0.5
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1])
                        for z in (lo[2], hi[2])])
    centre = sc.q.mean(axis=0)
    far = corners[np.argmax(np.linalg.norm(corners - centre, axis=1))]

    def bad_goal(own: OwnState, others: np.ndarray, env: object, d_opt: float) -> Goal | None:
        if own.id != "D0":
            return None
        away = (far - centre) / np.linalg.norm(far - centre)
        return Goal(far, away, own.vision + 10.0)  # nothing in view there: a lie

    monkeypatch.setattr(planning, "relocation_goal", bad_goal)
    _o, thesis = run(tmp_path, sc, "thesis", 0.0)
    s2 = dataclasses.replace(sc, strategy="potential")
    cfg = AgentConfig(mission="mem", seed=1, max_relocations=1, regroups_per_member=0,
                      triples=False)
    m = MemoryMission(s2, tmp_path / "revert", FaultConfig(drop_default=drop) if drop else None,
                      seed=1, config=cfg)
    low: list[float] = []

    def probe(mm: MemoryMission) -> bool:
        if mm.agents["D0"].core.planning.relocations and not revert_of(mm.agents["D0"]).reverting:
            low.append(mm.coverage())
        return mm.complete

    try:
        assert m.run(s2.duration, until=probe)
        assert m.violations == [] and m.final_violations() == []
        assert_every_landmark_owned_once(m)
        assert all(revert_of(rt).reverting for rt in m.agents.values())
        score = final(m, s2)[1]
    finally:
        m.close()
    assert low and min(low) < thesis - 1.0  # the fault cost coverage
    assert score == pytest.approx(thesis, rel=1e-3)


@pytest.mark.parametrize("drop", [
    pytest.param(0.0, marks=pytest.mark.long),  # make test: [0.3], the same at 30 % loss
    0.3])
def test_a_leader_killed_in_the_middle_of_a_team_resplit_restarts_and_the_mission_completes(
        tmp_path: Path, drop: float) -> None:
    """Pier, 4 drones, held-out start 3: D0 is killed after the first committed leg of its
    whole-team re-split and restarted from its journal 2 s later. Every landmark keeps one
    owner, the mission completes, the restarted D0 has its thesis-stage record back from the
    journal (StageRec), and nobody reverts (the moves gained)."""
    sc = dataclasses.replace(make_scene("pier", "heldout", 0, 4, 3).scenario(),
                             strategy="potential", lost_after=0.0)
    m = MemoryMission(sc, tmp_path / "crash", FaultConfig(drop_default=drop) if drop else None,
                      seed=1, config=AgentConfig(mission="mem", seed=1))
    try:
        def mid_team_move(mm: MemoryMission) -> bool:
            g = mm.agents["D0"].core.moves.group
            return g is not None and len(g.plan.members) == 4 and g.legs >= 1

        assert m.run(sc.duration, until=mid_team_move), "no whole-team re-split under way"
        recorded = revert_of(m.agents["D0"]).stage1_vision
        assert recorded > 0.0
        m.crash("D0")
        t_back = m.net.now + 2.0
        assert not m.run(t_back)
        m.start("D0")
        assert m.run(sc.duration + t_back), f"not complete after {m.net.now:.0f} s"
        assert m.violations == [] and m.final_violations() == []
        assert_every_landmark_owned_once(m)
        d0 = m.agents["D0"]
        assert d0.core.machine.incarnation == 2 and revert_of(d0).stage1_vision == recorded
        rec = revert_of(d0).record
        assert rec is not None and rec.vision == recorded
        assert not any(revert_of(rt).reverting for rt in m.agents.values())
    finally:
        m.close()


def test_a_transit_turns_a_camera_that_faces_exactly_away_from_its_goal(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A relocation goal at D0's own position looking exactly the other way (the cross
    product of the two directions is zero, so it names no axis): the transit still turns
    the camera round and arrives facing the goal's direction."""
    import agent.runtime.moves.planning as planning

    goals: list[Goal] = []

    def turn_round(own: OwnState, others: np.ndarray, env: object, d_opt: float
                   ) -> Goal | None:
        if own.id != "D0" or goals:
            return None
        goals.append(Goal(own.p.copy(), -own.v, own.vision + 1.0))
        return goals[0]

    monkeypatch.setattr(planning, "relocation_goal", turn_round)
    sc = dataclasses.replace(make_scene("lshape", "tuning", 1, 3, 1).scenario(),
                             strategy="potential", lost_after=0.0)
    cfg = AgentConfig(mission="mem", seed=1, max_relocations=1, regroups_per_member=0)
    m = MemoryMission(sc, tmp_path / "turn", None, seed=1, config=cfg)
    seen_goal: list[bool] = []

    def arrived(mm: MemoryMission) -> bool:
        if mm.agents["D0"].core.planning.goal is not None:
            seen_goal.append(True)
        return bool(seen_goal) and mm.agents["D0"].core.planning.goal is None

    try:
        assert m.run(sc.duration, until=arrived)
        v = np.asarray(m.agents["D0"].pose.current()[1])
    finally:
        m.close()
    assert float(v @ goals[0].v) > 1.0 - 1e-6
