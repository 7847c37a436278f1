"""The capture table built cell by cell within capture range (agent/structure/inspection.py)
against the dense algorithm it replaced, kept here as the reference: every (candidate,
landmark) pair tested by :func:`agent.core.inspection.capture_quality`, candidates kept by
the signed distance of one closest-point query each. Same viewpoints, same captures, same
reasons; the summed qualities within rounding. Also: the vectorised margin test against
the closest-point distances, the capture ball against sampled poses, and the capture matrix
by rows against the dense one."""

from __future__ import annotations

import math

import numpy as np
import pytest
from numpy.typing import NDArray

from agent.config.parse import load_scenario, parse_scenario
from agent.config.scenario import Scenario
from agent.core.capture_rows import CaptureRows
from agent.core.inspection import (
    CaptureSpec,
    CaptureTable,
    capture_lobe,
    capture_quality,
    capture_range,
    inspection_candidates,
    probe_poses,
    seed_rows,
)
from agent.core.viewpoints import seed_viewpoints
from agent.structure.inspection import _reasons, capture_table
from agent.structure.model import StructureModel
from agent.structure.sight_lines import sight_lines
from agent.world.structure import resolve_structure, structure_model
from tests.conftest import scenario_path

Array = NDArray[np.float64]
Mask = NDArray[np.bool_]


# -- the reference: the dense algorithm ---------------------------------------------------------


def _ref_clear_of(model: StructureModel | None, P: Array) -> Mask:
    if model is None or P.shape[0] == 0:
        return np.ones(P.shape[0], dtype=np.bool_)
    ok = model.distance(P) >= model.margin  # one closest-point query per position
    ok[ok] = model.solid.reachable(P[ok])
    return np.asarray(ok, dtype=np.bool_)


def _ref_captures(P: Array, V: Array, q: Array, u: Array, d_opt: float, spec: CaptureSpec,
                  lo: Array, hi: Array, model: StructureModel | None,
                  caster: StructureModel | None, seen: Mask, axis: Array | None,
                  cos_cone: float | None) -> tuple[Array, Array, Mask, Array]:
    keep = np.all((P >= lo) & (P <= hi), axis=-1)
    keep[keep] = _ref_clear_of(model, P[keep])
    P, V = P[keep], V[keep]
    Q = capture_quality(P, V, q, u, d_opt, spec, axis, cos_cone)  # (K, m) dense
    good: Mask = (Q >= spec.threshold) & seen[None, :]
    pairs = np.nonzero(good)
    good[pairs] = sight_lines(caster, P, q, u, pairs)
    return P, V, good, np.where(good, Q, 0.0).sum(axis=1)


def reference_table(q: Array, u: Array, d_opt: float, spec: CaptureSpec, lo: Array,
                    hi: Array, model: StructureModel | None, occlusion: bool,
                    axis: Array | None = None, cos_cone: float | None = None,
                    seeds: int | None = None) -> CaptureTable:
    """The capture table as it was built before (dense K x m)."""
    caster = model if occlusion else None
    reason = np.zeros(q.shape[0], dtype=np.int8) if model is None else model.hidden(q, u)
    seen = reason == 0
    rows = seed_rows(q.shape[0]) if seeds is None else seed_rows(q.shape[0], seeds)
    seeds_ = rows[seen[rows]]
    sub = None if axis is None else axis[seeds_]
    P, V, good, value = _ref_captures(*inspection_candidates(
        q[seeds_], u[seeds_], d_opt, spec, sub, cos_cone),
        q, u, d_opt, spec, lo, hi, model, caster, seen, axis, cos_cone)
    missing = np.flatnonzero(~good.any(axis=0) & seen)
    if missing.size:
        PP, VV = probe_poses(q[missing], u[missing], d_opt, spec,
                             None if axis is None else axis[missing], cos_cone)
        P2, V2, good2, value2 = _ref_captures(PP.reshape(-1, 3), VV.reshape(-1, 3), q, u,
                                              d_opt, spec, lo, hi, model, caster, seen, axis,
                                              cos_cone)
        P, V = np.vstack([P, P2]), np.vstack([V, V2])
        good, value = np.vstack([good, good2]), np.concatenate([value, value2])
        found = np.asarray(good2.any(axis=0), dtype=np.bool_)
        left = missing[~found[missing]]
        if left.size:  # (the old code crashed here when every missed one was found)
            reason[left] = _reasons(q, u, left, d_opt, spec, lo, hi, model, caster, axis,
                                    cos_cone)
    useful = good.any(axis=1)
    return CaptureTable(P[useful], V[useful], good[useful], value[useful], reason)


def _both(sc: Scenario, seeds: int | None = None) -> tuple[CaptureTable, CaptureTable]:
    assert sc.inspection is not None
    model = None if sc.structure is None else structure_model(sc.structure)
    args = (sc.q, sc.u, sc.d_opt, sc.inspection, sc.space.lo, sc.space.hi, model,
            sc.visibility == "occlusion", sc.view_axis, sc.view_cos)
    return capture_table(*args), reference_table(*args, seeds=seeds)


def _assert_same(new: CaptureTable, ref: CaptureTable) -> None:
    assert np.array_equal(new.P, ref.P) and np.array_equal(new.V, ref.V)
    assert np.array_equal(new.C, ref.C)
    assert np.array_equal(new.reason, ref.reason)
    np.testing.assert_allclose(new.value, ref.value, rtol=1e-12, atol=0.0)
    assert [a.tolist() for a in new.capturers] == [
        a.tolist() for a in CaptureRows.from_dense(ref.C).columns()]


# -- the tests ----------------------------------------------------------------------------------


@pytest.mark.parametrize("name", ["inspect_house_parts", "inspect_house_camera",
                                  "inspect_chimney_plant"])
def test_the_table_is_the_dense_algorithms(name: str) -> None:
    """Occlusion, buried faces, a cavity, a camera's GSD and incidence limits."""
    new, ref = _both(resolve_structure(load_scenario(scenario_path(name))))
    assert new.rows.nnz > 0 and (new.reason != 0).any() == (ref.reason != 0).any()
    _assert_same(new, ref)


def test_the_table_is_the_dense_algorithms_with_view_sectors() -> None:
    sc = resolve_structure(load_scenario(scenario_path("inspect_house_views")))
    assert sc.view_axis is not None
    _assert_same(*_both(sc))


def test_the_table_is_the_dense_algorithms_without_a_structure_and_with_uncapturable() -> None:
    """Facing model, no mesh: a box's faces, the bottom face against the floor (reason 1)."""
    text = """name = "box_inspection"
dims = 3
d_opt = 1.5
duration = 10.0
[space]
lo = [-5.0, -5.0, 0.0]
hi = [5.0, 5.0, 5.0]
[[generators]]
kind = "box"
center = [0.0, 0.0, 1.0]
size = 2.0
grid = [4, 4]
[inspection]
quality = 0.4
fov_deg = [80.0, 60.0]
max_incidence_deg = 70.0
[[agents]]
id = "A"
position = [-4.0, -4.0, 1.0]
"""
    sc = parse_scenario(text.replace('id = "A"', 'id = "A"\nlandmarks = ['
                                     + ", ".join(str(i) for i in range(1, 97)) + "]"))
    new, ref = _both(sc)
    assert (new.reason == 1).sum() == 16  # the -z face: every pose under the floor
    _assert_same(new, ref)


def test_the_margin_test_is_the_closest_point_distance() -> None:
    """:meth:`StructureModel.reachable` (one bulk box query) against one closest-point query
    per position, on positions around and inside the structure."""
    sc = load_scenario(scenario_path("inspect_house_parts"))
    assert sc.structure is not None
    model = structure_model(sc.structure)
    rng = np.random.default_rng(3)
    lo, hi = model.mesh.bounds
    P = rng.uniform(lo - 3.0, hi + 3.0, (3000, 3))
    d = model.distance(P)
    near = np.abs(d - model.margin) < 0.05  # and some right at the margin
    assert near.any()
    assert np.array_equal(model.reachable(P), _ref_clear_of(model, P))


def test_the_capture_ball_holds_every_capture() -> None:
    """Random cameras and landmarks: every pair eq. 3.1 passes lies in the ball of
    :func:`capture_lobe` (the field of view's, the quality's, and a GSD's range)."""
    rng = np.random.default_rng(5)
    for spec in (CaptureSpec(0.3), CaptureSpec(0.2, fov=(math.radians(90), math.radians(70)),
                                                max_incidence=math.radians(75))):
        P = rng.normal(size=(300, 3)) * 3.0
        V = rng.normal(size=(300, 3))
        V /= np.linalg.norm(V, axis=1, keepdims=True)
        q = rng.normal(size=(400, 3)) * 6.0
        u = rng.normal(size=(400, 3))
        u /= np.linalg.norm(u, axis=1, keepdims=True)
        Q = capture_quality(P, V, q, u, 2.0, spec)
        c, rho = capture_lobe(2.0, spec)
        k, j = np.nonzero(Q >= spec.threshold)
        assert k.size > 50
        assert (np.linalg.norm(q[j] - (P[k] + c * V[k]), axis=1) <= rho).all()
        assert rho < capture_range(2.0, spec.threshold)  # tighter than the range alone


def test_capture_rows_answer_as_the_dense_matrix() -> None:
    rng = np.random.default_rng(9)
    C = rng.random((50, 70)) < 0.1
    C[:, 3] = False
    rows = CaptureRows.from_dense(C)
    assert rows.shape == C.shape and rows.nnz == int(C.sum())
    assert np.array_equal(rows.dense(), C)
    assert all(np.array_equal(rows.row(k), C[k]) for k in range(50))
    pick = rng.random(50) < 0.3
    assert np.array_equal(rows.any_of(pick), C[pick].any(axis=0))
    _, k = np.nonzero(C.T)
    indptr, by_col = rows.columns()
    assert by_col.tolist() == k.tolist()
    assert np.array_equal(np.diff(indptr), C.sum(axis=0))
    table = CaptureTable(np.zeros((50, 3)), np.zeros((50, 3)), rows, np.zeros(50),
                         np.zeros(70, dtype=np.int8))
    assert np.array_equal(table.C, C)
    with pytest.raises(ValueError, match="does not match"):
        CaptureTable(np.zeros((49, 3)), np.zeros((49, 3)), rows, np.zeros(49),
                     np.zeros(70, dtype=np.int8))


def test_few_seeds_stay_the_dense_algorithms(monkeypatch: pytest.MonkeyPatch) -> None:
    """Seeds a small subset (as past MAX_SEEDS landmarks): most landmarks are then captured
    from the probe poses of those the seeds' candidates miss."""
    import agent.structure.inspection as built

    monkeypatch.setattr(built, "seed_rows", lambda m: seed_rows(m, 12))
    sc = resolve_structure(load_scenario(scenario_path("inspect_gabled_house")))
    new, ref = _both(sc, seeds=12)
    assert new.P.shape[0] > 12 * 75  # probe poses of missed landmarks among them
    _assert_same(new, ref)


@pytest.mark.parametrize("m", [1, 399, 400, 401, 1_000, 9_999, 10_000, 10_001, 123_457])
def test_seeds_are_the_old_ones_up_to_ten_thousand_landmarks_and_keep_up_after(m: int) -> None:
    """Up to MAX_SEEDS · LANDMARKS_PER_SEED landmarks the seeds are the old rule's (so the
    table is the old one); past that they include them, plus every 25th row."""
    old = np.arange(m) if m <= 400 else np.unique(np.linspace(0, m - 1, 400).round())
    rows = seed_rows(m)
    if m <= 10_000:
        assert rows.tolist() == old.astype(int).tolist()
    else:
        assert set(old.astype(int).tolist()) <= set(rows.tolist())
        assert rows.size >= m // 25 and (np.diff(rows) > 0).all()


def test_seed_viewpoints_by_blocks_are_the_whole_matrices() -> None:
    """Past MAX_SEEDS seeds their groups are formed a block of rows at a time (memory
    O(block·m), the k nearest by a partial sort): the same poses as the whole (m, m)
    matrices, within rounding, when no two distances tie."""
    rng = np.random.default_rng(2)
    q = rng.normal(size=(700, 3)) * 5.0
    u = rng.normal(size=(700, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    P, V = seed_viewpoints(q, u, 2.0)
    Pb, Vb = seed_viewpoints(q, u, 2.0, block=128)
    assert P.shape == Pb.shape
    np.testing.assert_allclose(Pb, P, rtol=0.0, atol=1e-9)
    np.testing.assert_allclose(Vb, V, rtol=0.0, atol=1e-12)
