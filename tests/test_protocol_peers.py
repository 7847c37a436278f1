"""The peer book on its own (:mod:`agent.protocol.peers`): who is live, a token that never
speaks, a joiner before and after admission, departures while busy, the latest state among
rival streams; and a hypothesis property over random event sequences."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from agent.protocol.peers import Came, Gone, PeerBook, quiet_state
from agent.wire.peer import AgentState, Counters, pack

P = (1.0, 2.0, 3.0)
V = (1.0, 0.0, 0.0)
SILENT_S = 10.0
FRESH_S = 2.0


def book() -> PeerBook:
    starts = {a: np.array([float(i), 0.0, 0.0]) for i, a in enumerate("ABCD")}
    return PeerBook("A", starts, FRESH_S, SILENT_S)


def state(sender: str, seq: int, incarnation: int = 1, quiet: bool = True,
          p: tuple[float, float, float] = P) -> AgentState:
    return AgentState(sender=sender, incarnation=incarnation, seq=seq, t=0.0, p=p, v=V,
                      phase="converged" if quiet else "optimising", owned=pack({1: 0}),
                      held=pack({}), vision=2.5, counters=Counters(), partners=[],
                      pending=[], trades_with={})


def test_a_token_makes_a_peer_live_and_a_silent_token_is_gone_until_it_speaks() -> None:
    b = book()
    assert b.token_appeared("B", True, 0.0) == [Came("B")]
    assert b.live == {"B"} and b.ever_seen == {"B"}
    assert b.sweep(SILENT_S) == []  # exactly silent_s: still live
    assert b.sweep(SILENT_S + 0.5) == [Gone("B", busy=True, silent_s=SILENT_S + 0.5)]
    assert b.live == set() and b.tokens == {"B"}
    assert b.last_departure == SILENT_S + 0.5  # never published a state: busy
    assert b.pose("B", P, V, 12.0) == [Came("B", again=True)]
    assert b.live == {"B"} and np.allclose(b.others_pos["B"], P)
    assert b.pose("B", P, V, 12.1) == []  # live already: nothing new


def test_a_quiet_peer_leaving_is_no_departure_and_a_busy_one_is() -> None:
    b = book()
    for aid in "BC":
        b.token_appeared(aid, True, 0.0)
    assert b.state(state("B", 1, quiet=True), 1.0) == (True, [])
    assert b.state(state("C", 1, quiet=False), 1.0) == (True, [])
    assert b.token_vanished("B", 2.0) == [Gone("B", busy=False)]
    assert b.last_departure is None
    assert b.token_vanished("C", 3.0) == [Gone("C", busy=True)]
    assert b.last_departure == 3.0
    assert b.live == set() and b.tokens == set() and b.ever_seen == {"B", "C"}


def test_a_joiner_is_live_only_once_admitted() -> None:
    b = book()
    assert b.token_appeared("J", False, 0.0) == []
    assert b.live == set() and b.unknown_live == {"J"}
    assert b.admit("J", (5.0, 5.0, 5.0), 1.0) == [Came("J")]
    assert b.live == {"J"} and np.allclose(b.others_pos["J"], (5.0, 5.0, 5.0))
    assert b.admit("K", None, 1.0) == []  # admitted without a token: known, not live
    assert "K" not in b.live


def test_our_own_token_is_not_a_peer() -> None:
    b = book()
    assert b.token_appeared("A", True, 0.0) == [] and b.token_vanished("A", 1.0) == []
    assert b.live == set() and "A" not in b.others_pos


def test_an_older_or_rival_state_is_not_the_latest_but_shows_the_peer_speaks() -> None:
    b = book()
    b.token_appeared("B", True, 0.0)
    assert b.state(state("B", 5), 1.0)[0]
    assert not b.state(state("B", 4), 9.0)[0]  # older: not the latest...
    assert b.heard["B"] == 9.0  # ...but B speaks
    assert b.sweep(9.0 + SILENT_S) == []  # so it is not gone
    forged = state("B", 1, incarnation=10**9, p=(9.0, 9.0, 9.0))
    assert b.state(forged, 9.5)[0]  # a huge incarnation takes over at first...
    assert not b.state(state("B", 6), 9.6)[0]  # ...and the genuine stream must wait
    assert not b.state(state("B", 7), 9.5 + FRESH_S + 0.1)[0]  # quiet long enough: candidate
    assert b.state(state("B", 8), 9.5 + FRESH_S + 0.2)[0]  # spoke twice: it is back
    assert b.states["B"][0].seq == 8 and np.allclose(b.others_pos["B"], P)


def test_quiet_state_is_converged_with_nothing_to_try_or_pending() -> None:
    assert quiet_state(state("B", 1, quiet=True))
    assert not quiet_state(state("B", 1, quiet=False))


EVENTS = st.lists(st.tuples(st.sampled_from(["appear", "vanish", "pose", "state", "sweep"]),
                            st.sampled_from("BCD"), st.floats(0.0, 4.0)), max_size=60)


@settings(max_examples=200, deadline=None)
@given(EVENTS)
def test_live_peers_hold_a_token_and_spoke_within_silent_s(events: list[tuple[str, str, float]]
                                                           ) -> None:
    """Whatever the order of tokens, poses, states and sweeps: the live peers hold a token
    and were ever seen; after a sweep every live peer spoke within ``silent_s``; every event
    names a peer, Came only for a live one, Gone only for one no longer live."""
    b = book()
    now, seq = 0.0, 0
    for kind, aid, dt in events:
        now += dt
        seq += 1
        if kind == "appear":
            out = b.token_appeared(aid, True, now)
        elif kind == "vanish":
            out = b.token_vanished(aid, now)
        elif kind == "pose":
            out = b.pose(aid, P, V, now)
        elif kind == "state":
            out = b.state(state(aid, seq, quiet=seq % 2 == 0), now)[1]
        else:
            out = b.sweep(now)
            assert all(now - b.heard[x] <= SILENT_S for x in b.live)
        for ev in out:
            assert (ev.aid in b.live) == isinstance(ev, Came)
        assert b.live <= b.tokens and b.live <= b.ever_seen
        assert "A" not in b.live
