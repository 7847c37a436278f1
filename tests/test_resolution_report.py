"""The report's resolution section (agent.sim.resolution): landmarks grouped by part and face
direction, each landmark's finest ground sampling distance recomputed here from the logged
camera positions with the datasheet formula, and the least margin to the spec per group."""

from __future__ import annotations

import numpy as np
import pytest

from agent.sim.resolution import best_gsd, face_direction, resolution_rows


def test_face_directions_are_up_down_or_a_compass_side() -> None:
    u = np.array([[0, 0, 1], [0, 0, -1], [0, 1, 0], [1, 0, 0], [0, -1, 0], [-1, 0, 0],
                  [0.6, 0.8, 0.0], [0.0, 0.8, 0.6], [0.0, 0.6, 0.8]], dtype=float)
    assert face_direction(u) == ["up", "down", "N", "E", "S", "W", "N", "N", "up"]


def test_the_finest_gsd_of_each_landmark_over_its_captures() -> None:
    q = np.array([[0.0, 0.0, 2.0], [5.0, 0.0, 2.0], [9.0, 9.0, 9.0]])
    u = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
    pixel = 13.2 / 5472 / 8.8  # [rad/px]
    caps = [([4.0, 0.0, 2.0], [10, 20]), ([3.0, 3.0, 2.0], [10, 20]), ([0.0, 2.0, 2.0], [10])]
    got = best_gsd(caps, [10, 20, 30], q, u, pixel)

    def gsd(p: list[float], j: int) -> float:  # range × pixel / cos(incidence)
        d = np.asarray(p) - q[j]
        r = float(np.linalg.norm(d))
        return r * pixel / (float(d @ u[j]) / r)

    assert got[0] == pytest.approx(min(gsd([4.0, 0.0, 2.0], 0), gsd([3.0, 3.0, 2.0], 0)))
    # Landmark 20 faces +y: seen from (4, 0, 2) edge-on (infinite), from (3, 3, 2) at 45°.
    assert got[1] == pytest.approx(gsd([3.0, 3.0, 2.0], 1))
    assert np.isnan(got[2])


def test_groups_are_sorted_by_least_margin_and_count_what_is_left() -> None:
    u = np.array([[0, 0, 1], [0, 0, 1], [1, 0, 0], [1, 0, 0], [1, 0, 0]], dtype=float)
    part = np.array([0, 0, 0, 1, 1])
    captured = np.array([True, True, True, True, False])
    capturable = np.array([True, True, True, True, True])
    value = np.array([1.0, 1.5, 1.9, 0.5, np.nan])  # GSD [mm/px]
    rows = resolution_rows(part, u, captured, capturable, value, 2.0, gsd=True)
    assert [r.name for r in rows] == ["part 1, facing E", "part 1, facing up",
                                      "part 2, facing E"]
    first = rows[0]
    assert (first.landmarks, first.captured, first.left) == (1, 1, 0)
    assert first.margin == pytest.approx(1 - 1.9 / 2.0)
    last = rows[2]
    assert (last.landmarks, last.captured, last.left) == (2, 1, 1)
    assert last.worst == pytest.approx(0.5) and last.margin == pytest.approx(0.75)
    one = resolution_rows(None, u, captured, capturable, value, 2.0, gsd=True)
    assert [r.name for r in one] == ["facing E", "facing up"]
