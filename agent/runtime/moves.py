"""The coverage moves of ``strategy = "potential"`` as one agent makes them (beyond the
thesis; the simulator's version is :mod:`agent.sim.strategy`).

Stage 1 is the thesis' strategy exactly. When an agent's completion detector first holds
(section 4.5's condition, every live peer quiet), it enters stage 2 instead of reporting the
mission complete: it publishes ``stage = 2``, tries every partner again and may fly once to a
better viewpoint for its own set (:meth:`Planning.relocate_for_stage`). In stage 2, when
Algorithm 7 moves nothing with a converged stage-2 partner (NoTrade), the agent asks
:func:`~agent.core.coverage_moves.group_proposal` for a re-split of both sets between two new
poses, from its own state and the partner's last published state only, and offers it
(:mod:`agent.protocol.regroup`); once committed both fly to their new poses and optimise from
there. The mission is complete when the completion condition holds again with every agent in
stage 2. Relocations and re-splits are bounded per agent (``max_relocations``,
``regroups_per_member`` × team size), so every run terminates.

Left out of the simulator's strategy: three-way and whole-team re-splits, and the revert to
the thesis' final state when the moves ended below it (they need a coordinated round).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import cast

import numpy as np

from agent.core.coverage_moves import OwnState, PeerMessage, group_proposal
from agent.core.vision import per_landmark_cols
from agent.protocol.regroup import regroup_terms
from agent.runtime.membership import Membership
from agent.runtime.shared import Attempt, Shared, vec3
from agent.runtime.trade_client import PoseNow
from agent.sim.strategy import environment_of
from agent.wire.codec import Codec
from agent.wire.peer import Request, unpack

_log = logging.getLogger(f"viscover.{__name__}")


@dataclass
class _Queued:
    partner: str
    ledger_rev: int


class CoverageMoves:
    """Stage switch and pair re-splits of one agent (see the module docstring)."""

    def __init__(self, shared: Shared, members: Membership, c_req: Codec[Request],
                 pose_now: PoseNow) -> None:
        self.s, self.members, self.c_req, self.pose_now = shared, members, c_req, pose_now
        self.enabled = shared.sc.strategy == "potential" and shared.sc.trading
        self.env = environment_of(shared.sc) if self.enabled else None
        self._queued: _Queued | None = None
        self.regroups = 0  #: pair re-splits this agent initiated

    def enter_stage_2(self, now: float) -> bool:
        """The thesis stage completed in our view: start the coverage moves (under the lock);
        False if this agent does not make them (then the mission is complete)."""
        s = self.s
        if not self.enabled or s.stage == 2:
            return False
        s.stage = 2
        s.success()  # every partner again, and a planner pass (which may relocate)
        s.dirty = True
        _log.info("agent %s: thesis stage complete; coverage moves on", s.id)
        return True

    def after_no_trade(self, partner: str, was_regroup: bool) -> None:
        """Algorithm 7 moved nothing with ``partner`` (under the lock): in stage 2 try a pair
        re-split with it at the next tick (not after a re-split was refused)."""
        s = self.s
        limit = s.cfg.regroups_per_member * len(self.members.team_order())
        if s.stage == 2 and not was_regroup and self.regroups < limit:
            self._queued = _Queued(partner, s.ledger_rev)

    def _peer(self, partner: str) -> PeerMessage | None:
        """The partner as its last state shows it, if converged in stage 2 (under the lock)."""
        entry = self.members.states.get(partner)
        if entry is None or partner not in self.members.live:
            return None
        st = entry[0]
        got = unpack(st.owned)
        if st.stage != 2 or st.phase != "converged" or got is None:
            return None
        rows = self.s.geo.rows(got[0])
        lm = self.s.geo.subset(rows)
        return PeerMessage(partner, np.asarray(st.p, np.float64), np.asarray(st.v, np.float64),
                           got[0], lm.qT.T.copy(), lm.uT.T.copy(), float(st.vision), True)

    def maybe_regroup(self, now: float) -> bool:
        """Offer the queued pair re-split if one beats both current visions (tick thread);
        True if an offer is now in flight."""
        s, q = self.s, self._queued
        if q is None or self.env is None:
            return False
        self._queued = None
        with s.lock:
            peer = self._peer(q.partner)
            if peer is None or s.phase != "converged" or s.ledger_rev != q.ledger_rev:
                return False
            ids, vers = s.machine.owned_arrays()
            entry = self.members.states[q.partner][0]
            p_vers = unpack(entry.owned)
            others = np.array([x for a, x in self.members.others_pos.items()
                               if a != q.partner]).reshape(-1, 3)
            rev = s.ledger_rev
        p, v, _ = self.pose_now()
        p, v = np.asarray(p, np.float64), np.asarray(v, np.float64)
        lm = s.geo.subset(s.geo.rows(ids))
        own = OwnState(s.id, p, v, ids, lm.qT.T.copy(), lm.uT.T.copy(),
                       float(per_landmark_cols(p, v, lm, s.geo.term).sum()) if lm.m else 0.0)
        prop = group_proposal(own, (peer,), others, self.env, s.sc.d_opt)
        if prop is None or p_vers is None:
            return False
        terms = regroup_terms(prop, ids, vers, p_vers[0], p_vers[1])
        with s.lock:
            if s.phase != "converged" or s.ledger_rev != rev:
                return False
            step = s.machine.new_offer(q.partner, vec3(p), vec3(v), regroup=terms)
            s.journal(step)
            assert step.trade_id is not None
            s.regroup_goals[step.trade_id] = prop.goals[0]
            payload = self.c_req.encode(cast(Request, step.message))
            s.attempt = Attempt(step.trade_id, q.partner, payload, due=now, regroup=True)
            s.counters.offers_sent += 1
            self.regroups += 1
        _log.info("agent %s: pair re-split offered to %s (predicted gain %.3f)", s.id,
                  q.partner, prop.gain)
        return True
