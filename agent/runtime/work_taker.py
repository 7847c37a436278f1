"""An inspection drone's re-splits with its peers, the runtime side of the strategy's
(:mod:`agent.strategy.inspection`): the peers' published states as
:class:`~agent.strategy.inspection.PeerWork`, a re-split carried out as the coverage moves'
pair legs (:meth:`agent.runtime.moves.CoverageMoves.start_resplit`: the journaled two-phase
trade, which a peer accepts only for its current set, flying or not).

* **At the start** (a first life: incarnation 1, not a joiner), the simulator's initial
  re-splits: with each later scenario agent in team order, once its first state is heard (or
  given up after :data:`INITIAL_WAIT_S`), the strategy's :func:`~agent.strategy.inspection.
  split_pair` of both remaining sets; the drone holds its pose while the legs go, then flies
  its new tour (:meth:`WorkTaker.initial_split`). As in the simulator each pair is tried once,
  by the one earlier in team order; the pairs of different drones run at once here, where the
  simulator takes them one after the other.
* **With nothing of its own left** (the converged phase): the strategy's re-split with the
  peer whose remaining tour is longest, else the flight home (:meth:`WorkTaker.tick`).
"""

from __future__ import annotations

import logging

import numpy as np
from numpy.typing import NDArray

from agent.core.coverage_moves import Goal, GroupProposal
from agent.runtime.inspecting import TAKE_TRIES, Inspecting
from agent.runtime.membership import Membership
from agent.runtime.moves import CoverageMoves
from agent.runtime.shared import Shared
from agent.strategy.inspection import remaining, split_pair
from agent.wire.peer import unpack

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
        #: later scenario agents still to offer the initial re-split to, in team order
        self.initial_left = order[order.index(shared.id) + 1:] if first else []
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

    def initial_split(self, now: float) -> bool:
        """The next initial re-split, if its peer's state is in (tick thread): True if one
        started (the drone then holds its pose while the legs go)."""
        s, ins = self.s, self.ins
        if not self.initial_left:
            return False
        with s.lock:
            if self.moves.active:
                return False
            aid = self.initial_left[0]
            entry = self.members.states.get(aid)
            if self._since is None:
                self._since = now
            if entry is None:
                if now - self._since >= INITIAL_WAIT_S:
                    self.initial_left.pop(0)
                return False
            self.initial_left.pop(0)
            got = unpack(entry[0].owned)
            p_peer, v_peer = np.asarray(entry[0].p), np.asarray(entry[0].v)
            mine = s.machine.owned_arrays()[0]
        if got is None or aid in s.machine.fenced:
            return False
        theirs = got[0]
        own = np.zeros(ins.ids.size, dtype=np.bool_)
        own[s.geo.rows(mine)] = True
        other = np.zeros(ins.ids.size, dtype=np.bool_)
        other[s.geo.rows(theirs)] = True
        p, _, _ = ins.pose.current()
        split = split_pair(p, remaining(own, ins.cap, ins.table), p_peer,
                           remaining(other, ins.cap, ins.table), ins.table)
        if split is None:
            return False
        prop = self._proposal(aid, p_peer, v_peer, mine, theirs, split[0], split[1])
        with s.lock:
            started = self.moves.start_resplit(prop, now)
        if started:
            self.initial_splits += 1
            _log.info("agent %s: initial re-split with %s (tours %.1f / %.1f m)", s.id, aid,
                      *split[2])
        return started

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
