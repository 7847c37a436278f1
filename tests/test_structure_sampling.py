"""agent.structure.sampling: even landmarks on the surface with outward normals.

Independent checks: trimesh's closest-point query (points on the surface), trimesh's
ray-based inside test (normals outward), a KD-tree over the landmarks and a dense uniform
sample of the surface (spacing and coverage).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pytest
import trimesh
from scipy.spatial import cKDTree

from agent.structure.examples import bridge, l_building, tower
from agent.structure.sampling import (
    CONFLICT_COS,
    maximal_independent_set,
    outward_face_normals,
    sample_landmarks,
)

MESHES: dict[str, Callable[[], trimesh.Trimesh]] = {
    "l_building": l_building, "bridge": bridge, "tower": tower}
#: a mesh, the landmark spacing [m], and the landmarks sampled on it (q, u)
Sampled = tuple[trimesh.Trimesh, float, np.ndarray, np.ndarray]
#: trimesh's closest-point query: closest points (m, 3), distances (m,), triangle ids (m,).
#: trimesh leaves it unannotated (calling it is an untyped call): bound here to the types
#: its docstring gives.
closest_point: Callable[[trimesh.Trimesh, np.ndarray], tuple[np.ndarray, np.ndarray, np.ndarray]]
closest_point = trimesh.proximity.closest_point


@pytest.fixture(scope="module", params=sorted(MESHES))
def sampled(request: pytest.FixtureRequest) -> Sampled:
    mesh = MESHES[request.param]()
    spacing = 0.8
    q, u = sample_landmarks(mesh, spacing, seed=7)
    return mesh, spacing, q, u


def test_points_on_surface_and_unit_normals(sampled: Sampled) -> None:
    mesh, _, q, u = sampled
    assert q.shape == u.shape and q.shape[0] > 100
    _, dist, _ = closest_point(mesh, q)
    assert dist.max() <= 1e-9
    assert np.abs(np.linalg.norm(u, axis=1) - 1.0).max() < 1e-12


def test_normals_point_outward(sampled: Sampled) -> None:
    mesh, _, q, u = sampled
    assert not mesh.contains(q + 0.01 * u).any()
    assert mesh.contains(q - 0.01 * u).all()


def test_spacing_and_coverage(sampled: Sampled) -> None:
    mesh, spacing, q, u = sampled
    pairs = cKDTree(q).query_pairs(spacing * (1 - 1e-12), output_type="ndarray")
    same_side = (u[pairs[:, 0]] * u[pairs[:, 1]]).sum(axis=1) > CONFLICT_COS
    assert not same_side.any()  # no two same-side landmarks closer than the spacing
    dense, _ = trimesh.sample.sample_surface(mesh, 100_000, seed=11)
    gap, _ = cKDTree(q).query(dense)
    assert gap.max() <= 1.5 * spacing
    # Density of a Poisson-disk set: between 0.4 and 1.155 (hexagonal packing) per spacing².
    per_area = q.shape[0] * spacing**2 / mesh.area
    assert 0.4 < per_area < 1.155


def test_deterministic_with_seed() -> None:
    mesh = l_building()
    a = sample_landmarks(mesh, 1.0, seed=3)
    b = sample_landmarks(mesh, 1.0, seed=3)
    c = sample_landmarks(mesh, 1.0, seed=4)
    assert np.array_equal(a[0], b[0]) and np.array_equal(a[1], b[1])
    assert a[0].shape != c[0].shape or not np.array_equal(a[0], c[0])


def test_inverted_mesh_still_gets_outward_normals() -> None:
    mesh = l_building()
    flipped = mesh.copy()
    flipped.invert()
    assert flipped.volume < 0
    assert np.allclose(outward_face_normals(flipped), mesh.face_normals)
    q, u = sample_landmarks(flipped, 1.0, seed=1)
    assert not mesh.contains(q + 0.01 * u).any()


def test_both_sides_of_a_thin_deck() -> None:
    plate = trimesh.creation.box(extents=(10.0, 10.0, 0.1))
    _, u = sample_landmarks(plate, 1.0, seed=5)
    top, bottom = (u[:, 2] > 0.5).sum(), (u[:, 2] < -0.5).sum()
    assert top > 40 and bottom > 40
    assert abs(int(top) - int(bottom)) < 0.25 * top


def test_filters_ground_region_and_downward_normals() -> None:
    mesh = bridge()
    q, u = sample_landmarks(mesh, 0.7, seed=2, z_min=1.0)
    assert q.shape[0] > 50 and q[:, 2].min() >= 1.0
    lo, hi = np.array([5.0, -10.0, -1.0]), np.array([19.0, 10.0, 20.0])
    q, u = sample_landmarks(mesh, 0.7, seed=2, region=(lo, hi))
    assert q.shape[0] > 50 and np.all((q >= lo) & (q <= hi))
    # Only the deck is inside that box: its underside (normal −z) is sampled.
    assert (u[:, 2] < -0.99).sum() > 20
    q, u = sample_landmarks(mesh, 0.7, seed=2, min_normal_z=-0.5)
    assert q.shape[0] > 50 and u[:, 2].min() >= -0.5
    assert (u[:, 2] > 0.99).sum() > 20  # the deck's top is kept


def test_filters_that_leave_nothing() -> None:
    q, u = sample_landmarks(tower(), 1.0, z_min=100.0)
    assert q.shape == (0, 3) and u.shape == (0, 3)


def test_bad_arguments() -> None:
    with pytest.raises(ValueError, match=r"^spacing must be a positive finite distance \[m\], "
                                         r"got 0\.0$"):
        sample_landmarks(tower(), 0.0)
    with pytest.raises(ValueError, match=r"^region must be \(lo, hi\)"):
        sample_landmarks(tower(), 1.0, region=((1, 1, 1), (0, 0, 0)))


def test_maximal_independent_set_on_a_path() -> None:
    n = 50
    edges = np.column_stack([np.arange(n - 1), np.arange(1, n)]).astype(np.intp)
    pick = maximal_independent_set(n, edges, np.random.default_rng(0))
    chosen = np.zeros(n, dtype=bool)
    chosen[pick] = True
    assert not (chosen[edges[:, 0]] & chosen[edges[:, 1]]).any()  # independent
    covered = chosen.copy()
    covered[edges[:, 0][chosen[edges[:, 1]]]] = True
    covered[edges[:, 1][chosen[edges[:, 0]]]] = True
    assert covered.all()  # maximal: every node is chosen or next to a chosen one
