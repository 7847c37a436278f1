"""Scenario files (agent.config.scenario) and landmark generators (agent.core.landmarks)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from agent.config.parse import load_scenario, parse_scenario
from agent.config.scenario import Scenario, ScenarioError
from agent.core.landmarks import BOX_FACES, box_faces, cylinder, regular_polygon
from agent.world.structure import resolve_structure

SCENARIOS = Path(__file__).resolve().parent.parent / "scenarios"
SHIPPED = sorted(SCENARIOS.glob("*.toml"))

GOOD = """\
name = "good"
dims = 2
seed = 3
d_opt = 1.0
duration = 10.0

[space]
lo = [-3.0, -3.0]
hi = [3.0, 3.0]

[planner]
dt = 0.1
p_lim = 0.3
p_min = 0.01
tau = 0.9
beta = 0.5
avoidance = "smooth"
r_s = 1.0
d_w = 0.5

[[landmarks]]
position = [1.0, 0.0]
normal = [1.0, 0.0]

[[landmarks]]
position = [0.0, 1.0]
normal_angle = 1.5707963267948966

[[generators]]
kind = "polygon"
sides = 3
side = 0.5
center = [0.0, -1.0]

[[agents]]
id = "A"
position = [-2.0, 2.0]
yaw = 0.0
landmarks = [1, 3, 4]

[[agents]]
id = "B"
position = [2.0, -2.0]
direction = [0.0, 1.0]
landmarks = [2, 5]
"""


def _load(tmp_path: Path, text: str, name: str = "broken.toml") -> Scenario:
    f = tmp_path / name
    f.write_text(text, encoding="utf-8")
    return load_scenario(f)


# --- shipped scenarios ---------------------------------------------------------------


def test_scenarios_are_shipped() -> None:
    names = {p.stem for p in SHIPPED}
    assert {"free_5_1", "bounded_5_2_smooth", "bounded_5_2_abrupt", "oscillation_5_2",
            "oscillation_5_2_fixed", "two_agents_5_2", "hexagon_5_3", "cube_6_2"} <= names


@pytest.mark.parametrize("path", SHIPPED, ids=lambda p: p.stem)
def test_shipped_scenario_loads(path: Path) -> None:
    sc = resolve_structure(load_scenario(path))  # mesh scenarios: with their landmarks
    m = sc.q.shape[0]
    assert sc.u.shape == (m, 3)
    np.testing.assert_allclose(np.linalg.norm(sc.u, axis=1), 1.0)
    owned = np.sort(np.concatenate([a.landmarks for a in sc.agents]))
    np.testing.assert_array_equal(owned, np.arange(m))
    for a in sc.agents:
        assert sc.space.contains(a.p0)
        assert np.isclose(np.linalg.norm(a.v0), 1.0)
    if sc.planar:
        assert np.all(sc.q[:, 2] == 0.0) and np.all(sc.u[:, 2] == 0.0)
        assert np.all(np.isinf(sc.space.lo[2])) and sc.params.planar


def test_free_5_1_matches_eq_5_2() -> None:
    sc = load_scenario(SCENARIOS / "free_5_1.toml")
    np.testing.assert_allclose(sc.q[:, :2], [[1.0, 4.5], [2.0, 4.1], [2.5, 4.3]])
    ang = np.array([-2 * np.pi / 3, -np.pi / 2, -np.pi / 4])
    np.testing.assert_allclose(sc.u[:, :2], np.stack([np.cos(ang), np.sin(ang)], 1), atol=1e-15)
    (a,) = sc.agents
    np.testing.assert_allclose(a.p0, [-1.0, 5.0, 0.0])
    np.testing.assert_allclose(a.v0, [0.5, math.sqrt(3) / 2, 0.0])
    assert sc.d_opt == 3.0 and sc.params.avoidance == "none"
    assert not np.isfinite(sc.space.lo).any()


def test_hexagon_matches_section_5_3() -> None:
    sc = load_scenario(SCENARIOS / "hexagon_5_3.toml")
    k = np.arange(1, 7)
    phi = np.pi * k / 3 - np.pi / 6
    u = np.stack([np.cos(phi), np.sin(phi), 0 * phi], axis=1)
    np.testing.assert_allclose(sc.u, u, atol=1e-12)
    np.testing.assert_allclose(sc.q, 0.5 * math.sqrt(3) / 2 * u, atol=1e-12)
    owned = {a.id: sorted(sc.landmark_ids[j] for j in a.landmarks) for a in sc.agents}
    assert owned == {"A": [3, 6], "B": [2, 4], "C": [1, 5]}


def test_cube_has_one_landmark_per_face_per_agent() -> None:
    sc = load_scenario(SCENARIOS / "cube_6_2.toml")
    assert sc.q.shape == (15, 3) and not sc.planar
    for a in sc.agents:
        normals = {tuple(np.round(sc.u[j]).astype(int)) for j in a.landmarks}
        assert len(a.landmarks) == 5 and len(normals) == 5  # five distinct faces
    assert not np.any(np.all(np.isclose(sc.u, [0, 0, -1]), axis=1))  # no bottom face


def test_good_text_parses_and_ids_continue() -> None:
    sc = parse_scenario(GOOD, "good.toml")
    assert sc.landmark_ids == [1, 2, 3, 4, 5]
    assert sc.seed == 3 and sc.name == "good"
    assert [a.id for a in sc.agents] == ["A", "B"]
    np.testing.assert_allclose(sc.agents[1].v0, [0.0, 1.0, 0.0])
    assert sc.with_seed(7).seed == 7


# --- generators ----------------------------------------------------------------------


@pytest.mark.parametrize("sides", [3, 6, 11])
def test_polygon_radial_normals(sides: int) -> None:
    c = np.array([1.0, -2.0, 0.5])
    q, u = regular_polygon(sides, 0.7, c, phase=0.3)
    assert q.shape == u.shape == (sides, 3)
    np.testing.assert_allclose(np.linalg.norm(u, axis=1), 1.0)
    radial = q - c
    apothem = 0.7 / (2 * np.tan(np.pi / sides))
    np.testing.assert_allclose(np.linalg.norm(radial, axis=1), apothem)
    np.testing.assert_allclose(radial / apothem, u, atol=1e-12)
    assert np.isclose(np.arctan2(u[0, 1], u[0, 0]), 0.3)


@pytest.mark.parametrize("grid", [(1, 1), (3, 1), (2, 4)])
def test_box_faces_on_faces_with_face_normals(grid: tuple[int, int]) -> None:
    c, s = np.array([0.5, -1.0, 2.0]), np.array([1.0, 2.0, 0.5])
    q, u = box_faces(c, s, BOX_FACES, grid)
    per = grid[0] * grid[1]
    assert q.shape == u.shape == (6 * per, 3)
    np.testing.assert_allclose(np.linalg.norm(u, axis=1), 1.0)
    axis = np.argmax(np.abs(u), axis=1)
    np.testing.assert_array_equal(axis, np.repeat([0, 0, 1, 1, 2, 2], per))
    rel = q - c
    # On the face plane, and inside the face.
    np.testing.assert_allclose(np.einsum("ij,ij->i", rel, u), s[axis] / 2)
    assert np.all(np.abs(rel) <= s / 2 + 1e-12)
    assert len({tuple(x) for x in np.round(q, 9)}) == q.shape[0]


def test_box_row_for_cube_6_2() -> None:
    q, _u = box_faces([0, 0, 1], [0.5] * 3, ["+x", "-x", "+y", "-y", "+z"], (3, 1))
    assert q.shape == (15, 3)
    np.testing.assert_allclose(q[:3], [[0.25, y, 1.0] for y in (-0.5 / 3, 0, 0.5 / 3)])
    np.testing.assert_allclose(q[12:], [[x, 0.0, 1.25] for x in (-0.5 / 3, 0, 0.5 / 3)])


def test_cylinder_radial_normals() -> None:
    c = np.array([1.0, 1.0, 0.0])
    q, u = cylinder(c, 0.5, 2.0, around=8, rows=3)
    assert q.shape == u.shape == (24, 3)
    np.testing.assert_allclose(np.linalg.norm(u, axis=1), 1.0)
    np.testing.assert_allclose(u[:, 2], 0.0)
    rel = q - c
    np.testing.assert_allclose(np.linalg.norm(rel[:, :2], axis=1), 0.5)
    np.testing.assert_allclose(rel[:, :2] / 0.5, u[:, :2], atol=1e-12)
    np.testing.assert_allclose(np.unique(np.round(rel[:, 2], 9)), [1 / 3, 1.0, 5 / 3])


def test_generator_argument_errors() -> None:
    with pytest.raises(ValueError, match="3 sides"):
        regular_polygon(2, 1.0)
    with pytest.raises(ValueError, match="unknown face"):
        box_faces([0, 0, 0], [1, 1, 1], ["+w"])


# --- broken files ----------------------------------------------------------------------

BROKEN = [
    # (id, old, new, expected fragments of the message)
    ("toml-syntax", 'name = "good"', 'name = "good', ["invalid TOML"]),
    ("unknown-field", "p_lim = 0.3", "p_lmi = 0.3", ["planner.p_lmi", "p_lim"]),
    ("unknown-top", "duration = 10.0", "duraton = 10.0", ["duraton", "duration"]),
    ("wrong-type", "dt = 0.1", 'dt = "fast"', ["planner.dt", "expected a number"]),
    ("dt-zero", "dt = 0.1", "dt = 0.0", ["planner.dt", "positive"]),
    ("p_min>p_lim", "p_min = 0.01", "p_min = 0.5", ["planner.p_min", "p_lim"]),
    ("tau-one", "tau = 0.9", "tau = 1.0", ["planner.tau", "between 0 and 1"]),
    ("beta-zero", "beta = 0.5", "beta = 0", ["planner.beta"]),
    ("r_s-negative", "r_s = 1.0", "r_s = -1.0", ["planner.r_s", "positive"]),
    ("d_w-zero", "d_w = 0.5", "d_w = 0.0", ["planner.d_w"]),
    ("avoidance-typo", '"smooth"', '"smoth"', ["planner.avoidance", "smooth"]),
    ("d_opt-missing", "d_opt = 1.0\n", "", ["d_opt", "missing"]),
    ("dims-4", "dims = 2", "dims = 4", ["dims"]),
    ("position-3-in-2d", "position = [2.0, -2.0]", "position = [2.0, -2.0, 1.0]",
     ["agents[1].position", "expected 2 numbers", "dims = 2"]),
    ("outside-space", "position = [-2.0, 2.0]", "position = [-4.0, 2.0]",
     ["agents[0].position", "outside the mission space"]),
    ("too-close", "position = [2.0, -2.0]", "position = [-2.0, 1.5]",
     ["agents[1].position", "r_s"]),
    ("unknown-landmark", "landmarks = [2, 5]", "landmarks = [2, 5, 9]",
     ["agents[1].landmarks[2]", "unknown landmark id 9"]),
    ("assigned-twice", "landmarks = [2, 5]", "landmarks = [2, 5, 1]",
     ["agents[1].landmarks[2]", "twice"]),
    ("assigned-to-nobody", "landmarks = [2, 5]", "landmarks = [2]", ["agents", "[5]", "no agent"]),
    ("duplicate-agent", 'id = "B"', 'id = "A"', ["agents[1].id", "duplicate"]),
    ("bad-agent-id", 'id = "B"', 'id = "B 2"', ["agents[1].id", "not a valid id"]),
    ("zero-normal", "normal = [1.0, 0.0]", "normal = [0.0, 0.0]",
     ["landmarks[0].normal", "non-zero"]),
    ("zero-direction", "direction = [0.0, 1.0]", "direction = [0.0, 0.0]",
     ["agents[1].direction", "non-zero"]),
    ("both-normals", "normal = [1.0, 0.0]", "normal = [1.0, 0.0]\nnormal_angle = 0.0",
     ["landmarks[0]", "exactly one"]),
    ("generator-kind", 'kind = "polygon"', 'kind = "polygn"',
     ["generators[0].kind", "polygon"]),
    ("generator-field", "side = 0.5", "sdie = 0.5", ["generators[0].sdie", "`side`"]),
    ("generator-type", "sides = 3", 'sides = "three"', ["generators[0].sides", "integer"]),
    ("box-in-2d", 'kind = "polygon"\nsides = 3\nside = 0.5\ncenter = [0.0, -1.0]',
     'kind = "box"\ncenter = [0.0, 0.0, 1.0]\nsize = 1.0', ["generators[0]", "3-D"]),
    ("space-inverted", "hi = [3.0, 3.0]", "hi = [3.0, -3.0]", ["space.hi", "greater"]),
    ("pitch-in-2d", "yaw = 0.0", "yaw = 0.0\npitch = 0.1", ["agents[0].pitch", "3-D"]),
    ("lambda-range", "d_w = 0.5", "d_w = 0.5\nlambda_dir = 1.5", ["planner.lambda_dir"]),
    ("strategy-typo", "seed = 3", 'seed = 3\nstrategy = "potentail"',
     ["strategy", "unknown strategy 'potentail'", "'thesis', 'potential'"]),
    ("potential-without-trading", "seed = 3", 'seed = 3\nstrategy = "potential"\ntrading = false',
     ["strategy", "set trading = true"]),
]


@pytest.mark.parametrize(("old", "new", "fragments"), [b[1:] for b in BROKEN],
                         ids=[b[0] for b in BROKEN])
def test_broken_file_names_file_and_field(
    tmp_path: Path, old: str, new: str, fragments: list[str]
) -> None:
    assert old in GOOD
    with pytest.raises(ScenarioError) as info:
        _load(tmp_path, GOOD.replace(old, new, 1))
    msg = str(info.value)
    assert msg.startswith(f"{tmp_path / 'broken.toml'}: "), msg
    for frag in fragments:
        assert frag in msg, (frag, msg)
    assert len(msg.splitlines()) <= 3


def test_missing_file(tmp_path: Path) -> None:
    with pytest.raises(ScenarioError, match=r"nope\.toml: no such file"):
        load_scenario(tmp_path / "nope.toml")


def test_parse_uses_source_name() -> None:
    with pytest.raises(ScenarioError, match=r"^mine\.toml: planner\.dt:"):
        parse_scenario(GOOD.replace("dt = 0.1", "dt = -1"), "mine.toml")


@pytest.mark.parametrize("path", SHIPPED, ids=lambda p: p.stem)
def test_every_agent_starts_in_front_of_one_of_its_landmarks(path: Path) -> None:
    """Some orientation sees an owned landmark (⟨p − q, u⟩ > 0), else the run is trivial."""
    sc = resolve_structure(load_scenario(path))
    for a in sc.agents:
        front = np.einsum("ij,ij->i", a.p0 - sc.q[a.landmarks], sc.u[a.landmarks]) > 0
        assert front.any(), a.id


# --- [structure] and visibility ----------------------------------------------------------

MESH_GOOD = """\
name = "mesh"
dims = 3
d_opt = 4.0
duration = 5.0
visibility = "occlusion"

[space]
lo = [-10.0, -10.0, 0.5]
hi = [10.0, 10.0, 20.0]

[structure]
mesh = "tower.stl"
spacing = 3.0
z_min = 1.0
margin = 1.0
refresh = 0.5

[[agents]]
id = "A"
position = [8.0, 0.0, 5.0]
yaw = 3.14
"""


@pytest.fixture
def mesh_dir(tmp_path: Path) -> Path:
    """A folder holding tower.stl (radius 3 m, 30 m tall) and a non-mesh file."""
    from agent.structure.examples import tower

    tower(height=10.0).export(str(tmp_path / "tower.stl"))
    (tmp_path / "garbage.stl").write_bytes(b"solid x\nnot an stl\n")
    return tmp_path


def test_mesh_scenario_parses_and_resolves(mesh_dir: Path) -> None:
    sc = _load(mesh_dir, MESH_GOOD)
    assert sc.visibility == "occlusion" and sc.structure is not None
    st = sc.structure
    assert st.mesh == mesh_dir / "tower.stl" and st.spacing == 3.0 and st.z_min == 1.0
    assert st.region == ((-10.0, -10.0, 0.5), (10.0, 10.0, 20.0))  # within_space default
    assert sc.q.shape == (0, 3) and not st.sampled
    full = resolve_structure(sc)
    assert full.structure is not None and full.structure.sampled
    m = full.q.shape[0]
    assert m > 10 and full.landmark_ids == list(range(1, m + 1))
    np.testing.assert_array_equal(full.agents[0].landmarks, np.arange(m))
    assert np.all(full.q[:, 2] >= 1.0) and np.all(full.q[:, 2] <= 10.0 + 1e-9)
    again = resolve_structure(sc)
    np.testing.assert_array_equal(again.q, full.q)  # seeded, deterministic
    assert resolve_structure(full) is full
    assert "structure tower.stl (landmarks every 3 m), visibility occlusion" in full.summary()


def test_scenario_without_structure_is_facing(tmp_path: Path) -> None:
    sc = _load(tmp_path, GOOD)
    assert sc.structure is None and sc.visibility == "facing"
    assert resolve_structure(sc) is sc


MESH_BROKEN = [
    # (id, old, new, the exact message after "<file>: ")
    ("visibility-typo", 'visibility = "occlusion"', 'visibility = "ocllusion"',
     "visibility: unknown model 'ocllusion'; did you mean `occlusion`?"),
    ("visibility-type", 'visibility = "occlusion"', "visibility = 1",
     "visibility: expected a string, got an integer"),
    ("structure-typo", "[structure]", "[strcture]",
     "strcture: unknown field; did you mean `structure`?"),
    ("structure-field", "spacing = 3.0", "spacnig = 3.0",
     "structure.spacnig: unknown field; did you mean `spacing`?"),
    ("mesh-missing", 'mesh = "tower.stl"\n', "",
     "structure.mesh: required field is missing; add `mesh = ...`"),
    ("mesh-type", 'mesh = "tower.stl"', "mesh = 3",
     "structure.mesh: expected a string, got an integer"),
    ("mesh-format", 'mesh = "tower.stl"', 'mesh = "tower.dae"',
     "structure.mesh: unsupported mesh format '.dae' in 'tower.dae'; use .stl, .obj, .ply"),
    ("spacing-missing", "spacing = 3.0\n", "",
     "structure.spacing: required field is missing; add `spacing = ...`"),
    ("spacing-zero", "spacing = 3.0", "spacing = 0.0",
     "structure.spacing: must be a positive number of metres, got 0.0"),
    ("position-2", "spacing = 3.0", "spacing = 3.0\nposition = [1.0, 2.0]",
     "structure.position: expected 3 numbers for this field, got 2"),
    ("position-nan", "spacing = 3.0", "spacing = 3.0\nposition = [1.0, 2.0, nan]",
     "structure.position: must contain finite numbers, got [1.0, 2.0, nan]"),
    ("yaw-inf", "spacing = 3.0", "spacing = 3.0\nyaw = inf",
     "structure.yaw: must be a finite number, got inf"),
    ("scale-negative", "spacing = 3.0", "spacing = 3.0\nscale = -2.0",
     "structure.scale: must be a positive number (model units to metres), got -2.0"),
    ("z_min-nan", "z_min = 1.0", "z_min = nan",
     "structure.z_min: must be a finite number, got nan"),
    ("min_normal_z-range", "z_min = 1.0", "z_min = 1.0\nmin_normal_z = 2.0",
     "structure.min_normal_z: must lie in [-1, 1] (a normal's z component), got 2.0"),
    ("within_space-type", "z_min = 1.0", 'z_min = 1.0\nwithin_space = "yes"',
     "structure.within_space: expected true or false, got a string"),
    ("region-half", "z_min = 1.0", "z_min = 1.0\nregion_lo = [0.0, 0.0, 0.0]",
     "structure.region_hi: is missing; give both region_lo and region_hi, or neither"),
    ("region-inverted", "z_min = 1.0",
     "z_min = 1.0\nregion_lo = [0.0, 0.0, 0.0]\nregion_hi = [1.0, -1.0, 1.0]",
     "structure.region_hi: must be greater than structure.region_lo on every axis; "
     "axis y has lo = 0, hi = -1"),
    ("region-outside-space", "z_min = 1.0",
     "z_min = 1.0\nregion_lo = [20.0, 0.0, 0.0]\nregion_hi = [30.0, 1.0, 1.0]",
     "structure.region_lo: the region of interest does not meet the mission space; move it "
     "inside [space] or set within_space = false"),
    ("margin-zero", "margin = 1.0", "margin = 0.0",
     "structure.margin: must be a positive number of metres, got 0.0"),
    ("refresh-negative", "refresh = 0.5", "refresh = -0.5",
     "structure.refresh: must be a positive number of metres, got -0.5"),
]


@pytest.mark.parametrize(("old", "new", "message"), [b[1:] for b in MESH_BROKEN],
                         ids=[b[0] for b in MESH_BROKEN])
def test_broken_structure_field_exact_message(
    mesh_dir: Path, old: str, new: str, message: str
) -> None:
    assert old in MESH_GOOD
    with pytest.raises(ScenarioError) as info:
        _load(mesh_dir, MESH_GOOD.replace(old, new, 1))
    assert str(info.value) == f"{mesh_dir / 'broken.toml'}: {message}"


def test_structure_needs_3d(mesh_dir: Path) -> None:
    text = MESH_GOOD.replace("dims = 3", "dims = 2").replace(", 0.5]", "]").replace(", 20.0]", "]")
    with pytest.raises(ScenarioError) as info:
        _load(mesh_dir, text)
    assert str(info.value) == (
        f"{mesh_dir / 'broken.toml'}: structure: needs a 3-D scenario (dims = 3)")


def test_occlusion_needs_a_structure(tmp_path: Path) -> None:
    text = GOOD.replace('name = "good"', 'name = "good"\nvisibility = "occlusion"')
    with pytest.raises(ScenarioError) as info:
        _load(tmp_path, text)
    assert str(info.value) == (
        f"{tmp_path / 'broken.toml'}: visibility: 'occlusion' needs a structure; add a "
        '[structure] table with a mesh, or use visibility = "facing"')


def test_missing_mesh_file_names_the_resolved_path(mesh_dir: Path) -> None:
    with pytest.raises(ScenarioError) as info:
        _load(mesh_dir, MESH_GOOD.replace("tower.stl", "sub/none.stl"))
    assert str(info.value) == (
        f"{mesh_dir / 'broken.toml'}: structure.mesh: no such mesh file "
        f"'{mesh_dir / 'sub' / 'none.stl'}'; relative paths start at the scenario file's folder")


RESOLVE_BROKEN = [
    # (id, old, new, the exact message after "<file>: ")
    ("agent-inside", "position = [8.0, 0.0, 5.0]", "position = [0.0, 0.0, 5.0]",
     "agents[0].position: is inside the structure; move the agent away from it"),
    ("agent-too-close", "position = [8.0, 0.0, 5.0]", "position = [3.5, 0.0, 5.0]",
     "agents[0].position: is 0.5 m from the structure, closer than structure.margin = 1 m; "
     "move the agent away from it"),
    ("filters-leave-nothing", "z_min = 1.0", "z_min = 15.0",
     "structure: no landmarks left on the mesh after the filters (z_min, min_normal_z, "
     "region, mission space); relax them"),
]


@pytest.mark.parametrize(("old", "new", "message"), [b[1:] for b in RESOLVE_BROKEN],
                         ids=[b[0] for b in RESOLVE_BROKEN])
def test_structure_problems_found_when_sampling(
    mesh_dir: Path, old: str, new: str, message: str
) -> None:
    sc = _load(mesh_dir, MESH_GOOD.replace(old, new, 1))  # the fields themselves are valid
    with pytest.raises(ScenarioError) as info:
        resolve_structure(sc)
    assert str(info.value) == f"{mesh_dir / 'broken.toml'}: {message}"


def test_unreadable_mesh_is_one_line(mesh_dir: Path) -> None:
    sc = _load(mesh_dir, MESH_GOOD.replace("tower.stl", "garbage.stl"))
    with pytest.raises(ScenarioError) as info:
        resolve_structure(sc)
    msg = str(info.value)
    assert msg.startswith(f"{mesh_dir / 'broken.toml'}: structure.mesh: "
                          f"{mesh_dir / 'garbage.stl'}: "), msg
    assert len(msg.splitlines()) == 1
