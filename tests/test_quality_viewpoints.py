"""Candidate viewpoints: the vision matrix, refinement and the joint selection."""

from __future__ import annotations

import numpy as np

from agent.core.landmarks import box_faces, cylinder
from agent.core.viewpoints import (
    Environment,
    best_view_owner,
    best_viewpoint,
    feasible,
    refine_team,
    refine_viewpoints,
    seed_viewpoints,
    select_viewpoints,
    vision_matrix,
)
from agent.core.vision import per_landmark

ENV = Environment(np.array([-8.0, -8.0, 0.3]), np.array([8.0, 8.0, 7.0]),
                  np.array([[[-2.0, -1.5, 0.0], [2.0, 1.5, 3.0]]]), 0.3, 1.0)


def _box() -> tuple[np.ndarray, np.ndarray]:
    return box_faces([0.0, 0.0, 1.5], [4.0, 3.0, 3.0], ["+x", "-x", "+y", "-y", "+z"], (2, 2))


def test_vision_matrix_matches_per_landmark_vision() -> None:
    q, u = _box()
    rng = np.random.default_rng(0)
    P = rng.uniform(-6, 6, size=(7, 3))
    V = rng.normal(size=(7, 3))
    V /= np.linalg.norm(V, axis=1)[:, None]
    M = vision_matrix(P, V, q, u, 2.0)
    for k in range(7):
        assert np.allclose(M[k], per_landmark(P[k], V[k], q, u, 2.0))


def test_seeds_look_at_the_landmarks_and_refinement_never_loses() -> None:
    q, u = cylinder([0.0, 0.0, 0.0], 1.0, 4.0, 10, 2)
    P, V = seed_viewpoints(q, u, 2.0)
    assert P.shape == V.shape and P.shape[0] > q.shape[0]
    assert np.allclose(np.linalg.norm(V, axis=1), 1.0)
    ok = feasible(P, ENV)
    P, V = P[ok], V[ok]
    before = vision_matrix(P, V, q, u, 2.0).sum(axis=1)
    P2, V2, val = refine_viewpoints(P, V, q, u, 2.0, env=ENV)
    assert np.all(val >= before - 1e-12)
    assert np.allclose(val, vision_matrix(P2, V2, q, u, 2.0).sum(axis=1))
    assert feasible(P2, ENV).all()


def test_selection_keeps_safety_radius_and_best_view_owner() -> None:
    q, u = _box()
    P, V = seed_viewpoints(q, u, 2.0)
    ok = feasible(P, ENV)
    P, V = P[ok], V[ok]
    M = vision_matrix(P, V, q, u, 2.0)
    chosen, value = select_viewpoints(M, P, 4, 1.0)
    assert chosen.size == 4
    d = np.linalg.norm(P[chosen][:, None] - P[chosen][None], axis=2) + np.eye(4) * 9
    assert d.min() >= 1.0
    assert value == np.maximum.reduce(M[chosen]).sum()
    Pt, Vt, owner, val = refine_team(P[chosen], V[chosen], q, u, 2.0, ENV)
    assert val >= value - 1e-9
    assert np.array_equal(owner, best_view_owner(vision_matrix(Pt, Vt, q, u, 2.0), owner))


def test_best_viewpoint_sees_a_whole_face_from_outside() -> None:
    q, u = box_faces([0.0, 0.0, 1.5], [4.0, 3.0, 3.0], ["+x"], (3, 3))
    p, v, val = best_viewpoint(q, u, 2.0, ENV)
    assert p[0] > 2.3 and v[0] < -0.9  # in front of the +x face, looking back at it
    assert val > 0.7 * q.shape[0]


def test_cluster_partition_gives_every_agent_a_face_group() -> None:
    from agent.core.coverage_moves import cluster_partition

    q, u = _box()
    starts = np.array([[6.0, 0.0, 1.5], [-6.0, 0.0, 1.5], [0.0, 6.0, 1.5], [0.0, -6.0, 1.5]])
    owner, gp, gv = cluster_partition(q, u, starts, ENV, 2.0)
    assert owner.shape == (q.shape[0],) and set(owner.tolist()) == {0, 1, 2, 3}
    assert feasible(gp, ENV).all() and np.allclose(np.linalg.norm(gv, axis=1), 1.0)
    # The agent starting in front of +x is sent to the +x side.
    assert gp[0, 0] > 2.0
