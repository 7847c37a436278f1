"""Section 4.5's termination condition as a pure function (agent.protocol.completion), on its
own: no runtime, no clock, no router."""

from __future__ import annotations

import dataclasses
from typing import Any

from hypothesis import given
from hypothesis import strategies as st

from agent.protocol.completion import (
    MINORITY,
    CompletionView,
    PeerView,
    agreeing,
    why_not_complete,
)

TEAM = ("A", "B", "C", "D", "E")


def peer(**change: Any) -> PeerView:
    base = PeerView(quiet=True, stage=1, complete=False, owns_nothing=False, age_s=0.1,
                    trades_with={})
    return dataclasses.replace(base, **change)


def view(peers: dict[str, PeerView], live: set[str], **change: Any) -> CompletionView:
    base = CompletionView(
        me="A", team=TEAM, quiet=True, quiet_detail="", stage=1, trades_with={},
        fenced=frozenset(), first_life=True, ever_seen=frozenset(TEAM) - {"A"},
        live=frozenset(live), peers=peers, fresh_s=3.0, departure_age_s=None,
        departure_grace_s=2.0)
    return dataclasses.replace(base, **change)


def test_a_whole_quiet_team_in_agreement_is_complete() -> None:
    others = {a: peer() for a in TEAM[1:]}
    assert why_not_complete(view(others, set(TEAM[1:]))) is None


def test_each_step_of_the_condition_says_why() -> None:
    others = {a: peer() for a in TEAM[1:]}
    live = set(TEAM[1:])
    assert why_not_complete(view(others, live, quiet=False, quiet_detail="phase trading")) \
        == "self not quiet: phase trading"
    assert why_not_complete(view(others, live, ever_seen=frozenset({"B"}))) == \
        "never seen ['C', 'D', 'E']"
    assert why_not_complete(view(others, live, adoption_wait="2 orphaned landmarks")) == \
        "2 orphaned landmarks"
    assert why_not_complete(view(others, live, departure_age_s=1.0)) == \
        "a working agent left 1.0 s ago: it may come back"
    assert why_not_complete(view({**others, "C": peer(quiet=False)}, live)) == "C: not quiet"
    assert why_not_complete(view({**others, "C": peer(age_s=9.0)}, live)) == \
        "C: no fresh state"
    assert why_not_complete(view({**others, "C": peer(trades_with={"A": 1})}, live)) == \
        "C: 1 trades with A, 0 here"
    assert why_not_complete(view({**others, "B": peer(trades_with={"C": 2})}, live)) == \
        "B and C disagree on their trades"


def test_a_minority_waits_a_majority_completes() -> None:
    """Cut off with one peer (2 of 5): not complete; with the last state of a third that
    reported complete, or of one that holds nothing, it is; without fencing it always was."""
    alone = view({"B": peer()}, {"B"})
    assert why_not_complete(alone) == f"2 of 5 agents agree (A, B): {MINORITY}"
    assert why_not_complete(dataclasses.replace(alone, majority_rule=False)) is None
    gone_done = {"B": peer(), "C": peer(complete=True, age_s=60.0)}
    assert why_not_complete(view(gone_done, {"B"})) is None
    gone_empty = {"B": peer(), "C": peer(owns_nothing=True, age_s=60.0)}
    assert why_not_complete(view(gone_empty, {"B"})) is None
    # a complete peer that disagrees on our trades does not count; a fenced one neither
    assert agreeing(view({"B": peer(), "C": peer(complete=True, age_s=60.0,
                                                 trades_with={"A": 3})}, {"B"}),
                    {"B"}) == {"A", "B"}
    assert agreeing(view(gone_done, {"B"}, fenced=frozenset({"C"})), {"B"}) == {"A", "B"}


@given(st.sets(st.sampled_from(TEAM[1:])), st.sets(st.sampled_from(TEAM[1:])))
def test_a_complete_view_stays_complete_when_fencing_is_off(live: set[str],
                                                            done: set[str]) -> None:
    """Whatever peers are live or gone-complete: a view complete with the majority rule is
    complete without it, and one complete without it fails with the rule only for want of a
    majority."""
    peers = {a: peer(complete=a in done, age_s=0.1 if a in live else 60.0)
             for a in live | done}
    with_rule = why_not_complete(view(peers, live))
    without = why_not_complete(view(peers, live, majority_rule=False))
    if with_rule is None:
        assert without is None
    if without is None and with_rule is not None:
        assert with_rule.endswith(MINORITY)
        assert 2 * len({"A"} | live | done) <= len(TEAM)
