"""An inspection drone's re-splits with its peers, the runtime side of the strategy's
(:mod:`agent.strategy.inspection`): the peers' published states as
:class:`~agent.strategy.inspection.PeerWork`, a re-split carried out as the coverage moves'
pair legs (:meth:`agent.runtime.moves.CoverageMoves.start_resplit`: the journaled two-phase
trade, which a peer accepts only for its current set, flying or not).

* **At the start** (a first life: incarnation 1, not a joiner), the simulator's initial
  re-splits, in the simulator's order: every pair once, by the one earlier in team order,
  pairs taken one after the other as :func:`~agent.strategy.inspection.split_pair` of both
  remaining sets. A drone first captures what its camera sees from its start pose (as the
  simulator does), then holds its pose until it has heard every peer's state (their start
  captures ride in it) and every earlier scenario
  agent has made its initial re-splits (``initial_step`` 2 in its state) and the states it
  reads agree on the trades they made (``trades_with``), so each pair is judged on the sets
  the simulator's sequence gives it; then it offers its own to each later agent in team order,
  publishes ``initial_step`` 2 and flies its tour (:meth:`WorkTaker.initial_split`). An earlier
  agent, or a later agent's first state, not heard within :data:`INITIAL_WAIT_S` of the
  drone's start is given up (a team that lost a drone before the start still flies).
* **With nothing of its own left** (the converged phase): the strategy's re-split with the
  peer whose remaining tour is longest, else the flight home (:meth:`WorkTaker.tick`).
"""

from __future__ import annotations

import logging
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from agent.core.coverage_moves import Goal, GroupProposal
from agent.runtime.inspecting import TAKE_TRIES, Inspecting
from agent.runtime.membership import Membership
from agent.runtime.moves import CoverageMoves
from agent.runtime.shared import Shared
from agent.strategy.inspection import remaining, split_pair
from agent.wire.peer import AgentState, unpack

_log = logging.getLogger(f"viscover.{__name__}")

#: Mission seconds a drone waits for a later peer's first state before it gives up that
#: peer's initial re-split.
INITIAL_WAIT_S = 10.0

Mask = NDArray[np.bool_]
IntArray = NDArray[np.int64]


class WorkTaker:
    """Re-splits of one inspection drone with its peers (see the module docstring)."""

    def __init__(self, ins: Inspecting, shared: Shared, members: Membership,
                 moves: CoverageMoves) -> None:
        self.ins, self.s, self.members, self.moves = ins, shared, members, moves
        order = list(shared.order)
        first = shared.machine.incarnation <= 1 and shared.id in order
        me = order.index(shared.id) if first else 0
        #: the other scenario agents, whose start captures count before any initial re-split
        self.everyone = [a for a in order if a != shared.id]
        #: earlier scenario agents whose initial re-splits come first, in team order
        self.earlier = order[:me] if first else []
        #: later scenario agents still to offer the initial re-split to, in team order
        self.initial_left = order[me + 1:] if first else []
        #: published as ``initial_step``: 0 not captured from the start pose yet, 1 captured
        #: there, 2 our initial re-splits made (or none to make: a restart, a joiner)
        self.step: Literal[0, 1, 2] = 0 if first else 2
        self.initial_splits = 0  #: initial re-splits started
        self._since: float | None = None  #: mission time of the first initial try [s]

    def _proposal(self, peer: str, p_peer: NDArray[np.float64], v_peer: NDArray[np.float64],
                  mine: IntArray, theirs: IntArray, mine_rows: Mask,
                  theirs_rows: Mask) -> GroupProposal:
        """The re-split giving this drone the landmark rows ``mine_rows`` and ``peer`` (at
        p_peer [m; world ENU]) ``theirs_rows``, from the sets ``mine`` / ``theirs`` (ids)."""
        p, v, _ = self.ins.pose.current()
        ids = self.ins.ids
        take = np.intersect1d(theirs, ids[mine_rows])
        give = np.intersect1d(mine, ids[theirs_rows])
        return GroupProposal(
            members=(self.s.id, peer), goals=(Goal(p, v, 0.0), Goal(p_peer, v_peer, 0.0)),
            sets=(np.union1d(np.setdiff1d(mine, give), take),
                  np.union1d(np.setdiff1d(theirs, take), give)),
            sets_before=(mine, theirs), gain=0.0)

    def _agree(self, a: str, b: AgentState | None) -> bool:
        """Whether earlier agent ``a``'s last state and ``b``'s (None: ours) count the same
        trades between them (under the lock)."""
        entry = self.members.states.get(a)
        if entry is None:
            return False
        if b is None:
            return entry[0].trades_with.get(self.s.id, 0) == \
                self.s.machine.trades_with.get(a, 0)
        return entry[0].trades_with.get(b.sender, 0) == b.trades_with.get(a, 0)

    def _earlier_pending(self) -> list[str]:
        """Earlier agents whose initial re-splits are not yet seen made and agreed with ours
        (under the lock)."""
        fenced = self.s.machine.fenced
        return [a for a in self.earlier if a not in fenced and not (
            (e := self.members.states.get(a)) is not None and e[0].initial_step == 2
            and self._agree(a, None))]

    def initial_split(self, now: float) -> bool:
        """The initial re-splits (tick thread), in the simulator's order: True while this
        drone holds its pose for them (waiting for earlier agents, or a re-split started)."""
        s, ins = self.s, self.ins
        if self.step == 2:
            return False
        if self._since is None:  # what the camera sees from the start pose first, as the
            self._since = now  # simulator captures before its initial re-splits
            ins.capture()
            with s.lock:
                self.step, s.dirty = 1, True
        with s.lock:
            waited = now - self._since >= INITIAL_WAIT_S
            if self.moves.active or s.machine.pending_ids:
                return True
            if not waited and not all((e := self.members.states.get(a)) is not None
                                      and e[0].initial_step >= 1 for a in self.everyone):
                return True  # every peer's start captures first (they ride in its state)
            if pending := self._earlier_pending():
                if not waited:
                    return True
                _log.info("agent %s: initial re-splits without %s (not heard within %.0f s)",
                          s.id, ", ".join(pending), INITIAL_WAIT_S)
                self.earlier = [a for a in self.earlier if a not in pending]
            if not self.initial_left:
                self.step, s.dirty = 2, True
                return False
            aid = self.initial_left[0]
            entry = self.members.states.get(aid)
            if entry is None or not all(self._agree(a, entry[0]) for a in self.earlier):
                if waited:  # not heard (or not up to date) in time: give its pair up
                    self.initial_left.pop(0)
                return True
            self.initial_left.pop(0)
            got = unpack(entry[0].owned)
            p_peer, v_peer = np.asarray(entry[0].p), np.asarray(entry[0].v)
            mine = s.machine.owned_arrays()[0]
        if got is None or aid in s.machine.fenced:
            return True
        theirs = got[0]
        own = np.zeros(ins.ids.size, dtype=np.bool_)
        own[s.geo.rows(mine)] = True
        other = np.zeros(ins.ids.size, dtype=np.bool_)
        other[s.geo.rows(theirs)] = True
        p, _, _ = ins.pose.current()
        split = split_pair(p, remaining(own, ins.cap, ins.table), p_peer,
                           remaining(other, ins.cap, ins.table), ins.table)
        if split is None:
            return True
        prop = self._proposal(aid, p_peer, v_peer, mine, theirs, split[0], split[1])
        with s.lock:
            started = self.moves.start_resplit(prop, now)
        if started:
            self.initial_splits += 1
            _log.info("agent %s: initial re-split with %s (tours %.1f / %.1f m)", s.id, aid,
                      *split[2])
        return True

    def tick(self, now: float) -> None:
        """With nothing of its own left: try to take work once (bounded by the strategy's
        tries), else fly home."""
        s, ins = self.s, self.ins
        if ins.want_home or ins.take_tries >= TAKE_TRIES:  # no more offers: home (once)
            ins.want_home = True
            if not ins.at_home:
                with s.lock:
                    s.optimising, s.dirty = True, True
            return
        with s.lock:
            if self.moves.active:
                return
            peers = []
            for aid, (st, _t) in self.members.states.items():
                got = unpack(st.owned)
                if aid in self.members.live and aid not in s.machine.fenced and got is not None:
                    peers.append((aid, np.asarray(st.p), np.asarray(st.v), got[0]))
            mine = s.machine.owned_arrays()[0]
        work = [ins.peer_work(aid, p, s.geo.rows(ids)) for aid, p, _v, ids in peers]
        act = ins.take_work(work)
        started = False
        if act is not None:
            aid, p_peer, v_peer, theirs = next(x for x in peers if x[0] == act.peer)
            prop = self._proposal(aid, p_peer, v_peer, mine, theirs, act.mine, act.theirs)
            with s.lock:
                started = s.phase == "converged" and self.moves.start_resplit(prop, now)
            if started:
                _log.info("agent %s: taking %d landmarks of work from %s (tours %.1f / %.1f m)",
                          s.id, np.setdiff1d(prop.sets[0], mine).size, aid, *act.lengths)
        if not started and ins.want_home and not ins.at_home:
            with s.lock:  # nothing to take: fly home (the planner's tick runs again)
                s.optimising, s.dirty = True, True
