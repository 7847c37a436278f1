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
- ``planner_step_occlusion``: every step of a pose optimisation beside the building with m
  landmarks on its surface, each step timed whole: the occlusion mask (recast after
  :data:`REFRESH` m, else cached), the building's obstacle rows, and ``plan_step`` with the
  mask and the reach bound; max over all steps, and the medians of casting / cached steps.
  On a shared, loaded machine run it with ``OPENBLAS_NUM_THREADS=1`` (recorded in the row):
  multi-threaded BLAS dot products then cost milliseconds each instead of microseconds.
- ``occlusion_staleness``: how many facing landmarks change occlusion state when the camera
  moves δ m (the measurement behind :data:`REFRESH`).
- ``coverage_by_visibility``: each shipped mesh scenario run with visibility "facing" and
  "occlusion"; final coverage under both models; for occlusion runs also, over all recasts
  the refresh distance triggered, the landmarks the planner was using (``recast_used``) and
  those the new cast found hidden (``recast_lost``: how stale the trusted set got).

Run: ``python -m bench.bench_occlusion``.
"""

from __future__ import annotations

import dataclasses
import json
import os
import statistics
import sys
import time
from collections.abc import Callable
from functools import partial
from pathlib import Path
from typing import Any, Literal, TextIO

import numpy as np
import trimesh

from agent.config.parse import load_scenario
from agent.core.avoidance import MissionSpace
from agent.core.planner import PlannerParams, integrate, plan_step
from agent.core.vision import Landmarks, unit
from agent.sim.kinematic import KinematicSim, simulate
from agent.structure.clearance import MeshClearance
from agent.structure.examples import l_building
from agent.structure.model import OcclusionTracker, StructureModel
from agent.structure.occlusion import OcclusionCaster, embree_available
from agent.structure.sampling import sample_landmarks
from agent.world.structure import resolve_structure
from bench.timing import time_calls

LANDMARKS = (1_000, 10_000, 100_000)
SUBDIVISIONS = (0, 2, 4, 6)  # 24, 384, 6,144 and 98,304 triangles
CAMERA = np.array([30.0, -10.0, 8.0])  # south-east of the building, both wings in view
TRIANGLE_MAX_WORK = 7_000_000  #: landmarks × triangles timed with the triangle backend
#: Occlusion recast distance [m] used by the shipped scenarios (see occlusion_staleness).
REFRESH = 0.5
PLANNER_STEPS = 120  #: longest pose optimisation timed per case
MESH_SCENARIOS = ("l_building", "bridge", "tower")


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
    backends: list[Literal["embree", "triangle"]] = \
        ["embree", "triangle"] if embree_available() else ["triangle"]
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
                times = time_calls(partial(caster.unoccluded, CAMERA, q, u), reps)
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
            ("closest_point", partial(clearance.closest, near_wall), 200),
            ("closest_point_trimesh",
             partial(trimesh.proximity.closest_point, mesh, near_wall[None, :]), 50),
            ("structure_obstacles", partial(clearance.obstacles, corner, 1.5, 0.3), 200),
            ("max_step_to_structure", partial(clearance.max_step, np.array([12.0, -5.0, 5.0]),
                                              np.array([0.0, 1.0, 0.0]), 0.5, 20.0), 50),
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


def _planner_occlusion(out: TextIO, records: list[dict[str, Any]]) -> None:
    params = PlannerParams(dt=0.1, p_lim=1.5, p_min=0.05, avoidance="smooth", r_s=2.0, d_w=1.0)
    space = MissionSpace(np.array([-8.0, -8.0, 0.5]), np.array([28.0, 20.0, 16.0]))
    for sub in (0, 4):
        mesh = _building(sub)
        model = StructureModel(mesh, margin=1.5)
        q_all, u_all = _landmarks(mesh, max(LANDMARKS))
        model.unoccluded(CAMERA, q_all[:10], u_all[:10])  # builds the ray structure (untimed)
        for m in LANDMARKS:
            q, u = q_all[:m], u_all[:m]
            lm = Landmarks.of(q, u)
            tracker = OcclusionTracker(model, REFRESH)
            p = np.array([26.0, -4.0, 8.0])  # south-east of the building, 2 m off the wall
            v, prev = unit(np.array([8.0, 4.0, 4.0]) - p), np.zeros(3)
            cast_steps, cached_steps, fractions = [], [], []
            for _ in range(PLANNER_STEPS):
                casts = tracker.casts
                t0 = time.perf_counter()
                mask = tracker.mask(p, q, u)
                step = plan_step(p, v, lm, None, 6.0, params, space, None, prev,
                                 unoccluded=mask, obstacles=model.obstacles(p, params.d_w),
                                 reach=tracker.reach)
                took = time.perf_counter() - t0
                if tracker.casts > casts:
                    cast_steps.append(took)
                    fractions.append(float(mask.mean()))
                else:
                    cached_steps.append(took)
                if step.converged:
                    break
                p, v = integrate(p, v, step.p_dot, step.omega, params.dt)
                prev = step.p_dir
            every = cast_steps + cached_steps
            _emit(out, records, {
                "bench": "planner_step_occlusion", "faces": len(mesh.faces), "m": m,
                "refresh_m": REFRESH, "steps": len(every), "casts": len(cast_steps),
                "blas_threads": os.environ.get("OPENBLAS_NUM_THREADS", "default"),
                "median_s": statistics.median(every), "p90_s": float(np.percentile(every, 90)),
                "max_s": max(every), "median_cast_step_s": statistics.median(cast_steps),
                "median_cached_step_s": statistics.median(cached_steps) if cached_steps
                else None, "unoccluded_fraction": statistics.median(fractions)})


def _staleness(out: TextIO, records: list[dict[str, Any]]) -> None:
    """Fraction of facing landmarks whose occlusion flips after a move of δ [m]."""
    mesh = l_building()
    model = StructureModel(mesh, margin=1.5)
    q, u = _landmarks(mesh, 10_000)
    rng = np.random.default_rng(0)
    starts: list[np.ndarray] = []
    while len(starts) < 30:  # camera positions 2-8 m from the building, above the ground
        p = rng.uniform([-8.0, -8.0, 1.0], [28.0, 20.0, 14.0])
        if 2.0 <= float(model.distance(p)[0]) <= 8.0:
            starts.append(p)
    for delta in (0.1, 0.25, 0.5, 1.0, 2.0):
        flips = []
        for p in starts:
            d = unit(rng.normal(size=3))
            facing = ((p - q) * u).sum(axis=1) > 0.0
            a = model.unoccluded(p, q[facing], u[facing])
            b = model.unoccluded(p + delta * d, q[facing], u[facing])
            flips.append(float((a != b).mean()))
        _emit(out, records, {"bench": "occlusion_staleness", "m": 10_000, "move_m": delta,
                             "changed_fraction_median": statistics.median(flips),
                             "changed_fraction_max": max(flips), "poses": len(starts)})


def _coverage(out: TextIO, records: list[dict[str, Any]]) -> None:
    root = Path(__file__).resolve().parent.parent / "scenarios"
    for name in MESH_SCENARIOS:
        base = dataclasses.replace(resolve_structure(load_scenario(root / f"{name}.toml")),
                                   inspection=None)  # the structure's coverage mission
        for vis in ("facing", "occlusion"):
            t0 = time.perf_counter()
            result = simulate(dataclasses.replace(base, visibility=vis))
            by = result.coverage_by_model
            assert by is not None
            used = lost = 0
            if vis == "occlusion":  # rerun step by step to read the trackers' staleness
                sim = KinematicSim(dataclasses.replace(base, visibility=vis))
                for _ in range(result.times.size - 1):
                    sim.tick()
                trackers = [i.tracker for i in sim.inputs if i.tracker is not None]
                used, lost = sum(t.used for t in trackers), sum(t.lost for t in trackers)
            _emit(out, records, {
                "bench": "coverage_by_visibility", "scenario": name, "visibility": vis,
                "m": len(result.landmark_ids), "agents": len(result.agent_ids),
                "initial_facing": float(by[0, 0]), "initial_occlusion": float(by[0, 1]),
                "final_facing": float(by[-1, 0]), "final_occlusion": float(by[-1, 1]),
                "trades": len(result.trades), "complete": result.complete,
                "t_complete": result.t_complete, "wall_s": time.perf_counter() - t0,
                "recast_used": used, "recast_lost": lost})


def run(out: TextIO | None = None) -> list[dict[str, Any]]:
    """Run every structure benchmark; print and return JSON records (one per line)."""
    out = out or sys.stdout
    records: list[dict[str, Any]] = []
    _occlusion(out, records)
    _clearance(out, records)
    _sampling(out, records)
    _planner_occlusion(out, records)
    _staleness(out, records)
    _coverage(out, records)
    return records


if __name__ == "__main__":
    run()
