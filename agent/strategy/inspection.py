"""The inspection strategy's decisions: each drone captures the landmarks it owns, tour by tour.

An inspection mission (a scenario with ``[inspection]``) wants every capturable landmark
captured once (:mod:`agent.core.inspection`). Each drone owns a set, as in the thesis; a
captured landmark weighs nothing any more, so what a drone works on is its *remaining* set:
owned, not yet captured by anyone, capturable. Its plan is a :class:`Tour`: the fewest
viewpoints of the mission's capture table that capture the remaining set (greedy cover),
visited in a short open path from where it is (:mod:`agent.core.tours`). Every decision is a
pure function of the drone's own state, its peers' messages and the capture table:

- :func:`advance_tour`: the rest of a tour once captures happened (the cheap decision at each
  viewpoint reached, while the drone's set is unchanged);
- :func:`next_action`: fly to the tour's first viewpoint; with nothing left, take work from
  the peer with the longest remaining tour, or go home;
- :func:`split_pair`: a re-split of two drones' remaining sets judged by the longer of their
  two tours (not by vision): what a drone proposes when it takes work, and what the two
  check at the start;
- :func:`settle_set`: at a viewpoint that did not capture all it was chosen for (another
  drone kept it off the exact pose, a flown pose is off), the landmarks for which the
  planner then ascends eq. 3.8 (the vision of the uncaptured ones only) before moving on;
- :func:`gives_up` and :func:`give_up_codes`: a drone whose every viewpoint left proved out
  of reach (a stalled flight) or was reached without its captures tries them all again, at
  most :data:`MAX_RETRIES` times; then it gives what is left up, each landmark
  :data:`BLOCKED` if it reached a viewpoint capturing it, else :data:`UNREACHABLE`. A given-up
  landmark leaves every drone's work (:func:`out_of_work`): the team does not take it over,
  and it is reported with its reason when the mission ends (:mod:`agent.protocol.
  inspection_end`), unless a camera captures it in passing after all.

The simulator (:mod:`agent.sim.inspection`) calls these for every drone in virtual time, and
each agent (:mod:`agent.runtime.moves.inspecting`) for itself.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from agent.core.inspection import CaptureTable
from agent.core.tours import greedy_cover, order_tour, path_length, split_tours

Array = NDArray[np.float64]
Mask = NDArray[np.bool_]
Index = NDArray[np.intp]

#: A re-split must shorten the longer of the two tours by this fraction to be taken.
SPLIT_GAIN = 0.05
#: ... and by at least this much [m] (no churn over small gains).
SPLIT_MIN = 1.0
#: Times a drone plans again around every viewpoint it found out of reach (or reached without
#: its captures) before it gives up what they were for.
MAX_RETRIES = 5
#: Why a drone gave a landmark up (per-landmark codes; 0: not given up): no viewpoint
#: capturing it could be reached; one was reached, yet the capture did not happen there.
UNREACHABLE = 1
BLOCKED = 2


@dataclass(frozen=True)
class Tour:
    """A drone's plan: capture-table rows in visiting order, the row credited with each
    landmark (m,) (-1: not in this tour) and the open path's length [m] from its position."""

    rows: Index
    credit: Index
    length: float

    @property
    def empty(self) -> bool:
        """Nothing left to capture."""
        return self.rows.size == 0


@dataclass(frozen=True)
class PeerWork:
    """What a peer publishes that the strategy reads: id, position (3,) [m; world ENU], the
    landmarks it owns (m,) and the length [m] of its remaining tour."""

    id: str
    p: Array
    owned: Mask
    remaining: float


@dataclass(frozen=True)
class FlyTo:
    """Fly to (and look from) capture-table row ``row``."""

    row: int


@dataclass(frozen=True)
class TakeWork:
    """Re-split the remaining sets with peer ``peer``: this drone's new set ``mine`` and the
    peer's ``theirs`` (m,), and the two tours' lengths [m]."""

    peer: str
    mine: Mask
    theirs: Mask
    lengths: tuple[float, float]


@dataclass(frozen=True)
class GoHome:
    """Nothing left here or to take: fly home."""


Action = FlyTo | TakeWork | GoHome


def remaining(owned: Mask, captured: Mask, table: CaptureTable) -> Mask:
    """Eq. 3.8's set once captures weigh 0: owned, not captured, capturable (m,)."""
    return np.asarray(owned & ~captured & table.capturable, dtype=np.bool_)


def plan_tour(p: Array, need: Mask, table: CaptureTable, blocked: Mask | None = None) -> Tour:
    """The fewest viewpoints (greedy cover over rows not ``blocked``) capturing ``need`` (m,),
    in a short open path from p (3,) [m; world ENU]."""
    rows, credit = greedy_cover(table.rows, need, table.value, table.capturers, blocked)
    if rows.size == 0:
        return Tour(rows, credit, 0.0)
    order = rows[order_tour(p, table.P[rows])]
    return Tour(order, credit, path_length(p, table.P[order]))


def advance_tour(p: Array, tour: Tour, captured: Mask, table: CaptureTable) -> Tour:
    """The rest of ``tour`` once captures happened (by this drone or its peers): its rows
    that still have an uncaptured landmark credited to them, in the same order, from p (3,)
    [m]. Cheap (O(m)), unlike a new :func:`plan_tour`: for a drone whose set did not change."""
    left = (tour.credit >= 0) & ~captured
    alive = np.bincount(tour.credit[left], minlength=table.P.shape[0]) > 0
    rows = tour.rows[alive[tour.rows]]
    credit = np.where(left, tour.credit, -1)
    return Tour(rows, credit, path_length(p, table.P[rows]))


def split_pair(p_a: Array, need_a: Mask, p_b: Array, need_b: Mask, table: CaptureTable
               ) -> tuple[Mask, Mask, tuple[float, float]] | None:
    """A re-split of two drones' remaining sets (at p_a, p_b [m]) that shortens the longer
    of their tours by ≥ SPLIT_GAIN (and SPLIT_MIN [m]): (a's set, b's set, tour lengths),
    or None. The union is covered once and its viewpoints shared by :func:`split_tours`."""
    old = max(plan_tour(p_a, need_a, table).length, plan_tour(p_b, need_b, table).length)
    union = need_a | need_b
    rows, credit = greedy_cover(table.rows, union, table.value, table.capturers)
    if rows.size == 0:
        return None
    label, _ = split_tours(np.vstack([p_a, p_b]), table.P[rows])
    mine = np.zeros(union.shape, dtype=np.bool_)
    got = credit >= 0
    mine[got] = np.isin(credit[got], rows[label == 0])
    mine &= union
    theirs = union & ~mine
    new = (plan_tour(p_a, mine, table).length, plan_tour(p_b, theirs, table).length)
    if max(new) > old * (1.0 - SPLIT_GAIN) or max(new) > old - SPLIT_MIN:
        return None
    return mine, theirs, new


@dataclass(frozen=True)
class InitialSplit:
    """One initial re-split: drone ``a`` (earlier in team order) and drone ``b`` (indices),
    the landmark rows each holds after it (masks (m,) of their remaining sets)."""

    a: int
    b: int
    mine: Mask
    theirs: Mask


def initial_resplits(P0: Array, owner0: Index, captured: Mask, table: CaptureTable
                     ) -> tuple[Index, list[InitialSplit]]:
    """The team's initial re-splits, every pair once in team order, one after the other, each
    :func:`split_pair` of both remaining sets (owned, not ``captured``, capturable) from the
    start positions P0 (n, 3) [m; world ENU]: (the owner of each landmark after them (m,),
    the re-splits made). A pure function of the mission's start, so the simulator and every
    agent compute the same one."""
    owner = np.asarray(owner0, dtype=np.intp).copy()
    done: list[InitialSplit] = []
    n = P0.shape[0]
    for i in range(n):  # pairs of drones in team order (not landmarks)
        for j in range(i + 1, n):
            split = split_pair(P0[i], remaining(owner == i, captured, table), P0[j],
                               remaining(owner == j, captured, table), table)
            if split is not None:
                owner[split[0]] = i
                owner[split[1]] = j
                done.append(InitialSplit(i, j, split[0], split[1]))
    return owner, done


def next_action(p: Array, tour: Tour, need: Mask, peers: Sequence[PeerWork],
                captured: Mask, table: CaptureTable) -> Action:
    """What a drone at p (3,) [m] does next: the first viewpoint of its tour; with nothing
    left, a re-split with the peer whose remaining tour is longest (if it helps); else home."""
    if need.any() and not tour.empty:
        return FlyTo(int(tour.rows[0]))
    for peer in sorted(peers, key=lambda w: -w.remaining):  # peers, not landmarks
        if peer.remaining <= SPLIT_MIN:
            break
        theirs = remaining(peer.owned, captured, table)
        split = split_pair(p, need, peer.p, theirs, table)
        if split is not None:
            return TakeWork(peer.id, split[0], split[1], split[2])
    return GoHome()


def settle_set(row: int, credit: Index, captured: Mask) -> Mask:
    """Landmarks (m,) viewpoint ``row`` was chosen for and that are still not captured."""
    return np.asarray((credit == row) & ~captured, dtype=np.bool_)


def gives_up(retries: int) -> bool:
    """Whether a drone that found every viewpoint of its remaining set out of reach for the
    ``retries``-th time gives the set up (else it clears its blocked viewpoints and tries
    them all again)."""
    return retries > MAX_RETRIES


def give_up_codes(need: Mask, reached: Mask, table: CaptureTable) -> NDArray[np.int8]:
    """The give-up code of each landmark (m,) of ``need`` (0 elsewhere): :data:`BLOCKED` if
    one of the viewpoints ``reached`` (K,) (arrived at, the capture not all done) captures
    it, else :data:`UNREACHABLE`."""
    seen = table.rows.any_of(reached)
    codes = np.where(seen, BLOCKED, UNREACHABLE).astype(np.int8)
    return np.where(need, codes, 0).astype(np.int8)


def out_of_work(given_up: NDArray[np.int8]) -> Mask:
    """Landmarks (m,) given up by a drone that tried them (:data:`UNREACHABLE`,
    :data:`BLOCKED`): nobody's work any more (a drone that left on low battery gave its own
    up untried: those stay work for whoever takes them over)."""
    return np.asarray((given_up == UNREACHABLE) | (given_up == BLOCKED), dtype=np.bool_)
