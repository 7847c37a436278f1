"""agent.structure.mesh and agent.structure.examples: loading, posing, one-line errors."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
import trimesh

from agent.structure.examples import bridge, example_structures, l_building, tower, write_examples
from agent.structure.mesh import load_mesh, load_structure, pose_matrix, posed_mesh


def _error(fn: Callable[..., object], *args: object, **kwargs: object) -> str:
    with pytest.raises(ValueError) as info:
        fn(*args, **kwargs)
    msg = str(info.value)
    assert "\n" not in msg
    return msg


def test_missing_file(tmp_path: Path) -> None:
    path = tmp_path / "nope.stl"
    assert _error(load_mesh, path) == f"{path}: no such mesh file"


def test_directory_is_not_a_mesh(tmp_path: Path) -> None:
    assert _error(load_mesh, tmp_path) == f"{tmp_path}: not a file"


def test_unsupported_format(tmp_path: Path) -> None:
    path = tmp_path / "cloud.xyz"
    path.write_text("1 2 3\n")
    assert _error(load_mesh, path) == (
        f"{path}: unsupported mesh format '.xyz' (use .stl, .obj, .ply)"
    )


def test_garbage_stl_has_no_triangles(tmp_path: Path) -> None:
    path = tmp_path / "garbage.stl"
    path.write_text("this is not a mesh\n")
    assert _error(load_mesh, path) == f"{path}: mesh has no triangles"


def test_unreadable_obj(tmp_path: Path) -> None:
    path = tmp_path / "bad.obj"
    path.write_text("v 1 2\nf 1 2 9\n")
    msg = _error(load_mesh, path)
    assert msg.startswith(f"{path}: cannot read mesh (") and msg.endswith(")")


def test_open_mesh_rejected_only_when_closed_required(tmp_path: Path) -> None:
    path = tmp_path / "triangle.obj"
    path.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    assert len(load_mesh(path).faces) == 1
    assert _error(load_mesh, path, require_watertight=True) == (
        f"{path}: mesh is not watertight (it has open edges)"
    )


def test_bad_pose_names_the_file(tmp_path: Path) -> None:
    path = write_examples(tmp_path)[0]
    assert _error(load_structure, path, scale=-1.0) == (
        f"{path}: scale must be a positive finite number, got -1.0"
    )
    assert _error(load_structure, path, rotation=np.diag([1.0, 1.0, -1.0])) == (
        f"{path}: rotation must be a proper rotation matrix (orthonormal, det +1)"
    )
    assert _error(load_structure, path, yaw=0.1, rotation=np.eye(3)) == (
        f"{path}: give either yaw or rotation, not both"
    )


def test_pose_scale_yaw_position(tmp_path: Path) -> None:
    [path] = [p for p in write_examples(tmp_path) if p.stem == "l_building"]
    placed = load_structure(path, position=(1.0, 2.0, 3.0), yaw=np.pi / 2, scale=2.0,
                            require_watertight=True)
    # (20, 0, 0) scaled by 2 and turned by 90° about z is (0, 40, 0); then moved by (1, 2, 3).
    assert np.min(np.linalg.norm(placed.vertices - [1.0, 42.0, 3.0], axis=1)) < 1e-6
    assert placed.volume == pytest.approx(1560.0 * 8.0, rel=1e-6)
    assert placed.bounds[:, 2].tolist() == pytest.approx([3.0, 23.0])


def test_posed_mesh_with_rotation_keeps_the_input() -> None:
    mesh = tower(radius=1.0, height=4.0)
    before = mesh.vertices.copy()
    turn = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])  # +90° about x
    lying = posed_mesh(mesh, rotation=turn)
    assert np.array_equal(mesh.vertices, before)
    assert lying.bounds[:, 1].tolist() == pytest.approx([-4.0, 0.0])
    assert lying.volume == pytest.approx(mesh.volume)
    assert pose_matrix(scale=3.0)[:3, :3] == pytest.approx(3.0 * np.eye(3))


@pytest.mark.parametrize(
    ("name", "volume", "bounds"),
    [
        ("l_building", (20 * 6 + 6 * 6) * 10.0, [[0, 0, 0], [20, 12, 10]]),
        ("bridge", (24 * 1 + 2 * 2 * 6) * 8.0, [[0, -4, 0], [24, 4, 7]]),
    ],
)
def test_examples_closed_with_known_volume(name: str, volume: float,
                                           bounds: list[list[float]]) -> None:
    mesh = example_structures()[name]
    assert mesh.is_watertight and mesh.is_winding_consistent
    assert mesh.volume == pytest.approx(volume, rel=1e-9)
    assert mesh.bounds == pytest.approx(np.array(bounds, dtype=float), abs=1e-9)


def test_tower_is_a_closed_upright_cylinder() -> None:
    mesh = tower(radius=3.0, height=30.0, sections=64)
    assert mesh.is_watertight and mesh.volume > 0
    assert mesh.bounds[:, 2].tolist() == pytest.approx([0.0, 30.0])
    polygon = 0.5 * 64 * 9.0 * np.sin(2 * np.pi / 64) * 30.0  # inscribed 64-gon prism
    assert mesh.volume == pytest.approx(polygon, rel=1e-9)


def test_bridge_leaves_the_underside_open() -> None:
    mesh = bridge()
    under = np.array([[12.0, 0.0, 3.0], [12.0, 0.0, 6.5], [1.0, 0.0, 3.0]])
    assert mesh.contains(under).tolist() == [False, True, True]


def test_write_examples_round_trip(tmp_path: Path) -> None:
    paths = write_examples(tmp_path / "meshes")
    assert sorted(p.name for p in paths) == [
        "bridge.stl", "chimney_plant.stl", "gabled_house.stl", "house_parts.stl",
        "l_building.stl", "scan_house.stl", "storage_tank.stl", "tower.stl", "u_boxes.stl",
        "u_building.stl", "wind_turbine.stl"]
    for path in paths:
        if path.stem == "scan_house":  # open, on purpose
            assert not load_mesh(path).is_watertight
            continue
        loaded = load_mesh(path, require_watertight=True)
        original = example_structures()[path.stem]
        assert isinstance(loaded, trimesh.Trimesh)
        assert loaded.volume == pytest.approx(original.volume, rel=1e-6)


def test_inspection_examples_have_their_stated_volumes() -> None:
    """Gabled house: 14 × (8·5 + 8·3/2); U: 20·16 − 8·10 = 240 m² × 9; tank: a cylinder of
    r = 6, 8 tall, under a cone 2.5 tall (40 facets: the polygon's area, not π r²); turbine:
    a 24-facet mast (its own volume, the part inside the nacelle counted twice) and the box."""
    ex = example_structures()
    assert ex["gabled_house"].volume == pytest.approx(14 * (8 * 5 + 8 * 3 / 2))
    assert ex["u_building"].volume == pytest.approx(240 * 9)
    polygon = 0.5 * 40 * 36 * np.sin(2 * np.pi / 40)
    assert ex["storage_tank"].volume == pytest.approx(polygon * (8 + 2.5 / 3))
    mast = 0.5 * 24 * 1.5**2 * np.sin(2 * np.pi / 24) * 24
    assert ex["wind_turbine"].volume == pytest.approx(mast + 6 * 3 * 3)
    for name, mesh in ex.items():
        if name == "scan_house":  # a scan: open, a third of it wound the wrong way
            merged = mesh.copy()
            merged.merge_vertices()
            assert not merged.is_watertight and not merged.is_winding_consistent
            continue
        assert mesh.is_watertight and mesh.volume > 0 and mesh.bounds[0, 2] == 0.0


def test_examples_reject_bad_sizes() -> None:
    assert _error(l_building, wing=13.0) == (
        "need 0 < wing < short_side, wing < long_side and height > 0 [m]"
    )
