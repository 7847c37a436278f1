"""An inspection specified by a camera (agent.core.camera, the ``[camera]`` table) and a
ground sampling distance: the camera's numbers, the config's one-line errors, and a mission
whose every capture, recomputed by independent code from its logged pose and the camera's
datasheet numbers, meets the GSD with its margin, the incidence limit and the trigger
interval."""

from __future__ import annotations

import math
import subprocess
import sys
import tomllib
from pathlib import Path

import numpy as np
import pytest

from agent.config.scenario import load_scenario, parse_scenario
from agent.config.validation import ScenarioError
from agent.core.camera import Camera
from agent.sim.inspection import InspectionSim
from agent.world.structure import resolve_structure
from tests.conftest import ROOT, repo_env, scenario_path

NAME = "inspect_house_camera"


def test_a_cameras_field_of_view_and_ground_sampling_distance() -> None:
    cam = Camera.from_sensor((13.2, 8.8), 8.8, (5472, 3648))
    assert cam.fov[0] == pytest.approx(2 * math.atan(13.2 / (2 * 8.8)))
    assert cam.fov[1] == pytest.approx(2 * math.atan(8.8 / (2 * 8.8)))
    # 5 m head-on: 5 m × 13.2 mm / (8.8 mm × 5472 px) = 1.371 mm/px.
    assert cam.range_for(5.0 * 13.2 / (8.8 * 5472)) == pytest.approx(5.0)
    same = Camera.from_fov(cam.fov, cam.image_px)
    assert same.pixel_angle == pytest.approx(cam.pixel_angle)
    assert cam.ready(10.0, None) and not Camera(1e-4, (10, 10), 2.0).ready(11.0, 10.0)


BASE = """
name = "cam"
dims = 3
d_opt = {d_opt}
duration = 60.0
[space]
lo = [-10.0, -10.0, 0.5]
hi = [10.0, 10.0, 10.0]
[[landmarks]]
id = 1
position = [0.0, 0.0, 2.0]
normal = [1.0, 0.0, 0.0]
[[agents]]
id = "A"
position = [5.0, 0.0, 2.0]
landmarks = [1]
"""


@pytest.mark.parametrize(("extra", "d_opt", "message"), [
    ("[inspection]\ngsd_mm = 2.0\n", 5.0,
     "cam.toml: inspection.gsd_mm: needs the camera: add a [camera] table (sensor_mm, "
     "focal_mm and image_px, or fov_deg and image_px)"),
    ("[inspection]\n[camera]\nimage_px = [4000, 3000]\nfov_deg = [80.0, 60.0]\n"
     "focal_mm = 8.0\n", 5.0,
     "cam.toml: camera: give either sensor_mm and focal_mm, or fov_deg (with image_px in "
     "both cases)"),
    ("[camera]\nimage_px = [4000, 3000]\nfov_deg = [80.0, 60.0]\n", 5.0,
     "cam.toml: camera: describes an inspection's camera; add an [inspection] table or "
     "remove [camera]"),
    ("[inspection]\nfov_deg = [80.0, 60.0]\n[camera]\nimage_px = [4000, 3000]\n"
     "fov_deg = [80.0, 60.0]\n", 5.0,
     "cam.toml: inspection.fov_deg: the [camera] table gives the field of view; remove "
     "inspection.fov_deg"),
    ("[inspection]\ngsd_mm = 1.0\n[camera]\nsensor_mm = [13.2, 8.8]\nfocal_mm = 8.8\n"
     "image_px = [5472, 3648]\n", 5.0,
     "cam.toml: d_opt: is 5 m, farther than the 3.28 m at which this camera meets "
     "inspection.gsd_mm = 1 (with aim_margin 0.1) head-on; set d_opt <= 3.28"),
])
def test_camera_mistakes_are_one_line_errors(extra: str, d_opt: float, message: str) -> None:
    with pytest.raises(ScenarioError) as err:
        parse_scenario(BASE.format(d_opt=d_opt) + extra, "cam.toml")
    assert str(err.value) == message


def _independent_gsd(p: list[float], q: np.ndarray, u: np.ndarray, sensor_w_mm: float,
                     focal_mm: float, width_px: int) -> tuple[np.ndarray, np.ndarray]:
    """GSD [mm/px] and incidence [deg] of landmarks (q, u) from camera position p, from the
    datasheet: range × (sensor width / image width) / focal length / cos(incidence)."""
    gap = np.asarray(p)[None, :] - q
    rng = np.linalg.norm(gap, axis=1)
    cos_inc = (gap * u).sum(axis=1) / rng
    pixel_mm = sensor_w_mm / width_px
    return rng * 1000.0 * pixel_mm / focal_mm / cos_inc, np.degrees(np.arccos(cos_inc))


def test_every_capture_meets_the_gsd_with_its_margin_and_the_trigger_interval() -> None:
    doc = tomllib.loads(scenario_path(NAME).read_text())
    cam, gsd_mm = doc["camera"], doc["inspection"]["gsd_mm"]
    aim, max_inc = doc["inspection"]["aim_margin"], doc["inspection"]["max_incidence_deg"]
    sc = resolve_structure(load_scenario(scenario_path(NAME)))
    sim = InspectionSim(sc)
    while not sim.done and sim.t < sc.duration:
        sim.tick()
    assert sim.complete and sim.cap[sim.table.capturable].all()
    ids = list(sc.landmark_ids)
    last: dict[str, float] = {}
    for c in sorted(sim.captures, key=lambda c: c.t):
        rows = [ids.index(i) for i in c.landmarks]
        gsd, inc = _independent_gsd(c.position, sc.q[rows], sc.u[rows], cam["sensor_mm"][0],
                                    cam["focal_mm"], cam["image_px"][0])
        assert (gsd <= (1.0 - aim) * gsd_mm * (1 + 1e-9)).all(), (c.t, gsd.max())
        assert (inc <= max_inc + 1e-9).all()
        if c.agent in last:
            assert c.t - last[c.agent] >= cam["trigger_s"] - 1e-9
        last[c.agent] = c.t
    summary = sim.summary().line()
    assert summary.startswith("captured 63/63 at GSD <= 2 mm/px (aimed 1.8), incidence <= "
                              "60 deg; 30 uncapturable (30: it lies on a face buried")


def test_simulate_runs_the_agents_to_the_camera_spec(tmp_path: Path) -> None:
    run = subprocess.run([sys.executable, "-m", "agent.cli", "simulate",
                          str(scenario_path(NAME)), "--out", str(tmp_path), "--no-plots"],
                         capture_output=True, text=True, env=repo_env(), cwd=ROOT, timeout=300)
    assert run.returncode == 0, run.stderr
    assert "captured 63/63 at GSD <= 2 mm/px (aimed 1.8), incidence <= 60 deg; " in run.stdout
    assert "complete at t = " in run.stdout
