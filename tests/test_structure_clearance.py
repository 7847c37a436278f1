"""agent.structure.clearance: closest points, avoidance obstacles and safe steps.

Known answers: the analytic distance to an axis-aligned box, trimesh's own closest-point
query as an independent reference, and hand-placed corners of the L-shaped building.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pytest
import trimesh

from agent.core.avoidance import safe_direction
from agent.core.viewpoints import Environment, feasible
from agent.structure.clearance import MeshClearance, _vertex_neighbours, closest_on_triangles
from agent.structure.examples import bridge, l_building
from agent.structure.model import StructureModel

HALF = np.array([1.0, 2.0, 3.0])

# trimesh's own queries, the independent references (trimesh leaves them unannotated, so
# calling them is an untyped call): bound here to the types their docstrings give.
#: Signed distances (m,) of points (m, 3) to a mesh, positive inside.
signed_distance: Callable[[trimesh.Trimesh, np.ndarray], np.ndarray]
signed_distance = trimesh.proximity.signed_distance
#: Closest points (m, 3) on triangles (m, 3, 3) to points (m, 3).
closest_point: Callable[[np.ndarray, np.ndarray], np.ndarray] = trimesh.triangles.closest_point


def box_signed_distance(p: np.ndarray) -> np.ndarray:
    """Exact signed distance to the box [−HALF, HALF] (negative inside)."""
    e = np.abs(p) - HALF
    outside = np.linalg.norm(np.maximum(e, 0.0), axis=1)
    inside = np.minimum(e.max(axis=1), 0.0)
    return np.asarray(outside + inside, dtype=np.float64)


def fine_box() -> trimesh.Trimesh:
    """The box [−HALF, HALF] split into many triangles (flat faces of several triangles)."""
    mesh = trimesh.creation.box(extents=2 * HALF)
    assert isinstance(mesh, trimesh.Trimesh)
    return mesh.subdivide().subdivide()


def test_closest_points_on_a_box_match_the_analytic_distance() -> None:
    mesh = fine_box()
    rng = np.random.default_rng(0)
    p = rng.uniform(-5, 5, (400, 3))
    res = MeshClearance(mesh).closest(p)
    assert res.distance == pytest.approx(box_signed_distance(p), abs=1e-12)
    outside = res.distance > 0
    assert np.allclose(res.point[outside], np.clip(p[outside], -HALF, HALF), atol=1e-12)
    assert np.allclose(np.linalg.norm(res.direction, axis=1), 1.0)
    # p = c + d·ŵ with the signed distance, inside and outside.
    assert np.allclose(res.point + res.distance[:, None] * res.direction, p, atol=1e-12)


def test_closest_points_match_trimesh_on_the_examples() -> None:
    rng = np.random.default_rng(1)
    for mesh in (l_building(), bridge()):
        p = rng.uniform(mesh.bounds[0] - 5, mesh.bounds[1] + 5, (300, 3))
        ref = signed_distance(mesh, p)  # positive inside
        assert MeshClearance(mesh).closest(p).distance == pytest.approx(-ref, abs=1e-9)


def test_closest_on_triangles_matches_trimesh() -> None:
    rng = np.random.default_rng(2)
    tri = rng.normal(size=(500, 3, 3))
    p = 3 * rng.normal(size=(500, 3))
    ref = closest_point(tri, p)
    assert np.allclose(closest_on_triangles(tri, p), ref, atol=1e-12)


def test_flat_wall_gives_one_obstacle_wherever_the_agent_is() -> None:
    clearance = MeshClearance(fine_box())
    rng = np.random.default_rng(3)
    for y, z, gap in rng.uniform([-1.9, -2.9, 0.05], [1.9, 2.9, 0.9], (20, 3)):
        w, d = clearance.obstacles([1.0 + gap, y, z], radius=1.0, margin=0.2)
        assert w == pytest.approx(np.array([[1.0, 0.0, 0.0]]))
        assert d.tolist() == pytest.approx([gap - 0.2])


def test_convex_corner_outside_is_one_diagonal_obstacle() -> None:
    w, d = MeshClearance(fine_box()).obstacles(HALF + 0.3, radius=1.0)
    assert w == pytest.approx(np.full((1, 3), 1 / np.sqrt(3)))
    assert d == pytest.approx([0.3 * np.sqrt(3)])


def test_inner_corner_of_the_l_gives_both_walls() -> None:
    clearance = MeshClearance(l_building())  # inner corner at (6, 6)
    w, d = clearance.obstacles([7.0, 6.5, 5.0], radius=2.0, margin=0.25)
    assert w == pytest.approx(np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0]]))
    assert d.tolist() == pytest.approx([0.25, 0.75])
    w, d = clearance.obstacles([7.0, 6.5, 5.0], radius=0.8)
    assert w == pytest.approx(np.array([[0.0, 1.0, 0.0]]))
    w, d = clearance.obstacles([15.0, 20.0, 5.0], radius=2.0)
    assert w.shape == (0, 3) and d.shape == (0,)


def test_obstacles_feed_smooth_avoidance() -> None:
    clearance = MeshClearance(l_building())
    p, d_w, margin = np.array([6.8, 6.6, 5.0]), 1.0, 0.3
    w, d = clearance.obstacles(p, radius=margin + d_w, margin=margin)
    lam = -np.maximum(d, 0.0) / d_w  # eq. 4.10
    p_opt = np.array([-1.0, -1.0, 0.2]) / np.linalg.norm([-1.0, -1.0, 0.2])  # into the corner
    x = safe_direction(p_opt, w, lam)
    assert np.linalg.norm(x) == pytest.approx(1.0)
    assert np.all(w @ x >= lam - 1e-9)
    assert float(x @ p_opt) >= 0.0


def test_max_step_stops_at_the_margin() -> None:
    clearance = MeshClearance(fine_box())
    p = np.array([6.0, 0.3, 0.2])
    alpha = clearance.max_step(p, [-1.0, 0.0, 0.0], margin=0.5, max_step=20.0, tol=1e-6)
    assert 4.5 - 1e-5 <= alpha <= 4.5  # wall at x = 1
    assert clearance.max_step(p, [0.0, 1.0, 0.0], margin=0.5, max_step=3.0) == 3.0
    rng = np.random.default_rng(4)
    for dvec in rng.normal(size=(20, 3)):  # whatever the direction, every step is safe
        a = clearance.max_step(p, dvec, margin=0.5, max_step=10.0)
        s = np.linspace(0.0, a, 50)[:, None] * (dvec / np.linalg.norm(dvec))
        assert clearance.closest(p + s).distance.min() >= 0.5 - 1e-9


def test_vertex_neighbours_match_brute_force() -> None:
    faces = np.asarray(l_building().subdivide().faces)
    ptr, ring = _vertex_neighbours(faces)
    share = (faces[:, None, :, None] == faces[None, :, None, :]).any(axis=(2, 3))
    for i in range(faces.shape[0]):  # loop over the 96 triangles of the test mesh
        assert sorted(ring[ptr[i]:ptr[i + 1]].tolist()) == np.flatnonzero(share[i]).tolist()


@pytest.mark.parametrize("mesh", [l_building(), bridge()], ids=["l_building", "bridge"])
def test_viewpoint_keepout_covers_the_structure_and_leaves_its_open_space(
        mesh: trimesh.Trimesh) -> None:
    """The voxel keep-out of a structure (StructureModel.keepout_boxes, inflated by the
    margin as candidate viewpoints are): every point closer than the margin to the surface
    or inside is kept out; points in the open space of a concave structure (the inner corner
    of the L, under the bridge deck), which its bounding box shuts out, are allowed."""
    margin = 1.5
    model = StructureModel(mesh, margin)
    env = Environment(np.full(3, -100.0), np.full(3, 100.0), model.keepout_boxes(), margin)
    lo, hi = mesh.bounds
    rng = np.random.default_rng(3)
    P = rng.uniform(lo - 3.0, hi + 3.0, size=(8000, 3))
    d = model.distance(P)
    assert not feasible(P[d < margin], env).any()  # (inside: negative distance)
    box = Environment(env.lo, env.hi, np.array([[lo, hi]]), margin)
    far = d > margin + 2.0 * np.sqrt(3.0) * margin  # beyond the voxels' reach
    assert feasible(P[far], env).all()
    opened = far & ~feasible(P, box)
    assert opened.sum() > 40  # open space the bounding box shuts out
