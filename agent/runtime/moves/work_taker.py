"""An inspection drone's re-splits with its peers, the runtime side of the strategy's
(:mod:`agent.strategy.inspection`): the peers' published states as
:class:`~agent.strategy.inspection.PeerWork`, a re-split carried out as the coverage moves'
pair legs (:meth:`agent.runtime.moves.coverage.CoverageMoves.start_resplit`: the journaled two-phase
trade, which a peer accepts only for its current set, flying or not).

* **At the start** (a first life: incarnation 1, not a joiner), the simulator's initial
  re-splits: every drone computes the same target partition, the pure
  :func:`~agent.strategy.inspection.initial_resplits` of the mission's start (the scenario's
  start poses and sets, what each camera captures from its start pose), so no drone waits for
  another's decision. Each then carries out its part: with each later scenario agent in team
  order, once that peer's state is heard, one pair leg moving what the target gives each of
  them from the other (refused legs, a peer's set having changed meanwhile, are tried again
  from its next state, at most :data:`LEG_TRIES` times); it captures from its start pose
  first and flies its tour meanwhile, holding only while a leg is in flight; the tour is
  planned again as the legs change its set (:meth:`WorkTaker.initial_split`). A peer not
  heard within :data:`INITIAL_WAIT_S` of the start is given up (a team that lost a drone
  before the start still flies).
* **With nothing of its own left** (the converged phase): the strategy's re-split with the
  peer whose remaining tour is longest, else the flight home (:meth:`WorkTaker.tick`).
"""

from __future__ import annotations

import logging

import numpy as np
from numpy.typing import NDArray

from agent.core.coverage_moves import Goal, GroupProposal
from agent.runtime.core.shared import Shared
from agent.runtime.ends.membership import Membership
from agent.runtime.moves.coverage import CoverageMoves
from agent.runtime.moves.inspecting import TAKE_TRIES, Inspecting
from agent.strategy.inspection import initial_resplits
from agent.wire.peer import unpack
from agent.world.environment import initial_owner

_log = logging.getLogger(f"viscover.{__name__}")

#: Mission seconds a drone waits for a later peer's first state before it gives up that
#: peer's initial re-split.
INITIAL_WAIT_S = 10.0
#: Legs tried with one peer before its initial re-split is given up (each refused because the
#: peer's set changed meanwhile, or not answered).
LEG_TRIES = 5

Mask = NDArray[np.bool_]
IntArray = NDArray[np.int64]


class WorkTaker:
    """Re-splits of one inspection drone with its peers (see the module docstring)."""

    def __init__(self, ins: Inspecting, shared: Shared, members: Membership,
                 moves: CoverageMoves) -> None:
        self.ins, self.s, self.members, self.moves = ins, shared, members, moves
        order = list(shared.order)
        first = shared.machine.incarnation <= 1 and shared.id in order
        self.me = order.index(shared.id) if first else -1
        #: later scenario agents still to carry out the initial re-split with, in team order
        self.initial_left = order[self.me + 1:] if first else []
        self.done = not first  #: the initial re-splits are over for this drone
        self.initial_splits = 0  #: initial re-split legs started
        self.target: NDArray[np.intp] | None = None  #: the owner of each row after them
        self._since: float | None = None  #: mission time of the first initial try [s]
        self._leg: tuple[str, int] | None = None  #: (peer, committed legs before it)
        self._tries: dict[str, int] = {}  #: legs tried per peer
        #: mission time [s] the peer's state a leg was computed from arrived (a leg is tried
        #: again only from a newer state)
        self._used: dict[str, float] = {}
        self._settled = False  #: the team held its target sets once (see :meth:`settled`)

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

    def _target(self) -> NDArray[np.intp]:
        """The owner index of each landmark row after the team's initial re-splits, from the
        mission's start alone (the same for every drone and for the simulator)."""
        sc, ins = self.s.sc, self.ins
        cap = np.zeros(ins.ids.size, dtype=np.bool_)
        for a in sc.agents:  # what each camera captures from its start pose (drones, not rows)
            cap |= ins.captures_at(a.p0, a.v0)
        P0 = np.array([a.p0 for a in sc.agents], dtype=np.float64)
        return initial_resplits(P0, initial_owner(sc), cap, ins.table)[0]

    def initial_split(self, now: float) -> bool:
        """This drone's part of the initial re-splits (the core's tick): True if a leg started (the
        drone holds its pose while it goes), else it flies its tour meanwhile."""
        s, ins = self.s, self.ins
        if self.done:
            return False
        if self._since is None or self.target is None:  # first: what the start pose images
            self._since = now
            ins.capture()
            self.target = self._target()
        target = self.target
        waited = now - self._since >= INITIAL_WAIT_S
        if self.moves.active or s.machine.pending_ids:
            return True
        if self._leg is not None:  # the last leg's group ended: committed, or try again
            peer, before = self._leg
            self._leg = None
            if self.moves.legs > before:
                self.initial_left.remove(peer)
        mine = s.machine.owned_arrays()[0]
        want = target == self.me
        job = self._next_leg(mine, want, waited)
        if job is None:
            if waited or not self.initial_left:
                self.done = True
            return False  # fly the tour meanwhile (it is planned again as the set changes)
        aid, theirs, p_peer, v_peer = job
        prop = self._proposal(aid, p_peer, v_peer, mine, theirs, want,
                              target == s.order.index(aid))
        self._leg = (aid, self.moves.legs)
        self._tries[aid] = self._tries.get(aid, 0) + 1
        if not self.moves.start_resplit(prop, now):
            self._leg = None
            return False
        self.initial_splits += 1
        _log.info("agent %s: initial re-split with %s", s.id, aid)
        return True  # the leg is in flight: hold the pose meanwhile

    def _next_leg(self, mine: IntArray, want: Mask, waited: bool
                  ) -> tuple[str, IntArray, NDArray[np.float64], NDArray[np.float64]] | None:
        """The next later peer whose leg moves something: (id, its set, its
        position [m; world ENU], its camera direction); peers with nothing to move, given up
        or fenced leave the list."""
        ids, target = self.ins.ids, self.target
        assert target is not None
        for aid in list(self.initial_left):  # a loop over the team's later drones
            entry = self.members.states.get(aid)
            if aid in self.s.machine.fenced or self._tries.get(aid, 0) >= LEG_TRIES or (
                    entry is None and waited):
                self.initial_left.remove(aid)
                continue
            got = None if entry is None else unpack(entry[0].owned)
            if entry is None or got is None or entry[1] <= self._used.get(aid, -np.inf):
                continue
            theirs = got[0]
            k = self.s.order.index(aid)
            if not (np.isin(mine, ids[target == k]).any()
                    or np.isin(theirs, ids[want]).any()):
                self.initial_left.remove(aid)  # nothing between us to move
                continue
            self._used[aid] = entry[1]
            return aid, theirs, np.asarray(entry[0].p), np.asarray(entry[0].v)
        return None

    def settled(self, now: float) -> bool:
        """Whether the initial re-splits are over at mission time ``now`` [s]: this drone's
        legs carried out, and its set and every live peer's published one the target's (or
        :data:`INITIAL_WAIT_S` gone by, or none to make: a restart, a joiner)."""
        if self._settled or not self.done:
            return self._settled
        if self.target is None or self._since is None or now - self._since >= INITIAL_WAIT_S:
            self._settled = True
            return True
        s, ids = self.s, self.ins.ids
        sets = {s.id: s.machine.owned_arrays()[0]}
        for aid in s.order:  # the live peers' published sets too (drones, not landmarks)
            entry = self.members.states.get(aid)
            got = None if entry is None else unpack(entry[0].owned)
            if aid != s.id and aid in self.members.live and got is not None:
                sets[aid] = got[0]
        # Once held, it stays over: later take-work re-splits move sets away from the target.
        self._settled = all(np.array_equal(np.sort(own),
                                           np.sort(ids[self.target == s.order.index(aid)]))
                            for aid, own in sets.items())
        return self._settled

    def tick(self, now: float) -> None:
        """With nothing of its own left: try to take work once (bounded by the strategy's
        tries), else fly home; not before the initial re-splits are over here (an earlier
        drone's leg may still bring work, as it does at once in the simulator)."""
        s, ins = self.s, self.ins
        if not self.settled(now):
            return
        if ins.want_home or ins.take_tries >= TAKE_TRIES:  # no more offers: home (once)
            ins.want_home = True
            if not ins.at_home:
                s.optimise_again()
            return
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
            started = s.phase == "converged" and self.moves.start_resplit(prop, now)
            if started:
                _log.info("agent %s: taking %d landmarks of work from %s (tours %.1f / %.1f m)",
                          s.id, np.setdiff1d(prop.sets[0], mine).size, aid, *act.lengths)
        if not started and ins.want_home and not ins.at_home:
            # nothing to take: fly home (the planner's tick runs again)
            s.optimise_again()
