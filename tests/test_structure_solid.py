"""Meshes as they come (agent.structure.repair, agent.structure.solid): parts that touch or
overlap, coincident faces, open scans, inconsistent winding, degenerate triangles and
duplicate vertices, closed cavities. Inside and outside are checked against an independent
test (trimesh's ray-parity ``contains`` on each clean closed part alone, or the parts'
analytic shapes); what cannot be imaged is named with its reason."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import trimesh

from agent.core.inspection import REASONS, CaptureSpec, CaptureTable
from agent.structure.clearance import MeshClearance
from agent.structure.examples import box, house_parts, u_boxes
from agent.structure.inspection import capture_table
from agent.structure.mesh import load_structure, mesh_repairs
from agent.structure.model import StructureModel
from agent.structure.repair import repair_mesh
from agent.structure.sampling import sample_landmarks
from agent.structure.solid import BURIED, CAVITY

SPEC = CaptureSpec(0.3, (np.radians(90.0), np.radians(70.0)), None)


def _soup(parts: list[trimesh.Trimesh]) -> trimesh.Trimesh:
    """The parts as one triangle soup: every triangle its own three vertices (as an STL or
    an OBJ with per-face normals stores them), nothing merged."""
    tri = np.concatenate([np.asarray(p.triangles) for p in parts])
    return trimesh.Trimesh(vertices=tri.reshape(-1, 3), faces=np.arange(tri.size // 3)
                           .reshape(-1, 3), process=False)


def _table(model: StructureModel, q: np.ndarray, u: np.ndarray, d_opt: float = 4.0
           ) -> CaptureTable:
    lo, hi = model.mesh.bounds[0] - 12.0, model.mesh.bounds[1] + 12.0
    lo[2] = 0.5
    return capture_table(q, u, d_opt, SPEC, lo, hi, model, True)


def test_inside_a_house_body_under_its_roof_is_inside() -> None:
    """The house body's centre is nearest to the roof's underside (set 0.4 m into the body,
    facing down, towards the centre): its normal says "outside"; the winding number says
    inside, as ray parity on the body alone does."""
    mesh, _ = repair_mesh(house_parts())
    body = box((0.0, 0.0, 0.0), (14.0, 8.0, 5.0))
    rng = np.random.default_rng(1)
    pts = rng.uniform((-2.0, -2.0, 0.2), (16.0, 10.0, 9.0), size=(400, 3))
    pts = np.vstack([pts, [[7.0, 4.0, 2.5], [7.0, 4.0, 4.4], [3.0, 2.0, 4.0]]])
    roof = trimesh.Trimesh(vertices=mesh.vertices, faces=mesh.faces[12:], process=False)
    want = body.contains(pts) | roof.contains(pts)
    got = MeshClearance(mesh).closest(pts).distance < 0.0
    assert got.tolist() == want.tolist()
    assert want[-3:].all()


def test_an_overlap_of_three_boxes_is_inside_and_the_courtyard_outside() -> None:
    mesh, _ = repair_mesh(u_boxes())
    parts = [box((0, 0, 0), (20, 6, 9)), box((0, 5, 0), (6, 16, 9)),
             box((14, 5, 0), (20, 16, 9))]
    rng = np.random.default_rng(2)
    pts = rng.uniform((-2.0, -2.0, 0.2), (22.0, 18.0, 11.0), size=(600, 3))
    want = np.any([p.contains(pts) for p in parts], axis=0)
    assert MeshClearance(mesh).winding.inside(pts).tolist() == want.tolist()
    model = StructureModel(mesh, 1.5)
    court = np.array([[10.0, 12.0, 4.0]])  # open to +y: reachable
    overlap = np.array([[3.0, 5.5, 4.0]])  # inside two boxes at once
    assert model.reachable(court).tolist() == [True]
    assert model.reachable(overlap).tolist() == [False]
    assert float(model.distance(overlap)[0]) < 0.0


def test_coincident_faces_of_touching_boxes_are_buried_with_their_reason() -> None:
    """Two boxes sharing the wall x = 4: both copies of that wall lie between two solids."""
    a, b = box((0, 0, 0), (4, 4, 4)), box((4, 0, 0), (8, 4, 4))
    model = StructureModel(repair_mesh(_soup([a, b]))[0], 1.0)
    q, u = sample_landmarks(model.mesh, 1.0, z_min=0.5)
    on_wall = np.abs(q[:, 0] - 4.0) < 1e-9
    assert on_wall.sum() >= 8 and (np.abs(u[on_wall, 0]) > 0.99).all()
    hidden = model.hidden(q, u)
    assert ((hidden == BURIED) == on_wall).all()
    table = _table(model, q, u)
    assert (table.reason[on_wall] == BURIED).all()
    assert table.capturable[~on_wall].all()
    assert REASONS[BURIED] == "it lies on a face buried inside another part of the structure"


def test_a_closed_cavity_is_neither_reachable_nor_imaged() -> None:
    """A hollow block: a closed outer shell and an inner shell facing into the cavity. The
    cavity is free space, but no drone can get in: its faces are named, no viewpoint is in
    it, and every outer face is captured."""
    outer = box((0, 0, 0), (10, 10, 8))
    inner = box((2, 2, 2), (8, 8, 6))
    inner.invert()
    model = StructureModel(repair_mesh(_soup([outer, inner]))[0], 1.0)
    assert model.reachable(np.array([[5.0, 5.0, 4.0]])).tolist() == [False]
    assert model.solid.winding(np.array([[5.0, 5.0, 4.0]]))[0] == pytest.approx(0.0, abs=0.01)
    q, u = sample_landmarks(model.mesh, 1.5, z_min=0.5)
    cavity = np.all((q > 2.0 - 1e-9) & (q < np.array([8, 8, 6]) + 1e-9), axis=1)
    assert cavity.sum() >= 20
    table = _table(model, q, u)
    assert (table.reason[cavity] == CAVITY).all()
    assert table.capturable[~cavity].all()
    inside_box = np.all((table.P > 1.0) & (table.P < np.array([9, 9, 7])), axis=1)
    assert not inside_box.any()


def _open_house(rng: np.random.Generator) -> trimesh.Trimesh:
    """The gabled house as a scan gives it: no floor, one triangle soup, a third of its
    triangles wound the wrong way, two degenerate slivers and a repeated triangle."""
    house = house_parts(seat=0.4)
    body = box((0, 0, 0), (14, 8, 5))
    body.update_faces(body.face_normals[:, 2] > -0.5)  # the floor was never scanned
    roof = trimesh.Trimesh(vertices=house.vertices, faces=house.faces[12:], process=False)
    tri = np.asarray(_soup([body, roof]).triangles).copy()
    flip = rng.random(tri.shape[0]) < 0.33
    tri[flip] = tri[flip][:, ::-1]
    sliver = np.array([[[0.0, 0.0, 1.0], [0.0, 0.0, 2.0], [0.0, 0.0, 3.0]],
                       [[14.0, 8.0, 1.0], [14.0, 8.0, 1.0], [14.0, 8.0, 2.0]]])
    tri = np.concatenate([tri, sliver, tri[:1]])
    return trimesh.Trimesh(vertices=tri.reshape(-1, 3),
                           faces=np.arange(tri.size // 3).reshape(-1, 3), process=False)


def test_an_open_scan_with_flipped_triangles_loads_outward_and_is_captured(tmp_path: Path
                                                                           ) -> None:
    path = tmp_path / "scan.obj"
    _open_house(np.random.default_rng(3)).export(str(path))
    mesh = load_structure(path)
    repairs = mesh_repairs(mesh)
    assert repairs is not None
    assert repairs.degenerate_faces == 2 and repairs.duplicate_faces == 1
    assert repairs.rewound_faces > 0 and repairs.parts == 2 and repairs.closed_parts == 1
    assert repairs.line().startswith("2 parts (1 closed, 1 open); repaired: ")
    assert mesh.is_winding_consistent
    model = StructureModel(mesh, 1.0)
    q, u = sample_landmarks(mesh, 1.5, z_min=0.5)
    # Outward: away from the house's axis (walls) or up (the roof planes, the body's top).
    centre = np.array([7.0, 4.0, 0.0])
    side = np.abs(u[:, 2]) < 0.5
    assert (np.einsum("ij,ij->i", (q - centre)[side, :2], u[side, :2]) > 0.0).all()
    table = _table(model, q, u)
    # Buried, by ray parity on the closed body and the closed roof, each alone.
    house = house_parts(seat=0.4)
    roof = trimesh.Trimesh(vertices=house.vertices, faces=house.faces[12:], process=False)
    lifted = q + 1e-3 * u
    buried = box((0, 0, 0), (14, 8, 5)).contains(lifted) | roof.contains(lifted)
    assert buried.sum() >= 40
    assert (table.reason[buried] == BURIED).all()
    assert table.capturable[~buried].all()


def test_duplicate_vertices_and_degenerate_triangles_change_nothing_but_the_count(
        tmp_path: Path) -> None:
    """A box stored as a soup with a zero-area triangle gives the clean box's landmarks."""
    clean = box((0, 0, 0), (6, 4, 3))
    soup = _soup([clean])
    tri = np.concatenate([np.asarray(soup.triangles),
                          [[[0.0, 0.0, 0.0], [3.0, 0.0, 0.0], [6.0, 0.0, 0.0]]]])
    dirty = trimesh.Trimesh(vertices=tri.reshape(-1, 3),
                            faces=np.arange(tri.size // 3).reshape(-1, 3), process=False)
    fixed, repairs = repair_mesh(dirty)
    assert repairs.merged_vertices == 36 + 3 - 9 and repairs.degenerate_faces == 1
    assert repairs.parts == 1 and repairs.closed_parts == 1 and fixed.is_watertight
    assert fixed.is_volume and fixed.volume == pytest.approx(72.0)
    assert sorted(map(tuple, fixed.triangles.reshape(-1, 9).round(9).tolist())) == \
        sorted(map(tuple, repair_mesh(clean)[0].triangles.reshape(-1, 9).round(9).tolist()))


def test_a_part_buried_in_another_keeps_the_orientation_its_author_gave() -> None:
    """A part nested in another is a cavity (facing in) or a buried part (facing out): its
    winding is the author's word, so it is not turned; a free inverted part is."""
    outer, cavity, free = box((0, 0, 0), (6, 6, 6)), box((2, 2, 2), (4, 4, 4)), \
        box((10, 0, 0), (12, 2, 2))
    cavity.invert()
    free.invert()
    fixed, repairs = repair_mesh(_soup([outer, cavity, free]))
    assert repairs.flipped_parts == 1
    w = StructureModel(fixed, 0.5).solid.winding(np.array([[3.0, 3.0, 3.0], [11.0, 1.0, 1.0],
                                                      [1.0, 1.0, 1.0]]))
    assert np.round(w).tolist() == [0.0, 1.0, 1.0]


def test_a_line_of_sight_grazing_an_edge_that_stands_proud_of_the_roof_is_blocked() -> None:
    """The house body's top edge stands 2 cm proud of the roof set into it. A camera below
    and to the south sees a roof landmark 4 cm behind that edge along a ray crossing the
    body's wall 0.1 mm below its top: blocked, as trimesh's own ray caster finds (the ray to
    the landmark lifted 1 mm off its face passes over the edge)."""
    from trimesh.ray.ray_triangle import RayMeshIntersector

    from agent.structure.sight_lines import sight_lines

    model = StructureModel(repair_mesh(house_parts())[0], 1.5)
    slope = np.array([0.0, -3.4, 4.5]) / np.hypot(3.4, 4.5)  # the roof's south plane normal
    y = 0.037
    q = np.array([[11.305, y, 4.6 + (y + 0.5) * 3.4 / 4.5]])
    p = np.array([[12.74, -4.45, 4.28]])
    pair = (np.array([0]), np.array([0]))
    assert sight_lines(model, p, q, slope[None, :], pair).tolist() == [False]
    d = q[0] - p[0]
    r = float(np.linalg.norm(d))
    loc, _, _ = RayMeshIntersector(model.mesh).intersects_location(  # type: ignore[no-untyped-call]
        p, (d / r)[None, :], multiple_hits=True)
    assert float(np.linalg.norm(loc - p[0], axis=1).min()) < r - 0.01
    # Lifted 1 mm off the face, the same ray misses the edge (what the check alone allowed).
    lifted = q + 1e-3 * slope[None, :]
    assert model.caster.segment_clear(p, lifted).tolist() == [True]
