"""The centralised reference and the seeded scenes of the coverage-quality benchmark."""

from __future__ import annotations

import io
import json

import numpy as np
import pytest

from agent.core.viewpoints import feasible, vision_matrix
from bench.quality.reference import reference
from bench.quality.runs import run_thesis
from bench.quality.structures import KINDS, R_S, make_scene, make_structure


@pytest.mark.parametrize("kind", KINDS)
def test_scenes_are_seeded_and_starts_are_valid(kind: str) -> None:
    a, b = make_scene(kind, "heldout", 1, 6, 3), make_scene(kind, "heldout", 1, 6, 3)
    assert np.array_equal(a.p0, b.p0) and np.array_equal(a.owner0, b.owner0)
    env = a.structure.environment()
    assert feasible(a.p0, env).all()  # in the space, outside the structure
    d = np.linalg.norm(a.p0[:, None] - a.p0[None], axis=2) + np.eye(6) * 1e9
    assert d.min() >= R_S
    assert np.allclose(np.linalg.norm(a.v0, axis=1), 1.0)
    assert a.owner0.min() >= 0 and a.owner0.max() < 6
    a.scenario()  # builds a kinematic-simulator scenario


def test_tuning_and_heldout_structures_differ() -> None:
    for kind in KINDS:
        t, h = make_structure(kind, "tuning", 0), make_structure(kind, "heldout", 0)
        assert t.q.shape != h.q.shape or not np.allclose(t.q, h.q)


@pytest.mark.parametrize(("kind", "n", "start"), [("box", 3, 0), ("pier", 2, 1),
                                                  ("lshape", 4, 2)])
def test_reference_is_at_least_the_thesis_score(kind: str, n: int, start: int) -> None:
    scene = make_scene(kind, "tuning", 0, n, start)
    ref = reference(scene.structure, n, scene.d_opt)
    thesis = run_thesis(scene)
    assert ref.score >= thesis.score - 1e-9
    # The reported score is the best-view score of the reported poses, which are feasible.
    s = scene.structure
    assert ref.score == pytest.approx(
        vision_matrix(ref.P, ref.V, s.q, s.u, scene.d_opt).max(axis=0).sum())
    assert feasible(ref.P, s.environment()).all()


def test_quick_bench_prints_json_lines() -> None:
    from bench.bench_quality import run

    out = io.StringIO()
    run(out, quick=True, kinds=("pier",))
    recs = [json.loads(line) for line in out.getvalue().splitlines()]
    cells = [r for r in recs if r["bench"] == "coverage_quality"]
    assert {r["strategy"] for r in cells} == {"thesis", "potential"}
    assert all(0.0 <= r["worst_ratio"] <= r["mean_ratio"] for r in cells)
