"""Coverage moves: decisions that take a converged team out of local optima of eq. 3.10.

Gradient ascent (chapter 4) and Algorithm 7 (one-to-one trades of landmarks the partner
sees strictly better *at its current pose*) stop where a landmark is invisible to its owner
(zero gradient) and to everyone else. The moves here judge a change by *potential* vision:
the vision a drone would have at the best pose it can reach for a landmark set, found from
candidate viewpoints (:mod:`agent.core.viewpoints`).

Every decision is a pure function of the deciding agent's own state (:class:`OwnState`),
the messages its peers publish (:class:`PeerMessage`: pose, landmark set, whether it has
converged) and the mission constants (:class:`agent.core.viewpoints.Environment`, d_opt).
Frames and units: world ENU, metres; visions in the units of eq. 3.8.

- :func:`relocation_goal`: jump to a better viewpoint for the own set (eq. 3.8), e.g. when
  some owned landmarks are invisible from the local optimum.
- :func:`pair_proposal`: with a converged peer, re-split the union of both sets between two
  new poses (best-view ownership, the two poses chosen jointly); proposed only if the
  predicted sum of both visions (eq. 3.10 restricted to the pair) beats the current one.
- :func:`group_proposal`: the same for the initiator and several converged peers (3-way
  re-splits leave pairwise local optima).
- :func:`cluster_partition`: an initial partition by clustering landmarks by their ideal
  viewpoints (position and normal), from the landmark table every agent knows.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from agent.core.viewpoints import (
    Environment,
    best_view_owner,
    best_viewpoint,
    feasible,
    refine_team,
    seed_viewpoints,
    seen_vision_matrix,
    select_viewpoints,
)

Array = NDArray[np.float64]
Ids = NDArray[np.int64]

#: A move must predict at least this gain [vision units] ...
ABS_MARGIN = 1e-3
#: ... and this fraction of the current vision.
REL_MARGIN = 0.01


@dataclass(frozen=True)
class OwnState:
    """An agent's own state: pose p, v (3,) [m; world ENU], its landmark ids (m,) with their
    positions q and normals u (m, 3), and the vision of eq. 3.8 at the current pose."""

    id: str
    p: Array
    v: Array
    ids: Ids
    q: Array
    u: Array
    vision: float


@dataclass(frozen=True)
class PeerMessage:
    """What a peer publishes: its pose, landmark set (ids, q, u), its vision and whether its
    pose optimisation has converged (only converged peers trade, section 4.5)."""

    id: str
    p: Array
    v: Array
    ids: Ids
    q: Array
    u: Array
    vision: float
    converged: bool


@dataclass(frozen=True)
class Goal:
    """A pose to fly to, p, v [m; world ENU], and the vision predicted there (eq. 3.8)."""

    p: Array
    v: Array
    predicted: float


@dataclass(frozen=True)
class GroupProposal:
    """A re-split of k agents' landmarks with a new pose each; member 0 is the initiator."""

    members: tuple[str, ...]
    goals: tuple[Goal, ...]
    sets: tuple[Ids, ...]  #: landmark ids each member owns after the move
    sets_before: tuple[Ids, ...]  #: each member's set the proposal was computed for
    gain: float  #: predicted increase of Σ vis over the members

    @property
    def a_ids(self) -> Ids:
        """The initiator's landmarks after the move."""
        return self.sets[0]

    @property
    def b_ids(self) -> Ids:
        """The (first) partner's landmarks after the move."""
        return self.sets[1]


#: The pairwise case (the partner is member 1).
PairProposal = GroupProposal


def _beats(new: float, old: float) -> bool:
    """Whether a predicted vision ``new`` beats ``old`` by the move margins."""
    return new > old + ABS_MARGIN + REL_MARGIN * abs(old)


def current_vision(member: OwnState | PeerMessage, env: Environment, d_opt: float) -> float:
    """Eq. 3.8 of a member's own set at its current pose: its stated vision under the facing
    model; with occlusion (``env.sight``) recomputed here with the lines of sight, so a move
    is judged against the vision the structure really lets it have."""
    if env.sight is None or member.ids.size == 0:
        return member.vision
    return float(seen_vision_matrix(member.p[None, :], member.v[None, :], member.q, member.u,
                                    d_opt, env).sum())


def relocation_goal(
    own: OwnState, others: Array, env: Environment, d_opt: float
) -> Goal | None:
    """A better pose for the own set (eq. 3.8 at the best feasible candidate viewpoint, ≥ R_s
    from the published positions ``others`` (k, 3) [m]), or None if none beats the current."""
    if own.ids.size == 0:
        return None
    p, v, val = best_viewpoint(own.q, own.u, d_opt, env, others,
                               extra_P=own.p[None, :], extra_V=own.v[None, :])
    if not np.isfinite(p).all() or not _beats(val, current_vision(own, env, d_opt)):
        return None
    return Goal(p, v, val)


def _match(P: Array, current: Array) -> NDArray[np.intp]:
    """Greedy nearest matching of k new positions P to k current positions [m]: slot of each
    current row (a loop over the k ≤ team-size members)."""
    k = P.shape[0]
    dist = np.sqrt(((current[:, None, :] - P[None, :, :]) ** 2).sum(axis=2))
    slot = np.zeros(k, dtype=np.intp)
    for _ in range(k):
        i, c = np.unravel_index(int(np.argmin(dist)), dist.shape)
        slot[i] = c
        dist[i, :], dist[:, c] = np.inf, np.inf
    return slot


def group_proposal(
    own: OwnState, peers: tuple[PeerMessage, ...], others: Array, env: Environment,
    d_opt: float, starts: int = 1,
) -> GroupProposal | None:
    """Re-split the union of the own and the peers' landmarks between k = 1 + len(peers)
    jointly chosen poses (best-view ownership, eq. 3.10 on the group), ≥ R_s apart and from
    ``others`` (j, 3) [m] (the other agents' published positions); ``starts`` greedy starts
    besides the current poses. None unless every peer has converged and the predicted Σ vis
    beats the members' current sum."""
    if not all(p.converged for p in peers):
        return None
    members: tuple[OwnState | PeerMessage, ...] = (own, *peers)
    k = len(members)
    q = np.vstack([m.q for m in members])
    u = np.vstack([m.u for m in members])
    ids = np.concatenate([m.ids for m in members])
    if ids.size == 0:
        return None
    cur_p = np.array([m.p for m in members])
    cur_v = np.array([m.v for m in members])
    P, V = seed_viewpoints(q, u, d_opt)
    ok = feasible(P, env, others)
    P, V = np.vstack([cur_p, P[ok]]), np.vstack([cur_v, V[ok]])  # current poses first
    M = seen_vision_matrix(P, V, q, u, d_opt, env)
    # Solutions to refine: the current poses swapped-improved, and greedy selections from
    # the best candidate and from the ``starts`` − 1 next best single candidates.
    sols = [select_viewpoints(M, P, k, env.r_s, init=np.arange(k, dtype=np.intp))[0]]
    firsts = np.argsort(-M.sum(axis=1), kind="stable")[:max(starts - 1, 0)]
    sols.append(select_viewpoints(M, P, k, env.r_s)[0])
    sols.extend(select_viewpoints(M, P, k, env.r_s, first=int(f))[0] for f in firsts)
    was = np.repeat(np.arange(k, dtype=np.intp), [m.ids.size for m in members])
    best: tuple[float, Array, Array] | None = None
    tried: list[NDArray[np.intp]] = []
    for chosen in sols:  # loop over a few candidate solutions, each vectorised
        if chosen.size < k or any(np.array_equal(np.sort(chosen), t) for t in tried):
            continue
        tried.append(np.sort(chosen))
        slot = _match(P[chosen], cur_p)
        Pn, Vn, _, val = refine_team(P[chosen][slot], V[chosen][slot], q, u, d_opt, env,
                                     fixed_others=others, owner=was)
        if best is None or val > best[0]:
            best = (val, Pn, Vn)
    if best is None:
        return None
    _, Pn, Vn = best
    Mn = seen_vision_matrix(Pn, Vn, q, u, d_opt, env)
    owner = best_view_owner(Mn, was)
    vals = (Mn * (owner[None, :] == np.arange(k)[:, None])).sum(axis=1)
    current = float(sum(current_vision(m, env, d_opt) for m in members))
    if not _beats(float(vals.sum()), current):
        return None
    return GroupProposal(
        members=tuple(m.id for m in members),
        goals=tuple(Goal(Pn[i], Vn[i], float(vals[i])) for i in range(k)),
        sets=tuple(ids[owner == i] for i in range(k)),
        sets_before=tuple(m.ids for m in members),
        gain=float(vals.sum()) - current,
    )


def pair_proposal(
    own: OwnState, peer: PeerMessage, others: Array, env: Environment, d_opt: float
) -> GroupProposal | None:
    """:func:`group_proposal` with one peer: re-split own ∪ peer between two new poses."""
    return group_proposal(own, (peer,), others, env, d_opt)


def cluster_partition(
    q: Array, u: Array, positions: Array, env: Environment, d_opt: float
) -> tuple[NDArray[np.intp], Array, Array]:
    """Initial partition from clustering landmarks by their ideal viewpoints: n jointly chosen
    viewpoints (best-view ownership), matched greedily to the agents' positions (n, 3) [m];
    returns (owner index per landmark (m,), goal positions (n, 3), goal directions (n, 3))."""
    n = positions.shape[0]
    P, V = seed_viewpoints(q, u, d_opt)
    ok = feasible(P, env)
    P, V = P[ok], V[ok]
    M = seen_vision_matrix(P, V, q, u, d_opt, env)
    chosen, _ = select_viewpoints(M, P, n, env.r_s)
    Pc, Vc, owner, _ = refine_team(P[chosen], V[chosen], q, u, d_opt, env)
    k = Pc.shape[0]
    dist = np.sqrt(((positions[:, None, :] - Pc[None, :, :]) ** 2).sum(axis=2))  # (n, k)
    agent_of = np.full(k, -1, dtype=np.intp)
    for _ in range(min(n, k)):  # greedy matching, one pair per pass (n ≤ team size)
        i, c = np.unravel_index(int(np.argmin(dist)), dist.shape)
        agent_of[c] = i
        dist[i, :], dist[:, c] = np.inf, np.inf
    goals_p, goals_v = positions.copy(), np.tile([1.0, 0.0, 0.0], (n, 1))
    matched = agent_of >= 0
    goals_p[agent_of[matched]] = Pc[matched]
    goals_v[agent_of[matched]] = Vc[matched]
    return agent_of[owner], goals_p, goals_v
