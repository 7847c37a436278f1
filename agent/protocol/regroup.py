"""Re-splits over the trade protocol (``strategy = "potential"``, beyond the thesis): a
converged pair that Algorithm 7 cannot improve re-splits the union of its sets between two new
poses (:func:`agent.core.coverage_moves.group_proposal`, computed by the initiator from its own
state and the partner's published one). The proposal travels in the Offer
(:class:`~agent.wire.peer.Regroup`) and is carried out by the same two-phase trade as
Algorithm 7's transfers: the responder's decision function (:data:`~agent.protocol.machine.
DecideFn`) accepts it only if it was made for the responder's current set and moves only what
the two own; otherwise it moves nothing (NoTrade). A re-split of three or more members is a
sequence of such pairwise legs (:func:`leg_terms`, :func:`after_leg`); a revert pull
(:func:`pull_terms`) takes back named landmarks from whoever owns them all. Pure: no clock, no
I/O.
"""

from __future__ import annotations

import math

import numpy as np

from agent.core.coverage_moves import Goal, GroupProposal
from agent.protocol.machine import DecideFn, IntArray, Mask
from agent.protocol.records import Vec3
from agent.wire.peer import Regroup, pack_arrays, unpack


def regroup_terms(proposal: GroupProposal, own_ids: IntArray, own_vers: IntArray,
                  partner_ids: IntArray, partner_vers: IntArray) -> Regroup:
    """The Regroup an initiator sends for a pair ``proposal`` (member 0: the initiator, 1:
    the partner), from both sets as it knows them (ids and versions)."""
    terms = leg_terms(proposal.sets[1], proposal.goals[1], own_ids, own_vers, partner_ids,
                      partner_vers)
    return terms if terms is not None else Regroup(
        before=pack_arrays(partner_ids, partner_vers), give=pack_arrays(own_ids[:0], own_vers[:0]),
        take=pack_arrays(partner_ids[:0], partner_vers[:0]), goal_p=_vec(proposal.goals[1].p),
        goal_v=_vec(proposal.goals[1].v))


def leg_terms(new_peer: IntArray, goal: Goal, own_ids: IntArray, own_vers: IntArray,
              peer_ids: IntArray, peer_vers: IntArray) -> Regroup | None:
    """One leg of a group re-split with one peer, whose set is to become ``new_peer`` (ids):
    the initiator takes every landmark of the peer's current set that is not in its new set
    and gives every landmark of the new set it holds now; None if nothing moves. A k-member
    re-split is a sequence of such pairwise two-phase trades, each atomic on its own (every
    landmark has one owner throughout); the initiator holds what is in transit between two
    peers."""
    give = np.isin(own_ids, new_peer)
    take = ~np.isin(peer_ids, new_peer)
    if not (give.any() or take.any()):
        return None
    return Regroup(before=pack_arrays(peer_ids, peer_vers),
                   give=pack_arrays(own_ids[give], own_vers[give]),
                   take=pack_arrays(peer_ids[take], peer_vers[take]),
                   goal_p=_vec(goal.p), goal_v=_vec(goal.v))


def after_leg(r: Regroup, own_ids: IntArray, own_vers: IntArray, peer_ids: IntArray,
              peer_vers: IntArray) -> tuple[IntArray, IntArray, IntArray, IntArray]:
    """Both sets (ids, versions) once leg ``r`` committed: the initiator's and the peer's
    (versions of moved landmarks as sent; the ledger bumps them, which no leg relies on)."""
    give, take = unpack(r.give), unpack(r.take)
    assert give is not None and take is not None
    keep_o = ~np.isin(own_ids, give[0])
    keep_p = ~np.isin(peer_ids, take[0])
    return (np.concatenate([own_ids[keep_o], take[0]]), np.concatenate([own_vers[keep_o], take[1]]),
            np.concatenate([peer_ids[keep_p], give[0]]),
            np.concatenate([peer_vers[keep_p], give[1]]))


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


def pull_terms(take_ids: IntArray, take_vers: IntArray, holder_ids: IntArray,
               holder_vers: IntArray) -> Regroup:
    """A revert pull: the initiator takes back ``take`` (ids, versions as published) from a
    holder whose published set is ``holder``."""
    none = np.zeros(0, dtype=np.int64)
    return Regroup(before=pack_arrays(holder_ids, holder_vers), give=pack_arrays(none, none),
                   take=pack_arrays(take_ids, take_vers), goal_p=(0.0, 0.0, 0.0),
                   goal_v=(1.0, 0.0, 0.0), pull=True)


def pull_decision(r: Regroup) -> DecideFn:
    """The holder's decision for a revert pull: give ``take`` if it owns every landmark of
    it and nothing comes back; else nothing."""
    give, take = unpack(r.give), unpack(r.take)

    def decide(_p_i: Vec3, _v_i: Vec3, ids_i: IntArray, _p_r: Vec3, _v_r: Vec3,
               ids_r: IntArray) -> tuple[Mask, Mask]:
        none = (np.zeros(ids_i.size, dtype=np.bool_), np.zeros(ids_r.size, dtype=np.bool_))
        if give is None or take is None or give[0].size or not take[0].size:
            return none
        m_ri = np.isin(ids_r, take[0])
        if int(m_ri.sum()) != np.unique(take[0]).size:
            return none  # names landmarks we do not own
        return none[0], m_ri

    return decide


def nothing_moves(_p_i: Vec3, _v_i: Vec3, ids_i: IntArray, _p_r: Vec3, _v_r: Vec3,
                  ids_r: IntArray) -> tuple[Mask, Mask]:
    """The decision of a responder not making coverage moves (yet): NoTrade."""
    return np.zeros(ids_i.size, dtype=np.bool_), np.zeros(ids_r.size, dtype=np.bool_)
