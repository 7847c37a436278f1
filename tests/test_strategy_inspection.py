"""The inspection strategy's decisions (agent.strategy.inspection) on a hand-built capture
table: a row of 40 landmarks along x, one viewpoint over each pair of them."""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np
import pytest

from agent.core.inspection import CaptureTable
from agent.strategy.inspection import (
    FlyTo,
    GoHome,
    PeerWork,
    TakeWork,
    advance_tour,
    initial_resplits,
    next_action,
    plan_tour,
    remaining,
    settle_set,
    split_pair,
)

M = 40


def _table(uncapturable: tuple[int, ...] = ()) -> CaptureTable:
    """Viewpoint k at (2k + 0.5, 0, 3) [m] captures landmarks 2k and 2k + 1."""
    K = M // 2
    P = np.stack([2.0 * np.arange(K) + 0.5, np.zeros(K), np.full(K, 3.0)], axis=1)
    V = np.tile([0.0, 0.0, -1.0], (K, 1))
    C = (np.arange(M)[None, :] // 2) == np.arange(K)[:, None]
    reason = np.zeros(M, dtype=np.int8)
    for j in uncapturable:
        C[:, j] = False
        reason[j] = 3
    return CaptureTable(P, V, C, C.sum(axis=1).astype(float), reason)


def _mask(idx: Iterable[int]) -> np.ndarray:
    out = np.zeros(M, dtype=bool)
    out[list(idx)] = True
    return out


def test_remaining_is_owned_uncaptured_and_capturable() -> None:
    table = _table(uncapturable=(5,))
    got = remaining(_mask(range(10)), _mask([1, 2]), table)
    assert np.flatnonzero(got).tolist() == [0, 3, 4, 6, 7, 8, 9]


def test_a_tour_captures_what_remains_with_one_viewpoint_per_pair_in_path_order() -> None:
    table = _table()
    need = _mask([0, 3, 9, 30, 31])
    tour = plan_tour(np.array([-5.0, 0.0, 3.0]), need, table)
    assert tour.rows.tolist() == [0, 1, 4, 15]  # nearest first along the row
    assert (tour.credit[need] >= 0).all() and (tour.credit[~need] == -1).all()
    assert tour.length == pytest.approx(30.5 + 5.0)
    blocked = np.zeros(M // 2, dtype=bool)
    blocked[4] = True
    assert 4 not in plan_tour(np.zeros(3), need, table, blocked).rows.tolist()


def test_a_re_split_hands_the_far_work_to_the_drone_near_it() -> None:
    table = _table()
    a, b = np.array([-2.0, 0.0, 3.0]), np.array([42.0, 0.0, 3.0])
    split = split_pair(a, _mask(range(M)), b, _mask([]), table)
    assert split is not None
    mine, theirs, (la, lb) = split
    assert not (mine & theirs).any() and (mine | theirs).all()
    assert mine[0] and theirs[M - 1]  # each keeps its own end
    old = plan_tour(a, _mask(range(M)), table).length
    assert max(la, lb) < 0.95 * old
    assert la == pytest.approx(plan_tour(a, mine, table).length)
    assert lb == pytest.approx(plan_tour(b, theirs, table).length)
    # Already balanced: nothing to gain.
    assert split_pair(a, mine, b, theirs, table) is None


def test_next_action_flies_the_tour_then_takes_work_then_goes_home() -> None:
    table = _table()
    p = np.array([-2.0, 0.0, 3.0])
    none = _mask([])
    need = _mask([6, 7])
    act = next_action(p, plan_tour(p, need, table), need, [], none, table)
    assert act == FlyTo(3)
    far = np.array([42.0, 0.0, 3.0])
    peer_owned = _mask(range(M))
    peer_len = plan_tour(far, peer_owned, table).length
    act = next_action(p, plan_tour(p, none, table), none,
                      [PeerWork("B", far, peer_owned, peer_len)], none, table)
    assert isinstance(act, TakeWork) and act.peer == "B"
    assert act.mine.any() and not (act.mine & act.theirs).any()
    # The peer's work is all captured already: nothing to take.
    act = next_action(p, plan_tour(p, none, table), none,
                      [PeerWork("B", far, peer_owned, peer_len)], _mask(range(M)), table)
    assert isinstance(act, GoHome)


def test_settle_set_is_what_the_viewpoint_was_chosen_for_and_is_still_uncaptured() -> None:
    table = _table()
    tour = plan_tour(np.zeros(3), _mask([4, 5, 6]), table)
    assert np.flatnonzero(settle_set(2, tour.credit, _mask([4]))).tolist() == [5]


def test_advance_tour_drops_the_viewpoints_whose_landmarks_were_all_captured() -> None:
    table = _table()
    p = np.array([-5.0, 0.0, 3.0])
    tour = plan_tour(p, _mask([0, 3, 9, 30, 31]), table)  # rows 0, 1, 4, 15
    rest = advance_tour(np.array([2.5, 0.0, 3.0]), tour, _mask([0, 30]), table)
    assert rest.rows.tolist() == [1, 4, 15]  # row 15 keeps landmark 31
    assert rest.length == pytest.approx(6.0 + 22.0)
    assert (rest.credit >= 0).tolist() == _mask([3, 9, 31]).tolist()
    # With nothing captured meanwhile it is the tour itself (from the same position).
    same = advance_tour(p, tour, _mask([]), table)
    assert same.rows.tolist() == tour.rows.tolist() and same.length == tour.length
    assert advance_tour(p, tour, _mask(range(M)), table).empty


def test_initial_resplits_take_each_pair_in_team_order_and_move_only_remaining_work() -> None:
    """Three drones on a row of 40 landmarks, drone 0 holding everything: the pairs (0, 1),
    (0, 2), (1, 2) are judged one after the other on the sets the earlier ones left; captured
    and uncapturable landmarks keep their owner; every split is one of split_pair's, applied
    in order it gives the returned owners."""
    table = _table(uncapturable=(7,))
    P0 = np.array([[-2.0, 0.0, 3.0], [20.0, 0.0, 3.0], [42.0, 0.0, 3.0]])
    owner0 = np.zeros(M, dtype=np.intp)
    captured = _mask([0, 1, 39])
    owner, splits = initial_resplits(P0, owner0, captured, table)
    assert [(x.a, x.b) for x in splits] == sorted((x.a, x.b) for x in splits)
    assert splits and {x.a for x in splits} | {x.b for x in splits} == {0, 1, 2}
    frozen = captured | _mask([7])
    assert np.array_equal(owner[frozen], owner0[frozen])
    replay = owner0.copy()
    for x in splits:
        need_a = remaining(replay == x.a, captured, table)
        need_b = remaining(replay == x.b, captured, table)
        assert not (x.mine & x.theirs).any() and np.array_equal(x.mine | x.theirs,
                                                               need_a | need_b)
        replay[x.mine], replay[x.theirs] = x.a, x.b
    assert np.array_equal(replay, owner)
    assert set(owner.tolist()) == {0, 1, 2}  # the far work went to the drones near it
