"""Structure benchmarks: occlusion refresh, closest points and landmark sampling on meshes.

- ``occlusion_refresh``: one :meth:`OcclusionCaster.unoccluded` call (one batched ray query)
  for m landmarks on the L-shaped building, per mesh size (the building subdivided into more
  triangles) and ray backend: ``embree`` (package embreex) and ``triangle`` (trimesh's
  numpy/rtree caster). The triangle backend is timed only while landmarks × triangles
  ≤ 7·10⁶ (it needs seconds and gigabytes beyond that), so not on the largest meshes.
- ``closest_point``: :meth:`MeshClearance.closest` for one position 2 m from the wall, and
  ``closest_point_trimesh``: trimesh.proximity.closest_point for the same position (baseline).
- ``structure_obstacles``: :meth:`MeshClearance.obstacles` at the inner corner (radius 1.5 m).
- ``max_step_to_structure``: :meth:`MeshClearance.max_step` towards a wall 5 m away.
- ``sample_landmarks``: Poisson-disk sampling of the building at two spacings.

Run: ``python -m bench.bench_occlusion``.
"""

from __future__ import annotations

import json
import statistics
import sys
import time
from collections.abc import Callable
from typing import Any, TextIO

import numpy as np
import trimesh

from agent.structure.clearance import MeshClearance
from agent.structure.examples import l_building
from agent.structure.occlusion import OcclusionCaster, embree_available
from agent.structure.sampling import sample_landmarks
from bench.timing import time_calls

LANDMARKS = (1_000, 10_000, 100_000)
SUBDIVISIONS = (0, 2, 4, 6)  # 24, 384, 6,144 and 98,304 triangles
CAMERA = np.array([30.0, -10.0, 8.0])  # south-east of the building, both wings in view
TRIANGLE_MAX_WORK = 7_000_000  #: landmarks × triangles timed with the triangle backend


def _emit(out: TextIO, records: list[dict[str, Any]], rec: dict[str, Any]) -> None:
    records.append(rec)
    out.write(json.dumps(rec) + "\n")
    out.flush()


def _building(subdivisions: int) -> trimesh.Trimesh:
    """The L-shaped building with every triangle split in four ``subdivisions`` times."""
    mesh = l_building()
    for _ in range(subdivisions):
        mesh = mesh.subdivide()
    return mesh


def _landmarks(mesh: trimesh.Trimesh, m: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """m uniform surface points with their face normals (sampling itself is not timed here)."""
    q, face = trimesh.sample.sample_surface(mesh, m, seed=seed)
    return np.asarray(q), np.asarray(mesh.face_normals[face])


def _occlusion(out: TextIO, records: list[dict[str, Any]]) -> None:
    backends = ["embree", "triangle"] if embree_available() else ["triangle"]
    for sub in SUBDIVISIONS:
        mesh = _building(sub)
        q_all, u_all = _landmarks(mesh, max(LANDMARKS))
        for backend in backends:
            if backend == "triangle" and min(LANDMARKS) * len(mesh.faces) > TRIANGLE_MAX_WORK:
                continue
            t0 = time.perf_counter()
            caster = OcclusionCaster(mesh, backend)
            caster.unoccluded(CAMERA, q_all[:10], u_all[:10])  # builds the ray structure
            build = time.perf_counter() - t0
            for m in LANDMARKS:
                if backend == "triangle" and m * len(mesh.faces) > TRIANGLE_MAX_WORK:
                    continue
                q, u = q_all[:m], u_all[:m]
                reps = max(1, min(20, 20_000 // m)) if backend == "embree" else \
                    max(1, min(5, 2_000 // m))
                mask = caster.unoccluded(CAMERA, q, u)
                times = time_calls(lambda c=caster, q=q, u=u: c.unoccluded(CAMERA, q, u), reps)
                _emit(out, records, {
                    "bench": "occlusion_refresh", "backend": backend, "faces": len(mesh.faces),
                    "m": m, "median_s": statistics.median(times), "reps": reps,
                    "build_s": build, "unoccluded_fraction": float(mask.mean())})


def _clearance(out: TextIO, records: list[dict[str, Any]]) -> None:
    near_wall = np.array([12.0, -2.0, 5.0])  # 2 m south of the long wing
    corner = np.array([6.8, 6.6, 5.0])  # inside the L's inner corner
    for sub in SUBDIVISIONS:
        mesh = _building(sub)
        t0 = time.perf_counter()
        clearance = MeshClearance(mesh)
        build = time.perf_counter() - t0
        faces = len(mesh.faces)
        cases: list[tuple[str, Callable[[], Any], int]] = [
            ("closest_point", lambda c=clearance: c.closest(near_wall), 200),
            ("closest_point_trimesh",
             lambda m=mesh: trimesh.proximity.closest_point(m, near_wall[None, :]), 50),
            ("structure_obstacles", lambda c=clearance: c.obstacles(corner, 1.5, 0.3), 200),
            ("max_step_to_structure",
             lambda c=clearance: c.max_step([12.0, -5.0, 5.0], [0.0, 1.0, 0.0], 0.5, 20.0), 50),
        ]
        for name, fn, reps in cases:
            fn()
            times = time_calls(fn, reps)
            _emit(out, records, {"bench": name, "faces": faces, "build_s": build,
                                 "median_s": statistics.median(times), "reps": reps})


def _sampling(out: TextIO, records: list[dict[str, Any]]) -> None:
    mesh = l_building()
    for spacing in (0.8, 0.25):
        t0 = time.perf_counter()
        q, _ = sample_landmarks(mesh, spacing, seed=0)
        _emit(out, records, {"bench": "sample_landmarks", "faces": len(mesh.faces),
                             "spacing_m": spacing, "m": int(q.shape[0]),
                             "median_s": time.perf_counter() - t0, "reps": 1})


def run(out: TextIO | None = None) -> list[dict[str, Any]]:
    """Run every structure benchmark; print and return JSON records (one per line)."""
    out = out or sys.stdout
    records: list[dict[str, Any]] = []
    _occlusion(out, records)
    _clearance(out, records)
    _sampling(out, records)
    return records


if __name__ == "__main__":
    run()
