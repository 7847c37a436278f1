"""Inspection missions in the simulator (agent.sim.inspection): everything capturable is
captured, every capture holds when re-checked from its logged pose with independent maths
(bench.inspection.recheck: trimesh's own ray caster), the captured set only grows, the
drones keep the structure's margin, and what cannot be captured is named with its reason."""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

import numpy as np
import pytest
import trimesh

from agent.cli import main
from agent.config.parse import load_scenario, parse_scenario
from agent.sim.inspection import InspectionSim
from agent.sim.kinematic import simulate
from agent.structure.examples import box, house_parts, tower
from agent.structure.solid import BURIED
from agent.world.structure import resolve_structure
from bench.inspection.recheck import false_captures, logged, spec_angles
from tests.conftest import ROOT, scenario_path


def _fly(name: str) -> InspectionSim:
    """The shipped scenario ``name`` flown to its end, checking every tick: the captured set
    only grows, every position is inside the space and keeps the structure's margin, and no
    path crosses the structure (each segment ray-cast both ways against the mesh, as
    tests/test_structure_runs.py does for every shipped structure)."""
    sc = resolve_structure(load_scenario(scenario_path(name)))
    sim = InspectionSim(sc)
    sizes = [int(sim.cap.sum())]
    clearance: list[float] = []
    path = [sim.positions().copy()]
    while not sim.done and sim.t < sc.duration:
        sim.tick()
        sizes.append(int(sim.cap.sum()))
        assert sim.model is not None
        clearance.append(float(sim.model.distance(sim.positions()).min()))
        assert np.all(sim.positions() >= sc.space.lo - 1e-9)
        assert np.all(sim.positions() <= sc.space.hi + 1e-9)
        path.append(sim.positions().copy())
    assert sizes == sorted(sizes), "the captured set shrank"
    # Section 4.3 keeps the margin up to the sphere-tracing tolerance (1 mm).
    assert sim.model is not None
    assert min(clearance) >= sim.model.margin - 2e-3
    pos = np.array(path)  # (T, n, 3)
    a, b = pos[:-1].reshape(-1, 3), pos[1:].reshape(-1, 3)
    assert (np.linalg.norm(b - a, axis=1) > 0.0).sum() > 50  # the agents did fly
    assert sim.model.segments_clear(a, b).all() and sim.model.segments_clear(b, a).all()
    assert sim.model.distance(pos.reshape(-1, 3)).min() >= sim.model.margin - 1e-3
    return sim


def _recheck(sim: InspectionSim) -> int:
    spec = sim.spec
    fov, inc = spec_angles(spec)
    caps = logged(sim.captures)
    assert sim.model is not None
    return false_captures(sim.model.mesh, caps, list(sim.sc.landmark_ids), sim.sc.q,
                          sim.sc.u, sim.sc.d_opt, spec.quality, fov, inc)


@pytest.mark.parametrize("name", ["l_building", "inspect_u_building",
                                  "inspect_storage_tank", "inspect_gabled_house"])
def test_every_landmark_of_a_shipped_structure_is_captured_and_every_capture_holds(name: str
                                                                                  ) -> None:
    sim = _fly(name)
    assert sim.complete
    assert sim.table.capturable.all()
    assert sim.cap.all()
    ids = [lid for c in sim.captures for lid in c.landmarks]
    assert sorted(ids) == sorted(sim.sc.landmark_ids)  # each captured exactly once
    assert all(q >= sim.spec.quality for c in sim.captures for q in c.quality)
    assert _recheck(sim) == 0


def _parts(name: str) -> list[trimesh.Trimesh]:
    """The closed parts of a CAD-like assembly, each alone (built again here)."""
    if name == "inspect_house_parts":
        house = house_parts()
        return [box((0, 0, 0), (14, 8, 5)),
                trimesh.Trimesh(vertices=house.vertices, faces=house.faces[12:])]
    if name == "inspect_u_boxes":
        return [box((0, 0, 0), (20, 6, 9)), box((0, 5, 0), (6, 16, 9)),
                box((14, 5, 0), (20, 16, 9))]
    disc = tower(3.0, 0.4, sections=24)
    disc.apply_translation((0.0, 0.0, 16.0))
    return [tower(1.5, 24.0, sections=24), disc, box((1.0, -3.0, 0.0), (9.0, 3.0, 6.0))]


@pytest.mark.parametrize("name", ["inspect_house_parts", "inspect_u_boxes",
                                  "inspect_chimney_plant"])
def test_an_assembly_of_touching_and_overlapping_parts_completes(name: str) -> None:
    """CAD-like assemblies: the faces inside another part (by ray parity on each closed
    part alone) are exactly the ones named buried; everything else is captured, each
    capture holds, and the mission completes."""
    sim = _fly(name)
    lifted = sim.sc.q + 1e-3 * sim.sc.u
    buried = np.any([p.contains(lifted) for p in _parts(name)], axis=0)
    assert buried.sum() >= 3
    assert (sim.table.reason == np.where(buried, BURIED, 0)).all()
    assert sim.complete and (sim.cap == ~buried).all()
    assert _recheck(sim) == 0


def test_the_coverage_mission_of_the_same_building_leaves_landmarks_unseen() -> None:
    """The thesis' coverage of l_building sees a part of it; the inspection all of it."""
    result = simulate(dataclasses.replace(load_scenario(scenario_path("l_building")),
                                          inspection=None))
    assert result.inspection is None and result.captures == []
    assert int((~result.seen_by_owner()).sum()) >= 20


def test_inside_the_nacelle_is_uncapturable_and_everything_else_is_captured() -> None:
    sim = _fly("inspect_wind_turbine")
    q, eps = sim.sc.q, 1e-6
    # Faces inside the other body: in the nacelle box (x in [-1, 5], |y| <= 1.5, z in
    # [22, 25]) or in the mast (24 facets round a radius of 1.5 m, z in [0, 24]).
    in_box = (q[:, 0] > -1.0 + eps) & (q[:, 0] < 5.0 - eps) & (np.abs(q[:, 1]) < 1.5 - eps) \
        & (q[:, 2] > 22.0 + eps) & (q[:, 2] < 25.0 - eps)
    inner = 1.5 * math.cos(math.pi / 24)  # the facets' distance from the axis
    in_mast = (np.hypot(q[:, 0], q[:, 1]) < inner - eps) & (q[:, 2] < 24.0 - eps)
    inside = in_box | in_mast
    assert inside.sum() >= 2
    assert (sim.table.reason != 0).tolist() == inside.tolist()
    assert sim.complete and (sim.cap == ~inside).all()
    assert _recheck(sim) == 0
    summary = sim.summary()
    assert summary.line().startswith(f"captured {int((~inside).sum())}/{int((~inside).sum())} "
                                     f"at quality >= 0.3; {int(inside.sum())} uncapturable (")


def test_one_drone_and_four_drones_finish_and_more_drones_finish_sooner() -> None:
    sc = load_scenario(scenario_path("inspect_storage_tank"))
    times: dict[int, float] = {}
    for n in (1, 4):
        ang = np.arange(n) * 2.0 * np.pi / n
        agents = [dataclasses.replace(sc.agents[0], id=f"D{i}",
                                      p0=np.array([12.0 * np.cos(a), 12.0 * np.sin(a), 3.0]))
                  for i, a in enumerate(ang)]
        sim = InspectionSim(resolve_structure(dataclasses.replace(sc, agents=agents)))
        while not sim.done and sim.t < sc.duration:
            sim.tick()
        assert sim.complete and sim.cap.all()
        assert _recheck(sim) == 0
        assert sim.t_complete is not None
        times[n] = sim.t_complete
    assert times[4] < 0.5 * times[1]


def test_a_landmark_facing_the_ground_is_uncapturable_with_its_reason() -> None:
    text = """
dims = 3
d_opt = 2.0
duration = 60.0
[space]
lo = [-5.0, -5.0, 0.5]
hi = [5.0, 5.0, 5.0]
[planner]
p_lim = 1.0
[[landmarks]]
position = [0.0, 0.0, 1.0]
normal = [1.0, 0.0, 0.0]
[[landmarks]]
position = [0.0, 0.0, 0.6]
normal = [0.0, 0.0, -1.0]
[[agents]]
id = "A"
position = [3.0, 3.0, 2.0]
landmarks = [1, 2]
[inspection]
"""
    sim = InspectionSim(parse_scenario(text, "ground.toml"))
    while not sim.done and sim.t < 60.0:
        sim.tick()
    assert sim.complete
    assert sim.summary().uncapturable == {2: "every pose that would image it is outside the "
                                             "mission space"}
    assert sim.summary().captured == [1]


def test_viscover_simulate_and_scenario_check_say_what_was_captured(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
        ) -> None:
    """(Both commands called in-process: what they say and write is checked, not their
    process.)"""
    path = scenario_path("inspect_wind_turbine")
    monkeypatch.chdir(ROOT)
    status = main(["simulate", str(path), "--out", str(tmp_path)])
    run = capsys.readouterr()
    assert status == 0, run.err
    why = "it lies on a face buried inside another part of the structure"
    assert f"captured 39/39 at quality >= 0.3; 2 uncapturable (2: {why}); complete at t = " \
        in run.out
    doc = json.loads((tmp_path / "result.json").read_text())
    assert doc["inspection"]["capturable"] == 39
    assert set(doc["inspection"]["uncapturable"].values()) == {why}
    rows = doc["captures"]
    assert {tuple(sorted(r)) for r in rows} == {
        ("agent", "direction", "landmarks", "position", "quality", "right", "t")}
    assert sum(len(r["landmarks"]) for r in rows) == 39
    assert (tmp_path / "captures.png").read_bytes()[:4] == b"\x89PNG"
    status = main(["scenario", "check", str(path)])
    check = capsys.readouterr()
    assert status == 0, check.err
    bad = sorted(int(k) for k in doc["inspection"]["uncapturable"])
    assert ("inspection: 39/41 landmarks capturable at quality >= 0.3 from "
            in check.out)
    assert f"2 uncapturable ({why}): {bad[0]}, {bad[1]}" in check.out
    assert ("    mesh: 2 parts (2 closed); no repair needed; 2 landmarks on faces buried inside "
            "another part, 0 facing a closed cavity\n") in check.out
