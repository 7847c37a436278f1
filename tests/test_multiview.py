"""Multi-view overlap (``inspection.views``, agent.core.views, agent.world.views): each landmark
captured in k images whose viewing directions differ pairwise by the parallax angle.

The sector geometry keeps any two views in different sectors at least the parallax apart and
within the incidence limit; the config's mistakes are one-line errors; the view landmarks keep
their landmark's position, normal and owner under ids id·k + s, once; and the shipped
scenario completes, in the lockstep simulator and in the agents at 30 % loss, with every
landmark's views counted again from the logged camera positions alone (against the landmarks
of the same file read without ``views``): k captures pairwise at least the parallax apart, at
the ground sampling distance of the camera's datasheet."""

from __future__ import annotations

import dataclasses
import itertools
import math
import tomllib
from pathlib import Path

import numpy as np
import pytest

from agent.config.parse import load_scenario, parse_scenario
from agent.config.scenario import Scenario
from agent.config.validation import ScenarioError
from agent.core.inspection import (
    CaptureSpec,
    capture_quality,
    probe_poses,
    probe_quality,
    uncapturable_line,
)
from agent.core.views import in_sector, sector_axes, sector_cone
from agent.net.faults import FaultConfig
from agent.protocol.records import CaptureRec
from agent.sim.inspection import InspectionSim
from agent.storage.journal import Journal
from agent.testing.memsim import MemoryMission
from agent.world.structure import resolve_structure, structure_model
from agent.world.tables import mission_tables
from bench.inspection.recheck import LoggedCapture, false_captures
from tests.conftest import scenario_path

NAME = "inspect_house_views"


def _unit(x: np.ndarray) -> np.ndarray:
    return np.asarray(x / np.linalg.norm(x, axis=-1, keepdims=True), dtype=np.float64)


def _normals(rng: np.random.Generator, m: int) -> np.ndarray:
    """Random unit normals, with the vertical and horizontal ones that need the fallback."""
    special = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0], [0.0, -1.0, 0.0],
                        [0.6, 0.0, 0.8]])
    return np.vstack([special, _unit(rng.normal(size=(m, 3)))])


def _in_cone(rng: np.random.Generator, axis: np.ndarray, half: float, n: int) -> np.ndarray:
    """n random unit directions within ``half`` [rad] of each ``axis`` (…, 3): (…, n, 3),
    the first of them on the cone's rim."""
    side = rng.normal(size=(*axis.shape[:-1], n, 3))
    side -= (side * axis[..., None, :]).sum(axis=-1, keepdims=True) * axis[..., None, :]
    side = _unit(side)
    tilt = rng.uniform(0.0, half, size=(*axis.shape[:-1], n, 1))
    tilt[..., 0, :] = half * (1.0 - 1e-12)
    return _unit(np.cos(tilt) * axis[..., None, :] + np.sin(tilt) * side)


def _angle_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.asarray(np.degrees(np.arccos(np.clip((a * b).sum(axis=-1), -1.0, 1.0))),
                      dtype=np.float64)


@pytest.mark.parametrize("views", [2, 3, 4, 5, 6])
def test_views_in_different_sectors_are_the_parallax_apart_within_the_incidence(views: int
                                                                                 ) -> None:
    rng = np.random.default_rng(views)
    u = _normals(rng, 60)
    tried = 0
    for theta, beta in [(20.0, 60.0), (10.0, 75.0), (30.0, 90.0), (15.0, 45.0), (40.0, 80.0)]:
        cone = sector_cone(views, math.radians(theta), math.radians(beta))
        if cone is None:
            continue
        tried += 1
        axes = sector_axes(u, views, cone.tilt)  # (m, k, 3)
        assert np.allclose(np.linalg.norm(axes, axis=2), 1.0)
        # Each axis τ off the normal, at most the largest incidence less the cone.
        off = _angle_deg(axes, u[:, None, :])
        assert np.allclose(off, math.degrees(cone.tilt), atol=1e-7)
        assert (off <= beta - math.degrees(cone.half) + 1e-7).all()
        # Sector 0 leans along the horizontal e1 ⊥ u.
        lean = axes[:, 0, :] - math.cos(cone.tilt) * u
        assert np.allclose(lean[:, 2], 0.0, atol=1e-12) and np.allclose((lean * u).sum(1), 0.0)
        w = _in_cone(rng, axes, cone.half, 12)  # (m, k, n, 3)
        assert in_sector(w, axes[:, :, None, :], cone.cos).all()
        assert (_angle_deg(w, u[:, None, None, :]) <= beta + 1e-7).all()  # incidence
        for s, t in itertools.combinations(range(views), 2):
            apart = _angle_deg(w[:, s, :, None, :], w[:, t, None, :, :])  # (m, n, n)
            assert apart.min() >= theta - 1e-7, (s, t, apart.min())
            # and nothing of sector t is in sector s: the sectors are disjoint
            assert not in_sector(w[:, t], axes[:, s, None, :], cone.cos).any()
    assert tried >= 3


def test_the_capture_test_and_the_probe_poses_keep_to_a_landmarks_sector() -> None:
    q = np.array([[0.0, 0.0, 3.0], [1.0, 2.0, 3.0]])
    u = np.array([[1.0, 0.0, 0.0], [0.0, 0.6, 0.8]])
    spec = CaptureSpec(0.3, max_incidence=math.radians(60.0), views=3)
    cone = sector_cone(3, spec.parallax, spec.max_incidence)
    assert cone is not None and cone.tilt > cone.half  # head-on is in no sector
    axes = sector_axes(u, 3, cone.tilt)
    for s in range(3):
        axis = axes[:, s]
        P = q + 2.0 * axis  # on the sector's axis, looking at the landmark
        got = capture_quality(P, -axis, q, u, 2.0, spec, axis, cone.cos)
        assert (np.diag(got) > 0.3).all()
        other = axes[:, (s + 1) % 3]  # from the next sector: not this one's capture
        assert not capture_quality(q + 2.0 * other, -other, q, u, 2.0, spec, axis,
                                   cone.cos).diagonal().any()
        head_on = capture_quality(q + 2.0 * u, -u, q, u, 2.0, spec, axis, cone.cos)
        assert not head_on.diagonal().any() and capture_quality(
            q + 2.0 * u, -u, q, u, 2.0, spec).diagonal().all()
        PP, VV = probe_poses(q, u, 2.0, spec, axis, cone.cos)
        away = _unit(PP - q[:, None, :])
        assert in_sector(away, axis[:, None, :], cone.cos).all()
        assert np.allclose(VV, -away)
        assert (probe_quality(PP, VV, q, u, 2.0, spec, axis, cone.cos) >= 0.3).any(axis=1).all()
    with pytest.raises(ValueError, match="cos_cone"):
        capture_quality(q, -u, q, u, 2.0, spec, axes[:, 0])


BASE = """
name = "mv"
dims = {dims}
d_opt = 2.0
duration = 60.0
[[landmarks]]
id = {lid}
position = {pos}
normal = {normal}
[[agents]]
id = "A"
position = {start}
landmarks = [{lid}]
[inspection]
"""


def _text(extra: str, dims: int = 3, lid: int = 1) -> str:
    if dims == 2:
        pos, normal, start = "[0.0, 0.0]", "[1.0, 0.0]", "[5.0, 0.0]"
    else:
        pos, normal, start = "[0.0, 0.0, 2.0]", "[1.0, 0.0, 0.0]", "[5.0, 0.0, 2.0]"
    return BASE.format(dims=dims, lid=lid, pos=pos, normal=normal, start=start) + extra


@pytest.mark.parametrize(("extra", "dims", "lid", "message"), [
    ("views = 7\n", 3, 1,
     "mv.toml: inspection.views: must be an integer from 1 to 6 (images per landmark), got 7"),
    ("views = 0\n", 3, 1,
     "mv.toml: inspection.views: must be an integer from 1 to 6 (images per landmark), got 0"),
    ("views = 2\nparallax_deg = 90.0\n", 3, 1,
     "mv.toml: inspection.parallax_deg: must lie in (0, 90) degrees (the least angle between "
     "two images of a landmark), got 90.0"),
    ("views = 6\nparallax_deg = 45.0\nmax_incidence_deg = 60.0\n", 3, 1,
     "mv.toml: inspection.views: 6 views 45 deg apart leave view sectors narrower than 5 deg "
     "within max_incidence_deg = 60; use parallax_deg <= 38.3 or max_incidence_deg >= 72.5 "
     "or fewer views"),
    ("views = 6\nparallax_deg = 80.0\n", 3, 1,
     "mv.toml: inspection.views: 6 views 80 deg apart leave view sectors narrower than 5 deg "
     "within the default max_incidence_deg of 75; use parallax_deg <= 46 or fewer views"),
    ("views = 3\n", 2, 1,
     "mv.toml: inspection.views: view sectors need a 3-D scenario (dims = 3); remove "
     "inspection.views"),
    ("views = 2\n", 3, 2**52,
     "mv.toml: inspection.views: view landmark ids (landmark id x 2 + view) reach "
     "9007199254740993, over 2^53 - 1 = 9007199254740991; use landmark ids up to "
     "4503599627370495 or fewer views"),
])
def test_multiview_mistakes_are_one_line_errors(extra: str, dims: int, lid: int, message: str
                                                ) -> None:
    with pytest.raises(ScenarioError) as err:
        resolve_structure(parse_scenario(_text(extra, dims, lid), "mv.toml"))
    assert str(err.value) == message


def test_the_suggested_parallax_and_incidence_fit() -> None:
    for extra in ("views = 6\nparallax_deg = 38.3\nmax_incidence_deg = 60.0\n",
                  "views = 6\nparallax_deg = 45.0\nmax_incidence_deg = 72.5\n",
                  "views = 6\nparallax_deg = 46.0\n"):
        sc = parse_scenario(_text(extra), "mv.toml")
        assert sc.inspection is not None and sc.inspection.views == 6


def test_a_landmark_met_only_head_on_is_uncapturable_from_its_sectors_with_code_7() -> None:
    """Quality 0.95 needs a view within about 18 deg of the normal at d_opt; two sectors 40
    deg apart within 60 deg of incidence start 22 deg off it."""
    extra = "quality = 0.95\nmax_incidence_deg = 60.0\n"
    plain = resolve_structure(parse_scenario(_text(extra), "mv.toml"))
    assert mission_tables(plain)[0].reason.tolist() == [0]
    sc = resolve_structure(parse_scenario(_text(extra + "views = 2\nparallax_deg = 40.0\n"),
                                          "mv.toml"))
    table, _ = mission_tables(sc)
    assert table.reason.tolist() == [7, 7]
    assert uncapturable_line(table.reason, np.asarray(sc.landmark_ids)) == (
        "2 uncapturable (no pose near it images it to the spec from its view sector "
        "(inspection.views)): 2, 3")


def test_each_landmark_becomes_its_view_landmarks_once() -> None:
    text = _text("views = 3\n").replace(
        "landmarks = [1]", "landmarks = [1, 9]") + """
[[landmarks]]
id = 9
position = [0.0, 1.0, 3.0]
normal = [0.0, 0.6, 0.8]
"""
    one = parse_scenario(text, "mv.toml")
    assert one.q.shape[0] == 2 and one.view_of is None
    assert "2 landmarks (each to be captured in 3 views)" in one.summary()
    sc = resolve_structure(one)
    assert sc.landmark_ids == [3, 4, 5, 27, 28, 29]
    assert sc.view_of is not None and sc.view_of.tolist() == [1, 1, 1, 9, 9, 9]
    assert np.array_equal(sc.q, np.repeat(one.q, 3, axis=0))
    assert np.array_equal(sc.u, np.repeat(one.u, 3, axis=0))
    assert sc.agents[0].landmarks.tolist() == [0, 1, 2, 3, 4, 5]
    assert sc.view_axis is not None and sc.view_cos is not None
    assert "6 view landmarks (2 landmarks x 3 views)" in sc.summary()
    assert resolve_structure(sc) is sc  # once
    assert resolve_structure(one).landmark_ids == sc.landmark_ids  # deterministic
    plain = parse_scenario(_text(""), "mv.toml")
    assert resolve_structure(plain) is plain and plain.view_axis is None


# -- the shipped scenario, counted again from the logged captures alone ---------------------


def _original(path: Path) -> Scenario:
    """The same file with ``views`` removed: the landmarks themselves."""
    text = path.read_text()
    assert text.count("\nviews = ") == 1
    plain = "\n".join(line for line in text.splitlines() if not line.startswith("views = "))
    sc = resolve_structure(parse_scenario(plain, str(path)))
    assert sc.view_of is None and sc.inspection is not None and sc.inspection.views == 1
    return sc


def _count_views(path: Path, sc: Scenario, logged: list[tuple[list[float], list[int]]]
                 ) -> int:
    """Checks, from logged (camera position, view ids) only, that every landmark has as many
    captures pairwise at least the parallax apart as it has capturable views, each at the
    datasheet GSD with its margin and within the incidence; returns how many landmarks have
    all their views."""
    doc = tomllib.loads(path.read_text())
    ins, cam = doc["inspection"], doc["camera"]
    k, theta = ins["views"], ins["parallax_deg"]
    gsd_limit = (1.0 - ins["aim_margin"]) * ins["gsd_mm"]
    mm_per_px_at_1m = cam["sensor_mm"][0] / cam["image_px"][0] / cam["focal_mm"] * 1000.0
    base = _original(path)
    row_of = {lid: j for j, lid in enumerate(base.landmark_ids)}
    seen: dict[int, list[np.ndarray]] = {}
    for position, ids in logged:
        p = np.asarray(position, dtype=float)
        for v in ids:
            j = row_of[v // k]
            gap = p - base.q[j]
            rng = float(np.linalg.norm(gap))
            cos_inc = float(gap @ base.u[j]) / rng
            assert cos_inc >= math.cos(math.radians(ins["max_incidence_deg"])) - 1e-9
            assert rng * mm_per_px_at_1m / cos_inc <= gsd_limit * (1 + 1e-9)
            seen.setdefault(v // k, []).append(gap / rng)
    table, _ = mission_tables(sc)
    assert sc.view_of is not None
    capturable = {lid: int(table.capturable[sc.view_of == lid].sum()) for lid in row_of}
    full = 0
    for lid, want in capturable.items():
        dirs = seen.get(lid, [])
        assert len(dirs) >= want, (lid, len(dirs), want)
        ok = any(all(math.degrees(math.acos(min(1.0, float(a @ b)))) >= theta - 1e-9
                     for a, b in itertools.combinations(group, 2))
                 for group in itertools.combinations(dirs, want))
        assert ok, f"landmark {lid}: no {want} captures {theta} deg apart"
        full += want == k
    return full


def test_the_shipped_multiview_scenario_completes_in_the_simulator() -> None:
    path = scenario_path(NAME)
    sc = resolve_structure(load_scenario(path))
    assert sc.view_of is not None and "view landmarks" in sc.summary()
    sim = InspectionSim(sc)
    while not sim.done and sim.t < sc.duration:
        sim.tick()
    assert sim.complete and sim.cap[sim.table.capturable].all()
    full = _count_views(path, sc, [(c.position, c.landmarks) for c in sim.captures])
    assert full >= 15  # landmarks with all three views (the others lose a sector to the
    # ground or the structure's margin)
    assert "3 views >= 20 deg apart" in sim.summary().line()


def test_the_shipped_multiview_scenario_completes_in_the_agents_at_30_percent_loss(
        tmp_path: Path) -> None:
    path = scenario_path(NAME)
    sc = resolve_structure(load_scenario(path))
    mm = MemoryMission(sc, tmp_path, faults=FaultConfig(drop_default=0.3, duplicate=0.1,
                                                        jitter_s=0.05), seed=5)
    try:
        assert mm.run(300.0)
        assert mm.final_violations() == []
    finally:
        mm.close()
    recs: list[CaptureRec] = []
    for a in sc.agents:
        j = Journal(tmp_path / a.id)
        recs += [r for r in j.replay() if isinstance(r, CaptureRec)]
        j.close()
    table, _ = mission_tables(sc)
    got = {lid for r in recs for lid in r.ids}
    assert got == set(np.asarray(sc.landmark_ids)[table.capturable].tolist())
    assert _count_views(path, sc, [(list(r.p), list(r.ids)) for r in recs]) >= 15
    spec = sc.inspection
    assert spec is not None and spec.fov is not None and sc.structure is not None
    assert sc.view_axis is not None and sc.view_cos is not None
    caps: list[LoggedCapture] = [
        {"position": r.p, "direction": r.v, "right": r.right, "landmarks": r.ids}
        for r in recs]
    args = (structure_model(sc.structure).mesh, caps, list(sc.landmark_ids), sc.q, sc.u,
            sc.d_opt, spec.quality, (math.degrees(spec.fov[0]), math.degrees(spec.fov[1])), 60.0)
    assert false_captures(*args, sectors=(sc.view_axis, sc.view_cos)) == 0
    # the independent sector check can fail: the axes of the next view do not hold
    shifted = np.roll(sc.view_axis.reshape(-1, 3, 3), 1, axis=1).reshape(-1, 3)
    assert false_captures(*args, sectors=(shifted, sc.view_cos)) == len(got)
    assert dataclasses.replace(spec, views=1).describe() + ", 3 views >= 20 deg apart" \
        == spec.describe()
