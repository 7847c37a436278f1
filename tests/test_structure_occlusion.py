"""agent.structure.occlusion: segment camera → landmark against the structure.

Hand-built cases with known answers, and a brute-force segment/triangle test
(Möller–Trumbore over every ray × triangle pair) as an independent reference.
"""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from numpy.typing import NDArray

from agent.structure.examples import bridge, l_building
from agent.structure.occlusion import (
    TARGET_LIFT,
    Backend,
    OcclusionCache,
    OcclusionCaster,
    embree_available,
    unoccluded,
)
from agent.structure.sampling import sample_landmarks

BACKENDS: list[Backend] = ["embree", "triangle"]


def segments_clear_reference(tri: np.ndarray, a: np.ndarray, b: np.ndarray) -> NDArray[np.bool_]:
    """Brute force: no triangle crosses segment a_i → b_i (Möller–Trumbore, float64)."""
    d = (b - a)[:, None, :]  # (n, 1, 3)
    v0, e1, e2 = tri[None, :, 0], (tri[:, 1] - tri[:, 0])[None], (tri[:, 2] - tri[:, 0])[None]
    h = np.cross(d, e2)
    det = (e1 * h).sum(axis=2)
    ok = np.abs(det) > 1e-14
    inv = 1.0 / np.where(ok, det, 1.0)
    s = a[:, None, :] - v0
    bu = (s * h).sum(axis=2) * inv
    qv = np.cross(s, e1)
    bv = (d * qv).sum(axis=2) * inv
    t = (e2 * qv).sum(axis=2) * inv
    hit = ok & (bu >= 0) & (bv >= 0) & (bu + bv <= 1) & (t > 0) & (t < 1)
    return np.asarray(~hit.any(axis=1), dtype=np.bool_)


def test_embree_is_installed() -> None:
    assert embree_available()  # the fast backend is part of the project's dependencies


@pytest.mark.parametrize("backend", BACKENDS)
def test_wall_between_camera_and_landmark(backend: Backend) -> None:
    target = trimesh.creation.box(extents=(1.0, 4.0, 4.0))
    target.apply_translation([10.5, 0.0, 0.0])  # face x = 10, normal −x, towards the camera
    wall = trimesh.creation.box(extents=(0.2, 4.0, 4.0))
    wall.apply_translation([5.0, 0.0, 0.0])
    q, u = np.array([[10.0, 0.0, 0.0], [10.0, 1.5, 1.5]]), np.array([[-1.0, 0, 0]] * 2)
    p = np.zeros(3)
    assert OcclusionCaster(target, backend).unoccluded(p, q, u).tolist() == [True, True]
    both = trimesh.util.concatenate([target, wall])
    assert isinstance(both, trimesh.Trimesh)
    assert OcclusionCaster(both, backend).unoccluded(p, q, u).tolist() == [False, False]
    # Seen from beside the wall (y = 6), the line of sight passes the wall's edge (y = 2).
    assert OcclusionCaster(both, backend).unoccluded([0.0, 6.0, 0.0], q, u).tolist() == [
        True, True]


@pytest.mark.parametrize("backend", BACKENDS)
def test_far_wing_of_an_l_hidden_by_the_near_wing(backend: Backend) -> None:
    mesh = l_building()  # long wing [0,20]×[0,6], short wing [0,6]×[6,12], height 10
    q = np.array([[6.0, 9.0, 5.0]])  # east face of the short wing
    u = np.array([[1.0, 0.0, 0.0]])
    caster = OcclusionCaster(mesh, backend)
    # From the east, straight on: nothing in between.
    assert caster.unoccluded([30.0, 9.0, 5.0], q, u).tolist() == [True]
    # From the south-east the landmark still faces the camera (⟨p − q, u⟩ > 0) but the
    # long wing stands in between.
    p = np.array([25.0, -5.0, 5.0])
    assert float((p - q[0]) @ u[0]) > 0
    assert caster.unoccluded(p, q, u).tolist() == [False]
    # Above the roof the line of sight clears the long wing (z = 10 at x ≤ 20).
    assert caster.unoccluded([25.0, -5.0, 40.0], q, u).tolist() == [True]


@pytest.mark.parametrize("backend", BACKENDS)
def test_own_surface_hides_only_landmarks_facing_away(backend: Backend) -> None:
    mesh = trimesh.creation.box(extents=(2.0, 2.0, 2.0))
    q = np.array([[1.0, 0.3, -0.2], [-1.0, 0.3, -0.2], [0.2, 1.0, 0.9]])
    u = np.array([[1.0, 0, 0], [-1.0, 0, 0], [0, 1.0, 0]])
    caster = OcclusionCaster(mesh, backend)
    assert caster.unoccluded([5.0, 0.0, 0.0], q, u).tolist() == [True, False, False]
    # Grazing but in front of the face: still visible.
    assert caster.unoccluded([1.5, 8.0, 0.95], q, u).tolist() == [True, False, True]


@pytest.mark.parametrize("backend", BACKENDS)
def test_matches_brute_force_reference(backend: Backend) -> None:
    mesh = bridge()
    q, u = sample_landmarks(mesh, 1.5, seed=1)
    rng = np.random.default_rng(5)
    cams = rng.uniform([-10, -12, 0.5], [34, 12, 15], (6, 3))
    cams = cams[~mesh.contains(cams)]
    got = OcclusionCaster(mesh, backend).unoccluded(cams, q, u)
    target = q + TARGET_LIFT * u
    ref = np.stack([segments_clear_reference(mesh.triangles, np.broadcast_to(c, q.shape),
                                             target) for c in cams])
    assert got.shape == ref.shape == (cams.shape[0], q.shape[0])
    assert 0.1 < ref.mean() < 0.9  # a mix of seen and hidden
    assert (got != ref).mean() <= 1e-3  # single-precision Embree may differ at exact edges


def test_batched_cameras_match_single_calls() -> None:
    mesh = l_building()
    q, u = sample_landmarks(mesh, 2.0, seed=3)
    cams = np.array([[30.0, 9.0, 5.0], [25.0, -5.0, 5.0], [-8.0, 20.0, 12.0]])
    caster = OcclusionCaster(mesh)
    batch = caster.unoccluded(cams, q, u)
    for i, c in enumerate(cams):  # loop over three cameras
        assert np.array_equal(batch[i], caster.unoccluded(c, q, u))
    assert np.array_equal(unoccluded(mesh, cams[0], q, u), batch[0])


def test_cache_recasts_only_when_stale() -> None:
    mesh = l_building()
    q, u = sample_landmarks(mesh, 2.0, seed=3)
    cache = OcclusionCache(OcclusionCaster(mesh), refresh_distance=0.5)
    p = np.array([30.0, 9.0, 5.0])
    near, far = np.array([0.3, 0.0, 0.3]), np.array([0.4, 0.0, 0.4])  # 0.42 m and 0.57 m
    assert cache.needs_refresh(p, q, u)
    first = cache.mask(p, q, u)
    assert cache.casts == 1 and not cache.needs_refresh(p + near, q, u)
    assert np.array_equal(cache.mask(p + near, q, u), first)
    assert cache.casts == 1
    assert cache.needs_refresh(p + far, q, u)
    cache.mask(p + far, q, u)
    assert cache.casts == 2
    assert cache.needs_refresh(p + far, q[:-1], u[:-1])  # landmark set changed
    assert cache.mask(p + far, q[:-1], u[:-1]).shape == (q.shape[0] - 1,)
    assert cache.casts == 3


def test_bad_arguments() -> None:
    mesh = l_building()
    with pytest.raises(ValueError, match=r"^unknown ray backend 'gpu'; use 'auto', 'embree' "
                                         r"or 'triangle'$"):
        OcclusionCaster(mesh, "gpu")  # type: ignore[arg-type]  # a wrong backend, refused
    with pytest.raises(ValueError, match=r"^lift must be a positive distance \[m\], got 0\.0$"):
        OcclusionCaster(mesh, lift=0.0)
    with pytest.raises(ValueError, match=r"^q and u must have the same shape"):
        OcclusionCaster(mesh).unoccluded(np.zeros(3), np.zeros((2, 3)), np.zeros((3, 3)))
    with pytest.raises(ValueError, match=r"^refresh_distance must be a finite distance"):
        OcclusionCache(OcclusionCaster(mesh), refresh_distance=-1.0)


def test_facing_only_cast_is_facing_and_unoccluded() -> None:
    """unoccluded_facing = (⟨p − q, u⟩ > 0) ∧ unoccluded, with rays cast for the facing ones
    only; on a closed mesh the two masks agree (own surface hides the others)."""
    mesh = l_building()
    q, u = sample_landmarks(mesh, 0.8, seed=2)
    caster = OcclusionCaster(mesh)
    for p in (np.array([30.0, -10.0, 8.0]), np.array([8.0, 9.0, 12.0]),
              np.array([-3.0, 5.0, 2.0])):
        facing = np.einsum("ij,ij->i", p - q, u) > 0.0
        full = caster.unoccluded(p, q, u)
        np.testing.assert_array_equal(caster.unoccluded_facing(p, q, u), facing & full)
        np.testing.assert_array_equal(full & ~facing, np.zeros_like(full))
    cache = OcclusionCache(caster, refresh_distance=0.5, facing_only=True)
    p = np.array([30.0, -10.0, 8.0])
    np.testing.assert_array_equal(cache.mask(p, q, u), caster.unoccluded_facing(p, q, u))
    assert cache.origin is not None and cache.casts == 1
    cache.invalidate()
    cache.mask(p, q, u)
    assert cache.casts == 2
