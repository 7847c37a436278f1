"""An inspection specified by a camera (agent.core.camera, the ``[camera]`` table) and a
ground sampling distance: the camera's numbers, the config's one-line errors, and a mission
whose every capture, recomputed by independent code from its logged pose and the camera's
datasheet numbers, meets the GSD with its margin, the incidence limit and the trigger
interval."""

from __future__ import annotations

import json
import math
import re
import tomllib
from pathlib import Path

import numpy as np
import pytest

from agent.cli import main
from agent.config.parse import load_scenario, parse_scenario
from agent.config.validation import ScenarioError
from agent.core.camera import Camera
from agent.sim.inspection import InspectionSim
from agent.world.structure import resolve_structure
from tests.conftest import ROOT, scenario_path

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


def test_simulate_runs_the_agents_to_the_camera_spec(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
        ) -> None:
    """The agents' run, and its report: result.json keeps the spec's numbers and each
    landmark's part; the page's resolution table has every captured landmark's finest GSD
    (recomputed here) within the aimed limit, the body's top (buried under the roof) as
    uncapturable, and the histogram. (``viscover simulate`` and ``export-plan`` are called
    in-process: what they write is checked here, not their process.)"""
    monkeypatch.chdir(ROOT)
    status = main(["simulate", str(scenario_path(NAME)), "--out", str(tmp_path)])
    run = capsys.readouterr()
    assert status == 0, run.err
    assert "captured 63/63 at GSD <= 2 mm/px (aimed 1.8), incidence <= 60 deg; " in run.out
    assert "complete at t = " in run.out
    doc = json.loads((tmp_path / "result.json").read_text())
    numbers = doc["inspection"]["numbers"]
    assert numbers["gsd_limit_mm"] == pytest.approx(2.0)
    assert numbers["gsd_aim_mm"] == pytest.approx(1.8)
    assert sorted(set(doc["inspection"]["parts"])) == [0, 1]
    toml = tomllib.loads(scenario_path(NAME).read_text())["camera"]
    index = {lm["id"]: j for j, lm in enumerate(doc["landmarks"])}
    q = np.array([lm["position"] for lm in doc["landmarks"]])
    u = np.array([lm["normal"] for lm in doc["landmarks"]])
    finest = np.full(len(q), np.inf)
    for c in doc["captures"]:
        seen = [index[i] for i in c["landmarks"]]
        gsd, _ = _independent_gsd(c["position"], q[seen], u[seen], toml["sensor_mm"][0],
                                  toml["focal_mm"], toml["image_px"][0])
        finest[seen] = np.minimum(finest[seen], gsd)
    worst = float(finest[np.isfinite(finest)].max())
    assert worst <= 1.8 * (1 + 1e-9)
    page = (tmp_path / "report.html").read_text()
    table = page[page.index('<table id="resolution">'):]
    table = table[:table.index("</table>")]
    cells = [re.sub(r"<[^>]+>", "", c) for c in re.findall(r"<td>.*?</td>", table)]
    rows = [cells[k:k + 8] for k in range(0, len(cells), 8)]
    assert max(float(r[6]) for r in rows if r[6] != "–") == pytest.approx(worst, rel=1e-2)
    top = next(r for r in rows if r[0] == "part 1, facing up")  # the body's top: buried
    assert top[2] == "0" and top[3] == "0" and int(top[4]) == int(top[1]) > 0
    assert (tmp_path / "resolution.png").read_bytes()[:4] == b"\x89PNG"
    # export-plan waits the camera's trigger interval after each image (made longer here
    # than the plan's own least wait) and, for PX4, sets the camera to image mode first.
    numbers["trigger_s"] = 2.5
    (tmp_path / "result.json").write_text(json.dumps(doc))
    for autopilot, mode_items in (("px4", 1), ("ardupilot", 0)):
        out = tmp_path / autopilot
        status = main(["export-plan", str(tmp_path), "--origin", "47.0,8.0,400", "--out",
                       str(out), "--autopilot", autopilot])
        assert status == 0, capsys.readouterr().err
        items = json.loads((out / "A.plan").read_text())["mission"]["items"]
        waits = [i["params"][0] for i in items if i["command"] == 93]  # MAV_CMD_NAV_DELAY
        assert waits and all(w == 2.5 for w in waits)
        modes = [i["params"][:2] for i in items if i["command"] == 530]
        assert modes == [[0, 0]] * mode_items  # MAV_CMD_SET_CAMERA_MODE, image
