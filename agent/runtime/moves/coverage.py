"""The coverage moves of ``strategy = "potential"`` as one agent makes them (beyond the
thesis; ``viscover simulate`` runs this code too, :mod:`agent.testing.agent_engine`).

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

A re-split of k > 2 members (a *triple*: when no pair re-split with the NoTrade partner beats
both, one with it and each other converged stage-2 peer in turn, as the simulator tries) is
carried out as a sequence of pairwise legs (:func:`agent.protocol.regroup.leg_terms`), each
the same atomic two-phase trade: the initiator takes from each peer what leaves its set and
gives it what its new set needs, holding in between what passes from one peer to another.
A leg refused because the peer's set changed ends the move where it stands (every landmark
still has exactly one owner; trading goes on from there). The initiator flies to its pose
after the last leg, each peer after its own.

Stages after 2 (teams of four or more, ``team_moves`` rounds): each starts with the leader's
(the first live member in team order) whole-team re-split, carried out leg by leg; the stage
advances with the first leg, so no peer sees the leader quiet in the new stage before the move.
The last stage makes no moves: entering it, each agent checks whether the team ended below its
thesis-stage score and if so reverts (:mod:`agent.runtime.moves.revert`).
"""

from __future__ import annotations

import logging
from collections import Counter
from collections.abc import Callable, Mapping
from dataclasses import dataclass

import numpy as np

from agent.core.coverage_moves import GroupProposal, OwnState, PeerMessage, group_proposal
from agent.core.vision import per_landmark_cols
from agent.protocol.machine import DecideFn, IntArray
from agent.protocol.regroup import after_leg, leg_terms, regroup_decision
from agent.runtime.core.events import Asking, compute
from agent.runtime.core.shared import Attempt, Shared, vec3
from agent.runtime.ends.membership import Membership
from agent.runtime.ends.trade_client import PoseNow
from agent.strategy.potential import TEAM_STARTS, resplit_after_no_trade
from agent.strategy.registry import strategy_of
from agent.wire.codec import Codec
from agent.wire.peer import MAX_STAGE, Offer, Regroup, Request, unpack

_log = logging.getLogger(f"viscover.{__name__}")


#: A group re-split not finished within this mission time [s] is given up where it stands.
GROUP_TIMEOUT_S = 30.0


@dataclass
class _Queued:
    partner: str
    ledger_rev: int


@dataclass
class _Group:
    """A group re-split in progress: the plan, each peer's set as we know it (ids,
    versions), the leg in flight."""

    plan: GroupProposal
    sets: dict[str, tuple[IntArray, IntArray]]
    started: float
    attempt: Attempt | None = None
    leg: Regroup | None = None
    busy: int = 0
    not_before: float = 0.0
    legs: int = 0


class CoverageMoves:
    """Stages, and re-splits carried out leg by leg, of one agent (see the module docstring):
    the part the registered moves ``team_move`` and ``regroup`` make, which an inspection's
    ``take_work`` and the battery hand-over use too."""

    def __init__(self, shared: Shared, members: Membership, c_req: Codec[Request],
                 pose_now: PoseNow) -> None:
        self.s, self.members, self.c_req, self.pose_now = shared, members, c_req, pose_now
        strategy = strategy_of(shared.sc.strategy)
        self.enabled = strategy.coverage_moves and shared.sc.trading
        #: the strategy's moves this part carries out (agent.strategy.registry)
        self.team = self.enabled and "team_move" in strategy.moves.holding
        self.pairs = self.enabled and "regroup" in strategy.moves.converged
        self.env = shared.world.environment() if self.enabled else None
        self._queued: _Queued | None = None
        self.regroups = 0  #: re-splits this agent initiated (pairs and groups)
        self.legs = 0  #: committed legs of the group re-splits it initiated
        self.started: Counter[int] = Counter()  #: re-splits started, by number of members
        self.group: _Group | None = None  #: the group re-split in progress, if any
        self._team_due = False  #: we lead the next whole-team re-split (the core's tick)
        #: the strategy's last stage: one more per whole-team re-split round; the last one
        #: makes no moves (and may revert); 1 without coverage moves
        self.final_stage = self._final_stage() if self.enabled else 1
        #: called with the stage entered at a stage change (2: the thesis stage ended; the
        #: last one: the moves are over), e.g. by the revert (agent.runtime.moves.revert)
        self.on_stage: list[Callable[[int], None]] = []

    def _final_stage(self) -> int:
        """The last stage: after stage 2, one per whole-team re-split round (``team_moves``,
        in a scenario team of four or more), then the last one, which makes no moves and may
        revert (:mod:`agent.runtime.moves.revert`)."""
        rounds = max(0, self.s.cfg.team_moves) if self.team and len(self.s.order) >= 4 else 0
        return min(MAX_STAGE, 3 + rounds)

    def next_stage(self, now: float) -> bool:
        """The completion condition held: go to the next stage instead of
        completing, if there is one. Stage 2 starts the coverage moves; each later one starts
        with the leader's whole-team re-split (:meth:`maybe_team_move`)."""
        s = self.s
        if not self.enabled or s.stage >= self.final_stage:
            return False
        if s.stage == 1:
            s.enter_stage(2)
            self._entered(2)
            s.success()  # every partner again, and a planner pass (which may relocate)
            _log.info("agent %s: thesis stage complete; coverage moves on", s.id)
            return True
        if s.stage == self.final_stage - 1:  # the moves are over: the last stage
            s.enter_stage(self.final_stage)
            self._entered(self.final_stage)
            return True
        if self._team_due or self._leader():
            self._team_due = True  # the stage advances when the move has started
            return True
        s.enter_stage(s.stage + 1)
        return True

    def _entered(self, stage: int) -> None:
        for hook in self.on_stage:
            hook(stage)

    def leg_terms(self, req: Offer) -> DecideFn | None:
        """The decision for a re-split leg offered to us (not a pull): taken in the coverage
        stages only, for our current set exactly (:func:`agent.protocol.regroup.
        regroup_decision`)."""
        g = req.regroup
        return regroup_decision(g) if g is not None and not g.pull and self.s.stage >= 2 \
            else None

    def in_move_stage(self) -> bool:
        """Whether this agent is in a stage that makes coverage moves (2 up to the last)."""
        return 2 <= self.s.stage < self.final_stage

    def _leader(self) -> bool:
        """Whether this agent leads whole-team re-splits: the first live, unfenced member in
        team order."""
        live = self.members.live | {self.s.id}
        first = next((a for a in self.members.team_order()
                      if a in live and a not in self.s.machine.fenced), None)
        return first == self.s.id

    def maybe_team_move(self, now: float) -> Asking[bool]:
        """The leader's whole-team re-split at a stage change (the core's tick): all live peers'
        published states, ``TEAM_STARTS`` greedy starts; with four or more members only
        (triples cover three). The stage advances in the same step as the first leg is
        offered, so no peer sees this agent quiet in the new stage before the move; True if
        a leg is now in flight."""
        s = self.s
        if not self._team_due or self.env is None:
            return False
        if s.phase != "converged" or self.group is not None:
            return False
        peers = [self._peer(a) for a in self.members.team_order()
                 if a != s.id and a in self.members.live]
        ids = s.machine.owned_arrays()[0]
        pos = dict(self.members.others_pos)
        rev = s.ledger_rev
        prop = None
        if len(peers) >= 3 and all(x is not None for x in peers):
            group = tuple(x for x in peers if x is not None)
            own, env, d_opt = self._own(ids), self.env, s.sc.d_opt
            rest = _others(pos, *(x.id for x in group))
            prop = yield from compute(lambda: group_proposal(own, group, rest, env, d_opt,
                                                             starts=TEAM_STARTS))
        self._team_due = False
        s.enter_stage(s.stage + 1)
        started = prop is not None and s.phase == "converged" and s.ledger_rev == rev \
            and self._start_group(prop, now)
        if started and prop is not None:
            self.regroups += 1
            _log.info("agent %s: whole-team re-split started (predicted gain %.3f)", s.id,
                      prop.gain)
        return started

    def _own(self, ids: IntArray) -> OwnState:
        """Our own state now: pose, the landmarks ``ids`` and our vision of them (eq. 3.8)."""
        s = self.s
        p, v, _ = self.pose_now()
        p, v = np.asarray(p, np.float64), np.asarray(v, np.float64)
        lm = s.geo.subset(s.geo.rows(ids))
        return OwnState(s.id, p, v, ids, lm.qT.T.copy(), lm.uT.T.copy(),
                        float(per_landmark_cols(p, v, lm, s.geo.term).sum()) if lm.m else 0.0)

    def after_no_trade(self, partner: str, was_regroup: bool) -> None:
        """Algorithm 7 moved nothing with ``partner``: in stage 2 try a pair
        re-split with it at the next tick (not after a re-split was refused)."""
        s = self.s
        limit = s.cfg.regroups_per_member * len(self.members.team_order())
        if self.pairs and self.in_move_stage() and not was_regroup \
                and self.regroups < limit:
            self._queued = _Queued(partner, s.ledger_rev)

    def _peer(self, partner: str) -> PeerMessage | None:
        """The partner as its last state shows it, if converged in stage 2."""
        entry = self.members.states.get(partner)
        if entry is None or partner not in self.members.live:
            return None
        st = entry[0]
        got = unpack(st.owned)
        if st.stage < 2 or st.phase != "converged" or got is None:
            return None
        rows = self.s.geo.rows(got[0])
        lm = self.s.geo.subset(rows)
        return PeerMessage(partner, np.asarray(st.p, np.float64), np.asarray(st.v, np.float64),
                           got[0], lm.qT.T.copy(), lm.uT.T.copy(), float(st.vision), True)

    def _candidates(self, partner: str) -> list[PeerMessage]:
        """Other converged stage-2 peers for a triple with ``partner``, in team order."""
        out = []
        for aid in self.members.team_order():
            if aid not in (self.s.id, partner):
                peer = self._peer(aid)
                if peer is not None:
                    out.append(peer)
        return out

    def maybe_regroup(self, now: float) -> Asking[bool]:
        """Offer the queued re-split if one beats the current visions (the core's tick): a pair
        with the NoTrade partner, else a triple with it and another converged peer; True if
        an offer is now in flight."""
        s, q = self.s, self._queued
        if q is None or self.env is None:
            return False
        self._queued = None
        peer = self._peer(q.partner)
        if peer is None or s.phase != "converged" or s.ledger_rev != q.ledger_rev:
            return False
        ids = s.machine.owned_arrays()[0]
        thirds = self._candidates(q.partner) if s.cfg.triples else []
        pos = dict(self.members.others_pos)
        rev = s.ledger_rev
        own, env, d_opt, triples = self._own(ids), self.env, s.sc.d_opt, s.cfg.triples
        prop = yield from compute(lambda: resplit_after_no_trade(
            own, peer, thirds, lambda out: _others(pos, *out), env, d_opt, triples))
        if prop is None:
            return False
        if s.phase != "converged" or s.ledger_rev != rev:
            return False
        if not self._start_group(prop, now):
            return False
        self.regroups += 1
        _log.info("agent %s: re-split offered to %s (predicted gain %.3f)", s.id,
                  ", ".join(prop.members[1:]), prop.gain)
        return True

    def start_resplit(self, prop: GroupProposal, now: float) -> bool:
        """Carry out a re-split another strategy computed (an inspection drone taking work):
        leg by leg as the coverage moves' own."""
        if self.group is not None or not self._start_group(prop, now):
            return False
        self.regroups += 1
        return True

    def _start_group(self, prop: GroupProposal, now: float) -> bool:
        """Begin carrying out ``prop``: the peers' sets as published, then
        the first leg; False if a peer's published set is gone."""
        sets: dict[str, tuple[IntArray, IntArray]] = {}
        for aid in prop.members[1:]:
            entry = self.members.states.get(aid)
            got = None if entry is None else unpack(entry[0].owned)
            if got is None:
                return False
            sets[aid] = got
        self.group = _Group(prop, sets, now)
        if not self._send_leg(self.group, now):
            self.group = None
            return False
        self.started[len(prop.members)] += 1
        return True

    @property
    def active(self) -> bool:
        """Whether a group re-split of ours is in progress."""
        return self.group is not None

    def continue_group(self, now: float) -> bool:
        """Drive the group re-split in progress (the core's tick): take the last leg's outcome,
        send the next leg; True while the move goes on (the agent then holds its pose)."""
        s = self.s
        g = self.group
        if g is None:
            return False
        if g.attempt is not None:
            if s.attempt is g.attempt:
                return True  # the leg is in flight
            if not self._leg_ended(g, now):
                self.group = None
                return False
        if now < g.not_before:
            return True
        if now - g.started > GROUP_TIMEOUT_S:
            _log.info("agent %s: re-split with %s given up after %d legs (timeout)", s.id,
                      ", ".join(g.plan.members[1:]), g.legs)
            self.group = None
            return False
        if self._send_leg(g, now):
            return True
        self.group = None
        return False

    def _leg_ended(self, g: _Group, now: float) -> bool:
        """Take the outcome of the leg that was in flight; False if the move
        ends here (refused, or busy too often)."""
        s, att, leg = self.s, g.attempt, g.leg
        assert att is not None and leg is not None
        g.attempt, g.leg = None, None
        if s.machine.decided.get(att.trade_id) == "committed":
            ids, vers = g.sets[att.partner]
            g.sets[att.partner] = after_leg(leg, ids[:0], vers[:0], ids, vers)[2:]
            g.legs += 1
            g.busy = 0
            self.legs += 1
            return True
        # (== rather than `in` a tuple: strict_equality checks each value is an outcome)
        busy = att.outcome == "retry_later" or att.outcome == "yield"
        if busy and g.busy < s.cfg.busy_retries:
            g.busy += 1
            g.not_before = now + s.cfg.backoff_s * 2.0 ** min(g.busy, 6)
            return True
        _log.info("agent %s: re-split with %s ends after %d legs (%s from %s)", s.id,
                  ", ".join(g.plan.members[1:]), g.legs, att.outcome or "aborted",
                  att.partner)
        return False

    def _send_leg(self, g: _Group, now: float) -> bool:
        """Offer the next leg that moves something; False when none is left
        (the move is done). A peer with an unacknowledged Commit of ours is waited for."""
        s = self.s
        ids, vers = s.machine.owned_arrays()
        unacked = {p for _, p in s.machine.unacked_commits()}
        members = g.plan.members
        for k in range(1, len(members)):  # a loop over the group's members (k ≤ team size)
            peer = members[k]
            pids, pvers = g.sets[peer]
            terms = leg_terms(g.plan.sets[k], g.plan.goals[k], ids, vers, pids, pvers)
            if terms is None:
                continue
            if peer in unacked:
                return True  # its last leg is not acknowledged yet: it would answer Busy
            p, v, _ = self.pose_now()
            step = s.machine.new_offer(peer, vec3(p), vec3(v), regroup=terms)
            s.journal(step)
            assert step.trade_id is not None
            if self._last_leg(g, k, terms, ids, vers):
                s.expect_goal(step.trade_id, g.plan.goals[0])
            payload = self.c_req.encode(step.request())
            g.attempt = Attempt(step.trade_id, peer, payload, due=now, regroup=True)
            g.leg = terms
            s.begin_offer(g.attempt)
            s.counters.offers_sent += 1
            return True
        if g.legs:
            _log.info("agent %s: re-split with %s done in %d legs", s.id,
                      ", ".join(members[1:]), g.legs)
        return False

    @staticmethod
    def _last_leg(g: _Group, k: int, terms: Regroup, ids: IntArray, vers: IntArray) -> bool:
        """Whether no leg is left once ``terms`` (with member k) committed."""
        members = g.plan.members
        o_ids, o_vers, p_ids, p_vers = after_leg(terms, ids, vers, *g.sets[members[k]])
        sets = dict(g.sets)
        sets[members[k]] = (p_ids, p_vers)
        return all(leg_terms(g.plan.sets[j], g.plan.goals[j], o_ids, o_vers, *sets[members[j]])
                   is None for j in range(1, len(members)))


def _others(pos: Mapping[str, object], *exclude: str) -> np.ndarray:
    """The published positions (k, 3) [m; world ENU] of every other agent not in
    ``exclude``."""
    return np.array([x for a, x in pos.items() if a not in exclude],
                    dtype=np.float64).reshape(-1, 3)
