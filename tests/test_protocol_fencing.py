"""The pure side of fence rounds (:mod:`agent.protocol.fencing`): quorum, the round's
decision on contested landmarks and orphans, the voter's freeze, the ledger changes of the
fence records and the fences an abandoned round lifts, each against a hand-worked answer."""

from __future__ import annotations

import numpy as np

from agent.protocol.fence_proof import make_proof
from agent.protocol.fencing import (
    FenceVoter,
    adoption_versions,
    decide_round,
    has_quorum,
    orphan_ids,
)
from agent.protocol.machine import TradeMachine
from agent.protocol.records import (
    AdoptRec,
    CommitRec,
    FencedRec,
    FenceRec,
    GenesisRec,
    PreparedRec,
    UnfenceRec,
)
from agent.wire.peer import AdoptOrder, FenceProposal, FenceVote, Refused, pack

A = np.asarray


def test_quorum_is_a_strict_majority_of_the_whole_team() -> None:
    team = ["A", "B", "C", "D"]
    assert has_quorum(team, [], ["D"])  # 3 of 4
    assert not has_quorum(team, [], ["C", "D"])  # 2 of 4: the other half could do the same
    assert not has_quorum(team, ["D"], ["C"])  # fenced agents still count
    assert not has_quorum(["A", "B"], [], ["B"])  # two drones: never


def test_orphans_and_contested_landmarks() -> None:
    universe = A([1, 2, 3, 4, 5, 6])
    # V0 owns 1, 2 and holds 5 for a trade with the fenced agent; V1 owns 3 and 5 (the
    # fenced agent committed that trade and gave 5 on to V1); V1 also holds 6 for the fenced
    # agent, at version 2, and V0 contests 6 at version 4 (it came back to V0 later).
    d = decide_round(universe, [A([1, 2]), A([3, 5])],
                     [(A([5, 6]), A([0, 4])), (A([6]), A([2]))])
    assert d.drop[0].tolist() == [5]  # claimed by V1: V0 lets it go
    assert d.drop[1].tolist() == [6]  # V0 contests it at a higher version
    assert d.orphans.tolist() == [4]
    assert orphan_ids(universe, [A([1, 2, 3])]).tolist() == [4, 5, 6]


def test_adopted_versions_lie_above_the_known_ones() -> None:
    orphans = A([3, 7, 9])
    v = adoption_versions(orphans, [(A([1, 7]), A([5, 2])), (A([7, 9]), A([4, 0]))])
    assert v.tolist() == [1, 5, 1]


def machine(me: str, owned: dict[int, int]) -> TradeMachine:
    m = TradeMachine(me, list(range(10)))
    m.apply(GenesisRec(agent=me, owned=pack(owned)))
    return m


def test_a_vote_fences_freezes_and_reports_the_ledger() -> None:
    m = machine("B", {1: 0, 2: 0})
    # B is prepared for F's offer: it holds 2 for F (contested), F's 5 would come to it.
    m.apply(PreparedRec(trade_id="F:1:1", partner="F", i_to_r=pack({5: 0}), r_to_i=pack({2: 0})))
    voter = FenceVoter(m)
    prop = FenceProposal(sender="A", epoch=3, fenced=["F"])
    refused = voter.on_proposal(prop, {"F"}, (0, 0, 0), (1, 0, 0), 0.0, 5.0)
    assert isinstance(refused.message, Refused) and refused.message.reason == "alive"
    step = voter.on_proposal(prop, set(), (0, 0, 0), (1, 0, 0), 0.0, 5.0)
    vote = step.message
    assert isinstance(vote, FenceVote)
    assert m.frozen and m.fenced == {"F"}
    assert vote.ledger == pack({1: 0})
    assert vote.contested == pack({2: 0})
    assert m.doubts() == []  # no StatusQuery to a fenced agent
    # Another coordinator's round is refused while frozen; the freeze expires.
    other = voter.on_proposal(FenceProposal(sender="C", epoch=4, fenced=["F"]), set(),
                              (0, 0, 0), (1, 0, 0), 1.0, 5.0)
    assert isinstance(other.message, Refused) and other.message.reason == "frozen"
    voter.expire(5.0)
    assert not m.frozen


def test_a_lower_coordinator_takes_a_freeze_over_and_the_first_round_adopts_nothing() -> None:
    """Competing coordinators (chaos run 3: N0, N2 and N4 each froze N6 for their own round,
    all gave up, for a minute): a round of a lower coordinator id, or the same coordinator's
    newer one, takes the freeze over; a higher one is refused. The round taken over adopts
    nothing at this voter; the one that took it does."""
    m = machine("B", {1: 0})
    voter = FenceVoter(m)
    here = ((0.0, 0.0, 0.0), (1.0, 0.0, 0.0))
    assert voter.on_proposal(FenceProposal(sender="C", epoch=4, fenced=["F"]), set(), *here,
                             0.0, 5.0).outcome == "voted"
    higher = voter.on_proposal(FenceProposal(sender="D", epoch=5, fenced=["F"]), set(), *here,
                               0.5, 5.0)
    assert higher.outcome == "frozen"
    newer = voter.on_proposal(FenceProposal(sender="C", epoch=5, fenced=["F"]), set(), *here,
                              0.6, 5.0)
    assert newer.outcome == "voted" and voter.freeze is not None
    assert voter.freeze.rid == (5, "C")
    lower = voter.on_proposal(FenceProposal(sender="A", epoch=4, fenced=["F"]), set(), *here,
                              1.0, 5.0)
    assert lower.outcome == "voted" and voter.freeze is not None
    assert voter.freeze.rid == (4, "A") and voter.freeze.until == 6.0
    old = voter.on_adopt(AdoptOrder(sender="C", epoch=5, fenced=["F"], owned=pack({7: 1}),
                                    drop=pack({})), 1.5)
    assert old.outcome == "expired" and 7 not in m.owned and m.frozen
    won = voter.on_adopt(AdoptOrder(sender="A", epoch=4, fenced=["F"], owned=pack({8: 1}),
                                    drop=pack({})), 2.0)
    assert won.outcome == "adopted" and m.owned == {1: 0, 8: 1} and not m.frozen


def test_adoption_resolves_trades_with_the_fenced_agent() -> None:
    m = machine("B", {1: 0, 2: 0, 3: 0})
    m.apply(PreparedRec(trade_id="F:1:1", partner="F", i_to_r=pack({5: 0}), r_to_i=pack({2: 0})))
    m.apply(CommitRec(trade_id="B:1:1", partner="F", i_to_r=pack({3: 0}), r_to_i=pack({6: 1})))
    voter = FenceVoter(m)
    voter.on_proposal(FenceProposal(sender="A", epoch=1, fenced=["F"]), set(), (0, 0, 0),
                      (1, 0, 0), 0.0, 5.0)
    # The round: B keeps 2 (nobody else has it), lets 3 go (F gave it on), adopts 8.
    order = AdoptOrder(sender="A", epoch=1, fenced=["F"], owned=pack({8: 4}), drop=pack({3: 0}))
    step = voter.on_adopt(order, 1.0)
    assert step.outcome == "adopted" and isinstance(step.records[0], AdoptRec)
    assert m.owned == {1: 0, 2: 0, 6: 2, 8: 4}
    assert m.held == {} and m.pending_ids == [] and not m.frozen
    # A repeated order gets the same answer; a late one (freeze over) is refused.
    assert voter.on_adopt(order, 2.0).outcome == "repeat"
    late = voter.on_adopt(AdoptOrder(sender="A", epoch=2, fenced=["F"], owned=pack({9: 1}),
                                     drop=pack({})), 2.0)
    assert late.outcome == "expired" and 9 not in m.owned


def test_an_order_for_landmarks_we_hold_is_refused() -> None:
    m = machine("B", {1: 0})
    voter = FenceVoter(m)
    voter.on_proposal(FenceProposal(sender="A", epoch=1, fenced=["F"]), set(), (0, 0, 0),
                      (1, 0, 0), 0.0, 5.0)
    step = voter.on_adopt(AdoptOrder(sender="A", epoch=1, fenced=["F"], owned=pack({1: 3}),
                                     drop=pack({})), 0.5)
    assert step.outcome == "expired" and m.owned == {1: 0}


def test_a_fenced_agent_drops_its_ledger_once_and_replays_to_the_same_state() -> None:
    m = machine("F", {4: 0, 5: 1})
    voter = FenceVoter(m)
    step = voter.learn_fenced(2, "A")
    assert step.records == [FencedRec(epoch=2, by="A")]
    assert m.owned == {} and m.fenced_out is not None
    assert voter.learn_fenced(3, "B").records == []
    again = machine("F", {4: 0, 5: 1})
    again.apply(step.records[0])
    assert again.owned == {} and again.fenced_out == m.fenced_out


def test_an_abandoned_round_lifts_only_the_fences_only_it_made() -> None:
    """B votes in A's round 3 (fencing F and G) and in C's round 4 (fencing G and H); a
    proof of another round fences H, an adoption fences nobody else. Round 3 abandoned lifts
    F (fenced by round 3 alone) but not G (round 4 fences it too); round 4 abandoned lifts G
    but not H (proven). An abandoned round is voted in no more, a lift unfreezes a voter
    frozen for that round, and the journal replays to the same fences."""
    m = machine("B", {1: 0})
    voter = FenceVoter(m)
    here = ((0.0, 0.0, 0.0), (1.0, 0.0, 0.0))
    records = []
    step = voter.on_proposal(FenceProposal(sender="A", epoch=3, fenced=["F", "G"]), set(),
                             *here, 0.0, 5.0)
    records += step.records
    voter.release()  # A gave up (its release arrived)
    step = voter.on_proposal(FenceProposal(sender="C", epoch=4, fenced=["F", "G", "H"]), set(),
                             *here, 1.0, 5.0)
    assert step.records == [FenceRec(epoch=4, coordinator="C", fenced=["F", "G", "H"])]
    records += step.records
    proof = make_proof(2, "D", ["H"], {"B": b"", "D": b"", "E": b""})
    rec = FenceRec(epoch=2, coordinator="D", fenced=[], proof=proof)
    m.apply(rec)
    records.append(rec)
    assert m.fenced == {"F", "G", "H"} and m.permanent_fences() == {"H"}
    assert m.unproven_rounds() == {(3, "A"), (4, "C")}

    lift = voter.abandon((3, "A"))
    assert lift.records == [UnfenceRec(epoch=3, coordinator="A")] and lift.outcome == "unfenced"
    records += lift.records
    assert m.fenced == {"F", "G", "H"}  # round 4 still fences F and G
    assert voter.freeze is not None and voter.freeze.rid == (4, "C")  # frozen for round 4
    lift = voter.abandon((4, "C"))
    records += lift.records
    assert m.fenced == {"H"} and voter.freeze is None and not m.frozen
    assert m.unproven_rounds() == set()
    assert voter.abandon((4, "C")).records == []  # once
    again = voter.on_proposal(FenceProposal(sender="C", epoch=4, fenced=["G"]), set(), *here,
                              2.0, 5.0)
    assert again.outcome == "finished" and m.fenced == {"H"}

    replayed = machine("B", {1: 0})
    for r in records:
        replayed.apply(r)
    assert (replayed.fenced, replayed.vote_fences, replayed.abandoned) == \
        (m.fenced, m.vote_fences, m.abandoned)


def test_an_adoption_makes_a_voted_fence_permanent() -> None:
    """A round that adopted fenced for good: no abandonment of another round lifts it."""
    m = machine("B", {1: 0})
    voter = FenceVoter(m)
    here = ((0.0, 0.0, 0.0), (1.0, 0.0, 0.0))
    voter.on_proposal(FenceProposal(sender="A", epoch=3, fenced=["F"]), set(), *here, 0.0, 5.0)
    voter.release()
    voter.on_proposal(FenceProposal(sender="C", epoch=4, fenced=["F"]), set(), *here, 1.0, 5.0)
    assert voter.on_adopt(AdoptOrder(sender="C", epoch=4, fenced=["F"], owned=pack({7: 1}),
                                     drop=pack({})), 1.5).outcome == "adopted"
    assert m.permanent_fences() == {"F"}
    voter.abandon((3, "A"))
    assert m.fenced == {"F"}
