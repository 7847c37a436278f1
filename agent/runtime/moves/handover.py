"""Handing one's work over before leaving (a drone whose battery will not last): every
landmark this agent owns goes to a live peer by the coverage moves' re-split legs (the
journaled two-phase trade of :mod:`agent.protocol.regroup`, which the peer accepts only for
the set it published, even while it flies), so no landmark is ever without an owner and none
waits for a fence round. The peer with the fewest landmarks takes them all; a refused leg
(the peer's set changed) is tried again with the peers as they now are.

Stepped in the core's tick by a departure (:mod:`agent.runtime.core.departing`); the drone leaves
the mission once :meth:`HandOver.step` says nothing is owned any more and the last leg is
acknowledged (or after the departure's own timeout; the team then fences the agent and adopts
what is left, as for any lost drone).
"""

from __future__ import annotations

import logging

import numpy as np

from agent.core.coverage_moves import Goal, GroupProposal
from agent.runtime.core.shared import Shared
from agent.runtime.core.vehicle import VehicleView
from agent.runtime.ends.membership import Membership
from agent.runtime.moves.coverage import CoverageMoves
from agent.wire.peer import unpack

_log = logging.getLogger(f"viscover.{__name__}")


class HandOver:
    """Give everything this agent owns to its peers (see the module docstring)."""

    def __init__(self, shared: Shared, members: Membership, moves: CoverageMoves,
                 pose: VehicleView) -> None:
        self.s, self.members, self.moves, self.pose = shared, members, moves, pose
        self.legs = 0  #: hand-over legs started
        self.given = 0  #: landmarks given so far

    def owned(self) -> int:
        """How many landmarks this agent owns now."""
        return int(self.s.machine.owned_arrays()[0].size)

    def step(self, now: float) -> bool:
        """Start the next hand-over leg when none is under way; True once nothing is owned
        and the last leg is over (the peer acknowledged the commit: leaving earlier could
        leave it in doubt about a decision only this agent knows)."""
        s = self.s
        mine = s.machine.owned_arrays()[0]
        if self.moves.active or s.attempt is not None:
            return False
        if mine.size == 0:
            return True
        peers = []
        for aid, (st, _t) in self.members.states.items():
            got = unpack(st.owned)
            if aid in self.members.live and aid not in s.machine.fenced and got is not None:
                peers.append((got[0].size, aid, np.asarray(st.p, np.float64),
                              np.asarray(st.v, np.float64), got[0]))
        if not peers:
            return False
        _n, aid, p_peer, v_peer, theirs = min(peers, key=lambda x: (x[0], x[1]))
        p, v, _ = self.pose.current()
        prop = GroupProposal(
            members=(s.id, aid),
            goals=(Goal(np.asarray(p, np.float64), np.asarray(v, np.float64), 0.0),
                   Goal(p_peer, v_peer, 0.0)),
            sets=(np.zeros(0, np.int64), np.union1d(theirs, mine)),
            sets_before=(mine, theirs), gain=0.0)
        started = self.moves.start_resplit(prop, now)
        if started:
            self.legs += 1
            self.given += int(mine.size)
            _log.info("agent %s: handing its %d landmarks over to %s", s.id, mine.size, aid)
        return False
