"""Pair re-splits over the trade protocol (``strategy = "potential"``, beyond the thesis): a
converged pair that Algorithm 7 cannot improve re-splits the union of its sets between two new
poses (:func:`agent.core.coverage_moves.group_proposal`, computed by the initiator from its own
state and the partner's published one). The proposal travels in the Offer
(:class:`~agent.wire.peer.Regroup`) and is carried out by the same two-phase trade as
Algorithm 7's transfers: the responder's decision function (:data:`~agent.protocol.machine.
DecideFn`) accepts it only if it was made for the responder's current set and moves only what
the two own; otherwise it moves nothing (NoTrade). Pure: no clock, no I/O.
"""

from __future__ import annotations

import math

import numpy as np

from agent.core.coverage_moves import GroupProposal
from agent.protocol.machine import DecideFn, IntArray, Mask
from agent.protocol.records import Vec3
from agent.wire.peer import Regroup, pack_arrays, unpack


def regroup_terms(proposal: GroupProposal, own_ids: IntArray, own_vers: IntArray,
                  partner_ids: IntArray, partner_vers: IntArray) -> Regroup:
    """The Regroup an initiator sends for ``proposal`` (member 0: the initiator, 1: the
    partner), from both sets as it knows them (ids and versions)."""
    keep = np.isin(own_ids, proposal.sets[0])
    take = np.isin(partner_ids, proposal.sets[0])
    goal = proposal.goals[1]
    return Regroup(before=pack_arrays(partner_ids, partner_vers),
                   give=pack_arrays(own_ids[~keep], own_vers[~keep]),
                   take=pack_arrays(partner_ids[take], partner_vers[take]),
                   goal_p=_vec(goal.p), goal_v=_vec(goal.v))


def _vec(x: object) -> Vec3:
    a = np.asarray(x, dtype=np.float64).reshape(3)
    return (float(a[0]), float(a[1]), float(a[2]))


def regroup_goal_ok(r: Regroup) -> bool:
    """The proposed pose is finite and its direction a unit vector."""
    vals = (*r.goal_p, *r.goal_v)
    return all(math.isfinite(x) for x in vals) and \
        abs(math.sqrt(sum(x * x for x in r.goal_v)) - 1.0) < 1e-6


def regroup_decision(r: Regroup) -> DecideFn:
    """The responder's decision for ``r``: move ``give`` and ``take`` if ``before`` is its
    current set exactly (ids) and ``give`` is within the initiator's offered set; else
    nothing."""
    before, give, take = unpack(r.before), unpack(r.give), unpack(r.take)

    def decide(_p_i: Vec3, _v_i: Vec3, ids_i: IntArray, _p_r: Vec3, _v_r: Vec3,
               ids_r: IntArray) -> tuple[Mask, Mask]:
        none = (np.zeros(ids_i.size, dtype=np.bool_), np.zeros(ids_r.size, dtype=np.bool_))
        if before is None or give is None or take is None or not regroup_goal_ok(r):
            return none
        if not np.array_equal(np.sort(before[0]), np.sort(ids_r)):
            return none  # made for a set we no longer have
        m_ir, m_ri = np.isin(ids_i, give[0]), np.isin(ids_r, take[0])
        if int(m_ir.sum()) != give[0].size or int(m_ri.sum()) != take[0].size:
            return none  # names landmarks the initiator did not offer, or we do not own
        return m_ir, m_ri

    return decide


def nothing_moves(_p_i: Vec3, _v_i: Vec3, ids_i: IntArray, _p_r: Vec3, _v_r: Vec3,
                  ids_r: IntArray) -> tuple[Mask, Mask]:
    """The decision of a responder not making coverage moves (yet): NoTrade."""
    return np.zeros(ids_i.size, dtype=np.bool_), np.zeros(ids_r.size, dtype=np.bool_)
