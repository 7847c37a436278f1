"""Global termination as one agent sees it (section 4.5): the condition is the pure
:func:`agent.protocol.completion.why_not_complete` over a :class:`~agent.protocol.completion.
CompletionView` built here from the agent's ledger and its peers' latest states (every
scenario agent seen once, everyone quiet and agreeing on their trades, no fence round due, no
working agent just gone, and with fencing on a strict majority of the team agreeing); it must
hold for ``complete_hold_periods`` state periods before it is reported.

Before it is reported the agent must also have heard the team's final word since the
condition began to hold (:mod:`agent.runtime.fencing.final_word`: the fence record the router
keeps),
so that a drone back after its team left never reports complete with landmarks the team
adopted.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Mapping
from typing import Protocol

from agent.protocol.completion import MINORITY, CompletionView, PeerView, why_not_complete
from agent.runtime.core.shared import Shared
from agent.wire.peer import AgentState


class PeersSeen(Protocol):
    """What completion reads of the agent's view of its peers
    (:class:`agent.runtime.ends.membership.Membership` provides it)."""

    @property
    def states(self) -> Mapping[str, tuple[AgentState, float]]:
        """Each peer's latest state and the mission time it arrived [s]."""
        ...

    @property
    def live(self) -> set[str]:
        """Peers whose liveliness token is present."""
        ...

    @property
    def ever_seen(self) -> set[str]:
        """Peers seen alive at least once."""
        ...

    @property
    def last_departure(self) -> float | None:
        """Mission time [s] a peer last left in the middle of its work (None: never)."""
        ...

_log = logging.getLogger(f"viscover.{__name__}")


class Completion:
    """The completion detector of one agent (see the module docstring); the core calls
    :meth:`check` every tick."""

    def __init__(self, shared: Shared) -> None:
        self.s = shared
        self.complete = False
        self.completed_at: float | None = None  #: mission time it was first reported [s]
        self.since: float | None = None  #: mission time the condition started to hold [s]
        self.announce = False  #: a MissionStatus is due
        #: why completion must wait for a fence round (None: it need not); see
        #: :meth:`agent.runtime.fencing.adoption.Adoption.waiting`
        self.waiting: Callable[[float], str | None] | None = None
        #: called when the condition has held: True if a next stage starts instead of the
        #: mission completing (:meth:`agent.runtime.moves.coverage.CoverageMoves.next_stage`)
        self.next_stage: Callable[[float], bool] | None = None
        #: why completion must wait for the team's final word (None: it need not); see
        #: :meth:`agent.runtime.fencing.final_word.FinalWord.waiting`
        self.final_word: Callable[[float], str | None] | None = None
        #: agents the team's final word heard complete, when this agent takes that record
        #: (:meth:`agent.runtime.fencing.final_word.FinalWord.heard_complete`)
        self.heard_complete: Callable[[], set[str]] | None = None
        self._minority_said = False
        self._farewell_sent = False

    def exit_due(self, now: float) -> tuple[bool, bool]:
        """(True once completion has held for ``exit_linger_periods`` state periods, True
        the first time: then step a :class:`~agent.runtime.core.events.Farewell` so that a
        lossy link still delivers the final state)."""
        cfg, at = self.s.cfg, self.completed_at
        if not self.complete or at is None or \
                now - at < cfg.exit_linger_periods * cfg.state_period_s:
            return False, False
        first = not self._farewell_sent
        self._farewell_sent = True
        return True, first

    def restart(self) -> None:
        """Something happened that may need more trades: start the hold time again."""
        self.since = None

    def view(self, now: float, members: PeersSeen) -> CompletionView:
        """What completion depends on, as this agent knows it at mission time ``now`` [s]
       ."""
        s, cfg = self.s, self.s.cfg
        peers = {aid: PeerView(
            quiet=st.phase == "converged" and not st.partners and not st.pending,
            stage=st.stage, complete=st.complete,
            owns_nothing=not st.owned.ids and not st.held.ids, age_s=now - t,
            trades_with=st.trades_with) for aid, (st, t) in members.states.items()}
        gone = members.last_departure
        quiet = s.quiet()
        # The fence rounds' reason is asked only of a quiet agent: the condition's first step
        # is quiet, and with a fence in force the question unpacks every peer's ledger.
        wait = self.waiting(now) if quiet and self.waiting is not None else None
        return CompletionView(
            me=s.id, team=tuple(s.order), quiet=quiet,
            quiet_detail=f"phase {s.phase}, partners {s.partners.pending}, pending "
                         f"{s.machine.pending_ids}",
            stage=s.stage, trades_with=dict(s.machine.trades_with),
            fenced=frozenset(s.machine.fenced),
            first_life=cfg.require_all and s.machine.incarnation <= 1,
            ever_seen=frozenset(members.ever_seen), live=frozenset(members.live), peers=peers,
            fresh_s=cfg.fresh_periods * cfg.state_period_s,
            departure_age_s=None if gone is None else now - gone,
            departure_grace_s=cfg.departure_grace_periods * cfg.state_period_s,
            adoption_wait=wait,
            majority_rule=s.sc.lost_after > 0,
            heard_complete=frozenset(self.heard_complete() if self.heard_complete else ()))

    def _all_agree(self, now: float, members: PeersSeen) -> bool:
        why = why_not_complete(self.view(now, members))
        if why is None or not why.endswith(MINORITY):
            self._minority_said = False
            return why is None
        if not self._minority_said:  # said once: the rest of the condition holds
            self._minority_said = True
            _log.warning("agent %s: the mission looks complete here, but %s", self.s.id, why)
        return False

    def check(self, now: float, members: PeersSeen) -> None:
        """Update :attr:`complete` at mission time ``now`` [s] ."""
        if not self._all_agree(now, members):
            self.since = None
            if self.complete:
                self.complete = False
                self.s.publish_soon()
            return
        if self.since is None:
            self.since = now
        hold = self.s.cfg.complete_hold_periods * self.s.cfg.state_period_s
        if not self.complete and self.final_word is not None and self.final_word(now):
            return  # the condition holds: wait for the fence record (asked meanwhile)
        if not self.complete and now - self.since >= hold:
            if self.next_stage is not None and self.next_stage(now):
                self.since = None
                return
            self.complete = True
            self.completed_at = now
            self.s.publish_soon()
            self.announce = True

    def blocker(self, now: float, members: PeersSeen) -> str:
        """Why the mission is not complete in this agent's view (diagnostics): the first
        reason of the condition, else the team's final word awaited, else (the hold period
        running) every live peer's last state."""
        s = self.s
        why = why_not_complete(self.view(now, members))
        if why is None and self.since is not None and self.final_word is not None:
            why = self.final_word(now)
        if why is not None:
            return why
        out = []
        for aid in sorted(members.live):
            entry = members.states.get(aid)
            if entry is None:
                out.append(f"{aid}: no state")
                continue
            st, t = entry
            out.append(f"{aid}: age {now - t:.1f} s, phase {st.phase}, partners "
                       f"{st.partners}, pending {st.pending}, trades {st.trades_with}")
        return f"live {sorted(members.live)}; my trades {s.machine.trades_with}; " + \
            "; ".join(out)
