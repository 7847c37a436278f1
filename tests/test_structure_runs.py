"""Mesh structures over whole runs: no path crosses the structure, occlusion-aware visibility
and the refresh of the occlusion mask (agent.world.structure, agent.structure.model)."""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
import trimesh
from numpy.typing import NDArray

from agent.config.parse import load_scenario
from agent.config.scenario import Scenario
from agent.core.avoidance import AvoidanceMode
from agent.core.planner import PlannerParams, integrate, plan_step
from agent.core.vision import Landmarks, per_landmark
from agent.sim.kinematic import KinematicSim, simulate
from agent.sim.result import SimResult
from agent.structure.examples import tower
from agent.structure.model import OcclusionTracker, StructureModel, ball_exit
from agent.world.structure import resolve_structure, structure_inputs, structure_model

SCENARIOS = Path(__file__).resolve().parent.parent / "scenarios"
#: Every shipped scenario with a [structure] (the three examples at least), all inspection
#: missions; the three examples also as coverage missions (their [inspection] dropped: the
#: thesis' strategy flies them around the structure).
MESH_SCENARIOS = tuple(p.stem for p in sorted(SCENARIOS.glob("*.toml"))
                       if load_scenario(p).structure is not None
                       # the CAD house again, specified by a camera: tests/test_camera_spec.py
                       # and tests/test_multiview.py fly them
                       and p.stem not in ("inspect_house_camera", "inspect_house_views"))
COVERAGE = ("l_building", "bridge", "tower")
#: Sphere tracing stops within 1 mm of the margin (MeshClearance.max_step's tol).
TRACE_TOL = 1e-3


def _coverage(name: str) -> Scenario:
    """The shipped mesh scenario ``name`` as a coverage mission (its [inspection] dropped)."""
    return dataclasses.replace(resolve_structure(load_scenario(SCENARIOS / f"{name}.toml")),
                               inspection=None)


Run = Callable[[str], tuple[Scenario, SimResult]]


@pytest.fixture(scope="module")
def runs() -> Run:
    """Each mesh scenario as shipped (an inspection mission) or, named "NAME coverage", as a
    coverage mission: simulated once for the module, on first use (the selected tests only)."""

    @functools.cache
    def run(name: str) -> tuple[Scenario, SimResult]:
        base = name.removesuffix(" coverage")
        sc = _coverage(base) if name != base else \
            resolve_structure(load_scenario(SCENARIOS / f"{name}.toml"))
        return sc, simulate(sc)

    return run


#: Shipped inspections test_inspection_sim.py flies tick by tick with the same checks (its
#: _fly: no segment crosses the mesh, the margin kept): in make test there, here in test-long.
FLOWN_THERE = ("l_building", "inspect_u_building", "inspect_storage_tank",
               "inspect_gabled_house", "inspect_house_parts", "inspect_u_boxes",
               "inspect_chimney_plant", "inspect_wind_turbine")


def test_the_example_meshes_are_shipped() -> None:
    assert set(COVERAGE) <= set(MESH_SCENARIOS)
    from agent.structure.examples import example_structures
    from agent.structure.mesh import load_mesh

    for name, mesh in example_structures().items():  # the files are what the script writes
        stored = load_mesh(SCENARIOS / "meshes" / f"{name}.stl",
                           require_watertight=name != "scan_house")  # a scan: open
        np.testing.assert_allclose(_triangle_set(stored), _triangle_set(mesh), atol=1e-4)


def _triangle_set(mesh: trimesh.Trimesh) -> NDArray[np.float64]:
    """The mesh's triangles as sorted unique rows of 9 coordinates (each triangle's corners
    sorted: loading re-winds a scan's wrongly wound ones), rounded to 0.1 mm."""
    tri = np.round(np.asarray(mesh.triangles, dtype=np.float64), 4)
    corners = np.sort(tri.view([("", tri.dtype)] * 3).reshape(tri.shape[0], 3), axis=1)
    return np.unique(corners.view(tri.dtype).reshape(-1, 9), axis=0)


def _segments(result: SimResult) -> tuple[np.ndarray, np.ndarray]:
    """Every segment of every agent's path: starts (k, 3) and ends (k, 3) [m]."""
    pos = result.positions  # (T, n, 3)
    return pos[:-1].reshape(-1, 3), pos[1:].reshape(-1, 3)


@pytest.mark.parametrize("name", [
    *(pytest.param(n, marks=pytest.mark.long) if n in FLOWN_THERE else n
      for n in MESH_SCENARIOS),
    *(f"{n} coverage" for n in COVERAGE)])
def test_no_path_crosses_the_structure(runs: Run, name: str) -> None:
    """Each segment of each path, checked against the mesh by a ray cast, crosses no
    triangle; every recorded position keeps the margin (up to the sphere-tracing tolerance)."""
    sc, result = runs(name)
    assert sc.structure is not None
    model = structure_model(sc.structure)
    a, b = _segments(result)
    moved = np.linalg.norm(b - a, axis=1) > 0.0
    assert moved.sum() > 50  # the agents did fly
    assert model.segments_clear(a, b).all()
    assert model.segments_clear(b, a).all()  # both directions (a ray may start on a face)
    dist = model.distance(result.positions.reshape(-1, 3))
    assert dist.min() >= sc.structure.margin - TRACE_TOL, dist.min()


@pytest.mark.parametrize("name", [f"{n} coverage" for n in COVERAGE])
def test_coverage_under_both_models(runs: Run, name: str) -> None:
    """Occlusion can only remove landmarks: its coverage is ≤ the facing one at every tick;
    the recorded coverage is the occlusion one (the scenarios' model) and it grows."""
    sc, result = runs(name)
    by = result.coverage_by_model
    assert by is not None and by.shape == (result.times.size, 2)
    assert sc.visibility == result.visibility == "occlusion"
    assert np.all(by[:, 1] <= by[:, 0] + 1e-9)
    np.testing.assert_allclose(result.coverage, by[:, 1], rtol=1e-12, atol=1e-12)
    assert result.coverage[-1] > result.coverage[0]
    assert result.complete
    assert "occlusion" in result.coverage_line() and "facing" in result.coverage_line()


def _pulled_through(use_structure: bool, mode: AvoidanceMode = "smooth", steps: int = 400
                    ) -> tuple[StructureModel, np.ndarray]:
    """One camera east of a tower (radius 3 m) and one landmark on the tower's far (west)
    side whose normal points east, at the camera: its vision alone pulls the camera to
    d_opt = 6 m in front of it, x = 2.5 m, inside the tower. Returns the path (T, 3)."""
    model = StructureModel(tower(height=10.0), margin=1.0)
    q = np.array([[-3.5, 0.0, 5.0]])
    u = np.array([[1.0, 0.0, 0.0]])
    lm = Landmarks.of(q, u)
    params = PlannerParams(dt=0.1, p_lim=1.5, p_min=0.01, avoidance=mode, d_w=1.0)
    p, v = np.array([12.0, 0.3, 5.0]), np.array([-1.0, 0.0, 0.0])
    prev = np.zeros(3)
    path = [p]
    for _ in range(steps):
        obstacles = model.obstacles(p, params.d_w) if use_structure else None
        reach = model.reach if use_structure else None
        step = plan_step(p, v, lm, None, 6.0, params, None, None, prev, obstacles=obstacles,
                         reach=reach)
        if step.converged:
            break
        p, v = integrate(p, v, step.p_dot, step.omega, params.dt)
        prev = step.p_dir
        path.append(p)
    return model, np.array(path)


@pytest.mark.parametrize("mode", ["smooth", "abrupt", "none"])
def test_structure_obstacle_stops_a_camera_pulled_through_it(mode: AvoidanceMode) -> None:
    """Without the structure as an obstacle the camera flies into the tower (the control:
    the test can fail); with it no segment crosses the mesh and the margin holds, in every
    avoidance mode (in "none" the reach bound alone stops it)."""
    model, free = _pulled_through(use_structure=False, mode=mode)
    assert not model.segments_clear(free[:-1], free[1:]).all()
    model, safe = _pulled_through(use_structure=True, mode=mode)
    assert model.segments_clear(safe[:-1], safe[1:]).all()
    assert model.distance(safe).min() >= 1.0 - TRACE_TOL
    assert safe[-1, 0] < 5.0  # it did come close, stopped by the margin (x ≥ 4)


def test_scenario_without_structure_plans_as_before() -> None:
    """No mesh: no planner inputs, so plan_step is called exactly as without this feature."""
    sc = load_scenario(SCENARIOS / "cube_6_2.toml")
    inputs = structure_inputs(sc)
    assert inputs.model is None and inputs.tracker is None
    lm = Landmarks.of(sc.q, sc.u)
    assert inputs.planner_inputs(sc.agents[0].p0, lm) == {}
    sim = KinematicSim(sc)
    assert sim.sc is sc and sim.coverage_by_model() is None


def test_occlusion_run_plans_over_unoccluded_landmarks_only() -> None:
    """In an occlusion run, the planner's mask hides exactly the landmarks a fresh ray cast
    hides from the camera position of the last cast."""
    sc = _coverage("l_building")
    sim = KinematicSim(sc)
    for _ in range(5):
        sim.tick()
    inputs = sim.inputs[0]
    assert inputs.tracker is not None and inputs.tracker.casts >= 1
    origin = inputs.tracker.cache.origin
    assert origin is not None
    mine = sim.owner == 0
    expected = inputs.model.unoccluded(origin, sc.q[mine], sc.u[mine]) if inputs.model else None
    mask = inputs.tracker.mask(origin, sc.q[mine], sc.u[mine])
    np.testing.assert_array_equal(mask, expected)


def test_tracker_recasts_at_the_ball_and_bounds_steps() -> None:
    model = StructureModel(tower(height=10.0), margin=1.0)
    tracker = OcclusionTracker(model, refresh=0.5)
    q = np.array([[3.0, 0.0, 5.0], [-3.0, 0.0, 5.0]])
    u = np.array([[1.0, 0.0, 0.0], [-1.0, 0.0, 0.0]])
    p = np.array([10.0, 0.0, 5.0])
    np.testing.assert_array_equal(tracker.mask(p, q, u), [True, False])
    east = np.array([-1.0, 0.0, 0.0])
    assert tracker.reach(p, east, 2.0) == pytest.approx(0.5)  # the refresh ball bounds it
    tracker.mask(p + 0.3 * east, q, u)
    assert tracker.casts == 1  # inside the ball: cached
    tracker.mask(p + 0.5 * east, q, u)
    assert tracker.casts == 2  # on the ball's surface: recast
    assert (tracker.used, tracker.lost) == (1, 0)  # the visible landmark stayed visible
    assert ball_exit(p, east, p, 0.5) == pytest.approx(0.5)
    assert ball_exit(p + np.array([1.0, 0.0, 0.0]), east, p, 0.5) == 0.0
    # Near the tower the clearance bounds the step instead: 4 m from the axis → 0 m left.
    near = np.array([4.0, 0.0, 5.0])
    tracker.mask(near, q, u)
    assert tracker.reach(near, east, 2.0) == pytest.approx(0.0, abs=TRACE_TOL)


def test_occlusion_vision_counts_only_unoccluded_landmarks() -> None:
    """The recorded vision of an occlusion run is the facing vision minus the occluded
    landmarks' terms, with a fresh cast at the recorded pose."""
    sc = _coverage("bridge")
    sim = KinematicSim(sc)
    for _ in range(20):
        sim.tick()
    model = sim.inputs[0].model
    assert model is not None
    for i, a in enumerate(sim.agents):
        mine = sim.owner == i
        each = per_landmark(a.p, a.v, sc.q[mine], sc.u[mine], sc.d_opt)
        clear = model.unoccluded(a.p, sc.q[mine], sc.u[mine])
        assert sim.visions()[i] == pytest.approx(float(each[clear].sum()))


def test_agent_runtime_plans_around_the_structure(tmp_path: Path) -> None:
    """The same inputs reach the planner of the process runtime (AgentRuntime._plan_once):
    a whole in-memory mission around the tower, no path segment crosses the mesh."""
    from agent.testing.memsim import MemoryMission

    sc = _coverage("tower")
    assert sc.structure is not None
    model = structure_model(sc.structure)
    mission = MemoryMission(sc, tmp_path)
    try:
        path = [np.array([rt.pose.current()[0] for rt in mission.agents.values()])]
        for _ in range(300):
            mission.step()
            path.append(np.array([rt.pose.current()[0] for rt in mission.agents.values()]))
            if mission.complete:
                break
        runtimes = list(mission.agents.values())
        trackers = [rt.core.planning.structure.tracker for rt in runtimes]
        assert all(t is not None and t.casts > 0 for t in trackers)
    finally:
        mission.close()
    pos = np.array(path)  # (T, n, 3)
    a, b = pos[:-1].reshape(-1, 3), pos[1:].reshape(-1, 3)
    assert (np.linalg.norm(b - a, axis=1) > 0).sum() > 20
    assert model.segments_clear(a, b).all()
    assert model.distance(pos.reshape(-1, 3)).min() >= sc.structure.margin - TRACE_TOL
