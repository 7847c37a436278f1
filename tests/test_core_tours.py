"""Inspection tours (agent.core.tours) against brute force on small instances."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from numpy.typing import NDArray

from agent.core.capture_rows import CaptureRows
from agent.core.tours import capturers, greedy_cover, order_tour, path_length, split_tours


def _best_open_path(start: np.ndarray, pts: np.ndarray) -> float:
    """Shortest open path from start through every point (every permutation)."""
    return min((path_length(start, pts[list(perm)])
                for perm in itertools.permutations(range(pts.shape[0]))), default=0.0)


def _covered(C: NDArray[np.bool_]) -> NDArray[np.bool_]:
    """The landmarks (columns) some viewpoint (row) of ``C`` captures, as an array."""
    return np.asarray(C.any(axis=0))


def test_greedy_cover_captures_every_needed_coverable_landmark_and_credits_a_capturer() -> None:
    rng = np.random.default_rng(0)
    for _ in range(50):
        C = rng.random((25, 40)) < 0.12
        need = rng.random(40) < 0.8
        rows, credit = greedy_cover(C, need)
        coverable = need & C.any(axis=0)
        assert (credit >= 0).tolist() == coverable.tolist()
        j = np.flatnonzero(coverable)
        assert C[credit[j], j].all()
        assert set(credit[j].tolist()) <= set(rows.tolist())
        assert len(set(rows.tolist())) == rows.size  # no viewpoint twice
        # Every chosen viewpoint added a landmark no earlier one had.
        covered = np.zeros(40, dtype=bool)
        for k in rows:
            assert (C[k] & need & ~covered).any()
            covered |= C[k]


def test_greedy_cover_is_within_the_set_cover_bound_of_the_optimum() -> None:
    rng = np.random.default_rng(1)
    for _ in range(30):
        C = rng.random((10, 12)) < 0.3
        need = _covered(C)
        rows, _ = greedy_cover(C, need)
        best = next(k for k in range(1, 11) for sub in itertools.combinations(range(10), k)
                    if _covered(C[list(sub)])[need].all())
        h = sum(1.0 / i for i in range(1, int(C.sum(axis=1).max()) + 1))
        assert best <= rows.size <= best * h + 1e-9


def test_order_tour_is_a_permutation_within_a_third_of_the_shortest_open_path() -> None:
    rng = np.random.default_rng(2)
    ratios = []
    for _ in range(40):
        pts = rng.uniform(0, 20, (7, 3))
        start = rng.uniform(0, 20, 3)
        order = order_tour(start, pts)
        assert sorted(order.tolist()) == list(range(7))
        ratios.append(path_length(start, pts[order]) / _best_open_path(start, pts))
    assert min(ratios) >= 1.0 - 1e-12
    assert max(ratios) <= 1.34


def test_order_tour_ends_at_a_2_opt_local_optimum() -> None:
    rng = np.random.default_rng(3)
    pts = rng.uniform(0, 30, (25, 3))
    start = np.zeros(3)
    order = order_tour(start, pts)
    best = path_length(start, pts[order])
    for i in range(25):
        for j in range(i + 1, 25):
            trial = order.copy()
            trial[i:j + 1] = trial[i:j + 1][::-1]
            assert path_length(start, pts[trial]) >= best - 1e-6


def test_split_tours_is_near_the_min_max_optimum_and_never_worse_than_nearest_starts() -> None:
    rng = np.random.default_rng(4)
    ratios = []
    for _ in range(25):
        pts = rng.uniform(0, 20, (6, 3))
        starts = rng.uniform(0, 20, (2, 3))
        label, lengths = split_tours(starts, pts)
        for i in range(2):
            mine = np.flatnonzero(label == i)
            order = order_tour(starts[i], pts[mine])
            assert lengths[i] == pytest.approx(path_length(starts[i], pts[mine][order]))
        best = min(
            max(_best_open_path(starts[0], pts[[k for k in range(6) if a[k] == 0]]),
                _best_open_path(starts[1], pts[[k for k in range(6) if a[k] == 1]]))
            for a in itertools.product((0, 1), repeat=6))
        near = np.argmin(np.linalg.norm(pts[:, None] - starts[None], axis=2), axis=1)
        voronoi = max(_best_open_path(starts[i], pts[near == i]) for i in range(2))
        assert lengths.max() <= voronoi * 1.34 + 1e-9  # the start, up to the tour heuristic
        ratios.append(lengths.max() / best)
    assert min(ratios) >= 1.0 - 1e-12
    assert float(np.median(ratios)) <= 1.1
    assert max(ratios) <= 1.6


def test_greedy_cover_never_picks_an_excluded_row_and_leaves_what_only_they_capture() -> None:
    rng = np.random.default_rng(5)
    for _ in range(30):
        C = rng.random((20, 30)) < 0.15
        need = np.ones(30, dtype=bool)
        exclude = rng.random(20) < 0.3
        rows, credit = greedy_cover(C, need, exclude=exclude)
        assert not exclude[rows].any()
        reachable = C[~exclude].any(axis=0)
        assert (credit >= 0).tolist() == reachable.tolist()
        same, _ = greedy_cover(C & ~exclude[:, None], need)  # the same as deleting the rows
        assert rows.tolist() == same.tolist()


def test_greedy_cover_of_a_matrix_kept_by_rows_is_the_dense_ones() -> None:
    """The capture table keeps C by rows (a 10^5-landmark table has no dense C): the cover,
    credits and ties are those of the same matrix dense; without its columns it is refused."""
    rng = np.random.default_rng(7)
    for _ in range(20):
        C = rng.random((40, 120)) < 0.06
        need = rng.random(120) < 0.7
        value = rng.random(40)
        rows = CaptureRows.from_dense(C)
        dense = greedy_cover(C, need, value, capturers(C))
        kept = greedy_cover(rows, need, value, rows.columns())
        assert np.array_equal(dense[0], kept[0]) and np.array_equal(dense[1], kept[1])
    with pytest.raises(ValueError, match="kept by rows needs its columns"):
        greedy_cover(rows, need)
