"""Captures (agent.core.inspection): the quality of eq. 3.1 with a field of view and an
incidence limit, the probe poses, the uncapturable reasons, the grow-only captured set."""

from __future__ import annotations

import math
import random

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from agent.core.inspection import (
    CaptureSpec,
    camera_axes,
    capture_quality,
    probe_poses,
    probe_quality,
    uncapturable_reasons,
)
from agent.core.viewpoints import vision_matrix
from agent.protocol.captures import CapturedSet
from tests.reference import Array


def _random_scene(rng: np.random.Generator, K: int = 7, m: int = 40
                  ) -> tuple[Array, Array, Array, Array]:
    P = rng.normal(size=(K, 3)) * 3.0
    V = rng.normal(size=(K, 3))
    V /= np.linalg.norm(V, axis=1, keepdims=True)
    q = rng.normal(size=(m, 3)) * 3.0
    u = rng.normal(size=(m, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    return P, V, q, u


def test_without_limits_the_quality_is_the_vision_matrix_of_eq_3_8() -> None:
    P, V, q, u = _random_scene(np.random.default_rng(0))
    got = capture_quality(P, V, q, u, 1.5, CaptureSpec(0.3))
    assert np.array_equal(got, vision_matrix(P, V, q, u, 1.5))


def test_head_on_at_d_opt_is_one_and_the_quality_is_f_times_both_cosines() -> None:
    q = np.array([[0.0, 0.0, 0.0]])
    u = np.array([[1.0, 0.0, 0.0]])
    got = capture_quality(np.array([[2.0, 0.0, 0.0]]), np.array([[-1.0, 0.0, 0.0]]), q, u, 2.0,
                          CaptureSpec())
    assert got[0, 0] == pytest.approx(1.0)
    # From 3 m, 30° off the normal, camera axis 20° off the line of sight (in the plane).
    r, beta, alpha = 3.0, math.radians(30), math.radians(20)
    p = r * np.array([math.cos(beta), math.sin(beta), 0.0])
    los = -p / r
    c, s = math.cos(alpha), math.sin(alpha)
    v = np.array([c * los[0] - s * los[1], s * los[0] + c * los[1], 0.0])
    f = (r / 2.0) * math.exp(1 - r / 2.0)
    got = capture_quality(p[None], v[None], q, u, 2.0, CaptureSpec())[0, 0]
    assert got == pytest.approx(f * math.cos(alpha) * math.cos(beta), rel=1e-12)


def test_the_field_of_view_bounds_horizontal_and_vertical_angles_separately() -> None:
    # Camera at the origin looking along +x; landmarks facing it at 35° and 45° to the side
    # and 25° and 40° up; fov 80° × 60° (half-angles 40° and 30°).
    ang = np.radians([35.0, 45.0])
    side = np.stack([np.cos(ang), np.sin(ang), np.zeros(2)], axis=1) * 2.0
    el = np.radians([25.0, 40.0])
    up = np.stack([np.cos(el), np.zeros(2), np.sin(el)], axis=1) * 2.0
    q = np.vstack([side, up])
    u = -q / np.linalg.norm(q, axis=1, keepdims=True)
    spec = CaptureSpec(0.01, fov=(math.radians(80), math.radians(60)))
    got = capture_quality(np.zeros((1, 3)), np.array([[1.0, 0.0, 0.0]]), q, u, 2.0, spec)[0]
    assert (got > 0).tolist() == [True, False, True, False]


def test_the_incidence_limit_drops_grazing_views() -> None:
    q = np.zeros((2, 3))
    u = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 1.0]])
    p = np.array([[2.0 * math.sin(math.radians(60)), 0.0, 2.0 * math.cos(math.radians(60))]])
    v = -p / np.linalg.norm(p)
    spec = CaptureSpec(0.01, max_incidence=math.radians(55))
    assert not capture_quality(p, v, q[:1], u[:1], 2.0, spec).any()
    spec = CaptureSpec(0.01, max_incidence=math.radians(65))
    assert capture_quality(p, v, q[:1], u[:1], 2.0, spec)[0, 0] > 0


def test_camera_axes_are_orthonormal_with_a_horizontal_right_axis() -> None:
    rng = np.random.default_rng(3)
    V = rng.normal(size=(50, 3))
    V /= np.linalg.norm(V, axis=1, keepdims=True)
    V[0] = [0.0, 0.0, -1.0]  # straight down: no yaw, a fixed right axis
    right, up = camera_axes(V)
    for a, b in ((right, up), (right, V), (up, V)):
        assert np.allclose((a * b).sum(axis=1), 0.0, atol=1e-12)
    assert np.allclose(np.linalg.norm(right, axis=1), 1.0)
    assert np.allclose(np.linalg.norm(up, axis=1), 1.0)
    assert np.allclose(right[:, 2], 0.0)


def test_probe_poses_look_at_their_landmark_and_reach_the_quality() -> None:
    rng = np.random.default_rng(4)
    _, _, q, u = _random_scene(rng, m=30)
    spec = CaptureSpec(0.3, max_incidence=math.radians(60))
    P, V = probe_poses(q, u, 2.0, spec)
    to_lm = q[:, None, :] - P
    to_lm /= np.linalg.norm(to_lm, axis=2, keepdims=True)
    assert np.allclose((to_lm * V).sum(axis=2), 1.0)
    cos_inc = (-(to_lm) * u[:, None, :]).sum(axis=2)
    assert (cos_inc >= math.cos(math.radians(60)) - 1e-9).all()
    pq = probe_quality(P, V, q, u, 2.0, spec)
    assert np.allclose(pq[:, 0], 1.0)  # head-on at d_opt
    # The same numbers as the full matrix for each landmark's own probes.
    full = capture_quality(P[3], V[3], q, u, 2.0, spec)[:, 3]
    assert np.allclose(full, pq[3])


def test_uncapturable_reasons_name_the_first_filter_that_left_no_pose() -> None:
    good = np.array([[1, 1], [1, 1], [1, 1], [1, 0], [0, 1]], dtype=bool)
    inside = np.array([[0, 0], [1, 0], [1, 1], [1, 1], [1, 0]], dtype=bool)
    clear = np.array([[1, 1], [0, 1], [1, 1], [1, 1], [1, 1]], dtype=bool)
    sight = np.array([[1, 1], [1, 1], [0, 0], [1, 0], [1, 1]], dtype=bool)
    assert uncapturable_reasons(good, inside, clear, sight).tolist() == [1, 2, 3, 0, 1]


@given(st.lists(st.lists(st.integers(0, 30), max_size=8), max_size=6),
       st.randoms(use_true_random=False))
@settings(max_examples=200, deadline=None)
def test_the_captured_set_is_a_grow_only_union_whatever_the_order(batches: list[list[int]],
                                                                  rnd: random.Random) -> None:
    a, b = CapturedSet(), CapturedSet()
    seen: set[int] = set()
    sizes = []
    for batch in batches:
        new = a.merge(batch)
        assert new == sorted(set(batch) - seen)
        seen |= set(batch)
        sizes.append(len(a))
    shuffled = [list(x) for x in batches] * 2  # duplicated and reordered delivery
    rnd.shuffle(shuffled)
    for batch in shuffled:
        b.merge(batch)
    assert a.ids() == b.ids() == sorted(seen)
    assert sizes == sorted(sizes)  # never shrinks
    ids = np.arange(31, dtype=np.int64)
    assert np.flatnonzero(a.mask(ids)).tolist() == sorted(seen)
