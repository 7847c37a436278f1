"""Global termination as one agent sees it (section 4.5): the mission is complete when every
agent has converged with an empty partner list and nothing pending, and every pair agrees on
how many trades it made together; it must hold for ``complete_hold_periods`` state periods
before it is reported.

Every scenario agent must have been seen once (nobody completes before the others start; a
restarted agent, which saw the start, and a joiner are not held to it);
afterwards only live agents count (a departed agent cannot trade), but the departure of an
agent that was not quiet holds completion back for a grace period, so that a restarting agent
(crash, journal recovery) can rejoin first.

With fencing on (``lost_after`` > 0), the agents that agree must be a strict majority of the
scenario's team (the quorum rule of :func:`agent.protocol.fencing.has_quorum`): itself, the
live peers checked, and the peers whose last state (not fenced, trades agreeing with ours)
reported the mission complete or held nothing with nothing pending; after a restart, also
those the router's record heard complete. A drone cut off with a minority cannot tell a
partition from a team that left: if it completed and left, the majority would fence it and
its landmarks would hang on the adoption succeeding; it waits instead, and hears the fence or
the team when the partition heals.

Before it is reported the agent must also have heard the team's final word since the
condition began to hold (:mod:`agent.runtime.final_word`: the fence record the router keeps),
so that a drone back after its team left never reports complete with landmarks the team
adopted.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from typing import TYPE_CHECKING

from agent.runtime.shared import Shared

if TYPE_CHECKING:
    from agent.runtime.membership import Membership

_log = logging.getLogger(f"viscover.{__name__}")


class Completion:
    """The completion detector of one agent (see the module docstring); call :meth:`check`
    under the shared lock every tick."""

    def __init__(self, shared: Shared) -> None:
        self.s = shared
        self.complete = False
        self.completed_at: float | None = None  #: mission time it was first reported [s]
        self.since: float | None = None  #: mission time the condition started to hold [s]
        self.announce = False  #: a MissionStatus is due
        #: why completion must wait for a fence round (None: it need not); see
        #: :meth:`agent.runtime.adoption.Adoption.waiting`
        self.waiting: Callable[[float], str | None] | None = None
        #: called when the condition has held: True if a next stage starts instead of the
        #: mission completing (:meth:`agent.runtime.moves.CoverageMoves.next_stage`)
        self.next_stage: Callable[[float], bool] | None = None
        #: why completion must wait for the team's final word (None: it need not); see
        #: :meth:`agent.runtime.final_word.FinalWord.waiting`
        self.final_word: Callable[[float], str | None] | None = None
        #: agents the team's final word heard complete, when this agent takes that record
        #: (:meth:`agent.runtime.final_word.FinalWord.heard_complete`)
        self.heard_complete: Callable[[], set[str]] | None = None
        self._minority_said = False

    def restart(self) -> None:
        """Something happened that may need more trades: start the hold time again."""
        self.since = None

    def _all_agree(self, now: float, members: Membership) -> bool:
        s, cfg = self.s, self.s.cfg
        if not s.quiet():
            return False
        fenced = s.machine.fenced
        # Everyone must have started (once): not asked of a restart, which saw the start.
        if cfg.require_all and s.machine.incarnation <= 1 and \
                not (set(s.order) - {s.id} - fenced <= members.ever_seen):
            return False
        if self.waiting is not None and self.waiting(now) is not None:
            return False
        if members.last_departure is not None and \
                now - members.last_departure < cfg.departure_grace_periods * cfg.state_period_s:
            return False
        # Agents to check: the live ones, plus any whose state is fresh (a missed liveliness
        # join must not let us overlook an agent that is still working).
        fresh = cfg.fresh_periods * cfg.state_period_s
        check = members.live | {a for a, (_st, t) in members.states.items() if now - t <= fresh}
        check.discard(s.id)
        check -= fenced
        for aid in check:
            entry = members.states.get(aid)
            if entry is None or now - entry[1] > fresh:
                return False
            st = entry[0]
            if not (st.phase == "converged" and not st.partners and not st.pending):
                return False
            if st.stage < s.stage:  # still in the thesis stage while we make moves
                return False
            if st.trades_with.get(s.id, 0) != s.machine.trades_with.get(aid, 0):
                return False
        live = sorted(check)
        for i, a in enumerate(live):
            sa = members.states[a][0]
            for b in live[i + 1:]:
                if sa.trades_with.get(b, 0) != members.states[b][0].trades_with.get(a, 0):
                    return False
        if s.sc.lost_after <= 0 or self.majority_agrees(check, members):
            self._minority_said = False
            return True
        if not self._minority_said:
            self._minority_said = True
            agree = sorted(self.agreeing(check, members))
            _log.warning("agent %s: the mission looks complete here, but only %d of %d agents "
                         "agree (%s): waiting for a strict majority (cut off from the team?)",
                         s.id, len(agree), len(s.order), ", ".join(agree))
        return False

    def agreeing(self, check: set[str], members: Membership) -> set[str]:
        """The scenario agents that agree the mission is complete in this agent's view (module
        docstring): itself, ``check`` (the live peers, checked), and the peers whose last
        state said complete or held nothing, quiet, with trades agreeing (under the lock)."""
        s = self.s
        agree = {s.id, *check}
        for aid, (st, _t) in members.states.items():
            if aid in s.machine.fenced or aid in agree:
                continue
            if st.trades_with.get(s.id, 0) != s.machine.trades_with.get(aid, 0):
                continue
            empty = not st.owned.ids and not st.held.ids and not st.pending
            if st.complete or (empty and st.phase == "converged" and not st.partners):
                agree.add(aid)
        if self.heard_complete is not None:
            agree |= self.heard_complete() - s.machine.fenced
        return agree & set(s.order)

    def majority_agrees(self, check: set[str], members: Membership) -> bool:
        """Whether :meth:`agreeing` is a strict majority of the scenario's team."""
        return 2 * len(self.agreeing(check, members)) > len(self.s.order)

    def check(self, now: float, members: Membership) -> None:
        """Update :attr:`complete` at mission time ``now`` [s] (call under the lock)."""
        if not self._all_agree(now, members):
            self.since = None
            if self.complete:
                self.complete = False
                self.s.dirty = True
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
            self.s.dirty = True
            self.announce = True

    def blocker(self, now: float, members: Membership) -> str:
        """Why the mission is not complete in this agent's view (diagnostics)."""
        s = self.s
        with s.lock:
            if not s.quiet():
                return (f"self not quiet: phase {s.phase}, partners {s.partners.pending}, "
                        f"pending {s.machine.pending_ids}")
            missing = set(s.order) - {s.id} - members.ever_seen - s.machine.fenced
            if missing and s.cfg.require_all and s.machine.incarnation <= 1:
                return f"never seen {sorted(missing)}"
            why = self.waiting(now) if self.waiting is not None else None
            if why is None and self.since is not None and self.final_word is not None:
                why = self.final_word(now)
            if why is not None:
                return why
            fresh = s.cfg.fresh_periods * s.cfg.state_period_s
            check = (members.live | {a for a, (_st, t) in members.states.items()
                                     if now - t <= fresh}) - {s.id} - s.machine.fenced
            if s.sc.lost_after > 0 and not self.majority_agrees(check, members):
                agree = sorted(self.agreeing(check, members))
                return (f"{len(agree)} of {len(s.order)} agents agree ({', '.join(agree)}): "
                        "completing needs a strict majority (a partition's minority "
                        "waits for the team)")
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
