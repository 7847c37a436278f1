"""Global termination as one agent sees it (section 4.5), as a pure function of what it knows:
:func:`why_not_complete` gives the first reason the mission is not complete in that view, or
None when it is. No clock, no lock: the runtime (:mod:`agent.runtime.ends.completion`) builds a
:class:`CompletionView` from its ledger and its peers' latest states, and holds the verdict
for ``complete_hold_periods`` before it reports it.

The mission is complete when, in this agent's view:

1. it is quiet itself (converged, nobody left to try, nothing pending);
2. every scenario agent was seen once (asked only of a first life: a restarted agent or a
   joiner saw the start);
3. no fence round is due (the adoption's own reason, passed in);
4. no agent that was working left within the departure grace (a restart may bring it back);
5. every peer to check (the live ones and any whose state is fresh, not fenced) has a fresh
   state, converged with an empty partner list and nothing pending, in this agent's stage or
   later, and agrees with this agent on how many trades they made together;
6. every pair of those peers agrees on its trade count;
7. with fencing on, the agents that agree are a strict majority of the scenario's team (the
   quorum of :func:`agent.protocol.fencing.has_quorum`): this agent, the peers checked, the
   peers whose last state (trades agreeing) said complete or held nothing while quiet, and
   those the router's record heard complete (a restarted agent only). A drone cut off with a
   minority cannot tell a partition from a team that left; completing, it would leave with
   landmarks the majority then fences and must adopt.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

#: The reason of step 7, as :func:`why_not_complete` words it (the runtime logs it once).
MINORITY = "completing needs a strict majority (a partition's minority waits for the team)"


@dataclass(frozen=True)
class PeerView:
    """A peer's latest state as this agent holds it."""

    quiet: bool  #: converged, empty partner list, nothing pending
    stage: int
    complete: bool
    owns_nothing: bool  #: neither owned nor held landmarks
    age_s: float  #: how old the state is [s, mission time]
    trades_with: Mapping[str, int] = field(default_factory=dict)


@dataclass(frozen=True)
class CompletionView:
    """What one agent knows that completion depends on (see the module docstring)."""

    me: str
    team: tuple[str, ...]  #: the scenario's agents, in order
    quiet: bool
    quiet_detail: str  #: why it is not quiet (phase, partners, pending), for the reason
    stage: int
    trades_with: Mapping[str, int]  #: this agent's trade count per peer
    fenced: frozenset[str]
    first_life: bool  #: every scenario agent must have been seen (require_all, incarnation 1)
    ever_seen: frozenset[str]
    live: frozenset[str]
    peers: Mapping[str, PeerView]
    fresh_s: float  #: a state older than this is stale [s]
    departure_age_s: float | None  #: since a working peer left [s] (None: none did)
    departure_grace_s: float
    adoption_wait: str | None = None  #: the fence rounds' reason to wait (None: none)
    majority_rule: bool = True  #: fencing is on (``lost_after`` > 0)
    heard_complete: frozenset[str] = frozenset()  #: the router's record, if taken


def peers_to_check(v: CompletionView) -> set[str]:
    """Step 5's peers: the live ones and any whose state is fresh, not fenced, not itself (a
    missed liveliness join must not let us overlook an agent that is still working)."""
    fresh = {a for a, p in v.peers.items() if p.age_s <= v.fresh_s}
    return (set(v.live) | fresh) - {v.me} - v.fenced


def agreeing(v: CompletionView, check: set[str]) -> set[str]:
    """Step 7's agents: itself, ``check``, the peers whose last state (not fenced, trades
    agreeing with ours) said complete or held nothing while quiet, those the router's record
    heard complete; scenario agents only."""
    agree = {v.me, *check}
    for aid, p in v.peers.items():
        if aid in v.fenced or aid in agree:
            continue
        if p.trades_with.get(v.me, 0) != v.trades_with.get(aid, 0):
            continue
        if p.complete or (p.owns_nothing and p.quiet):
            agree.add(aid)
    agree |= v.heard_complete - v.fenced
    return agree & set(v.team)


def why_not_complete(v: CompletionView) -> str | None:
    """The first reason the mission is not complete in view ``v`` (one line), or None when
    it is (section 4.5's condition, module docstring steps 1-7)."""
    if not v.quiet:
        return f"self not quiet: {v.quiet_detail}"
    missing = set(v.team) - {v.me} - v.fenced - v.ever_seen
    if v.first_life and missing:
        return f"never seen {sorted(missing)}"
    if v.adoption_wait is not None:
        return v.adoption_wait
    if v.departure_age_s is not None and v.departure_age_s < v.departure_grace_s:
        return f"a working agent left {v.departure_age_s:.1f} s ago: it may come back"
    check = peers_to_check(v)
    for aid in sorted(check):  # the team, not landmarks
        p = v.peers.get(aid)
        if p is None or p.age_s > v.fresh_s:
            return f"{aid}: no fresh state"
        if not p.quiet:
            return f"{aid}: not quiet"
        if p.stage < v.stage:
            return f"{aid}: in stage {p.stage}, this agent in {v.stage}"
        if p.trades_with.get(v.me, 0) != v.trades_with.get(aid, 0):
            return (f"{aid}: {p.trades_with.get(v.me, 0)} trades with {v.me}, "
                    f"{v.trades_with.get(aid, 0)} here")
    live = sorted(check)
    for i, a in enumerate(live):
        for b in live[i + 1:]:
            if v.peers[a].trades_with.get(b, 0) != v.peers[b].trades_with.get(a, 0):
                return f"{a} and {b} disagree on their trades"
    if v.majority_rule:
        agree = sorted(agreeing(v, check))
        if 2 * len(agree) <= len(v.team):
            return f"{len(agree)} of {len(v.team)} agents agree ({', '.join(agree)}): {MINORITY}"
    return None
