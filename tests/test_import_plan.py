"""``viscover import-plan``: the plans export-plan wrote for a small inspection run (the gabled
house: a mesh, occlusion, a field of view), read back unchanged, with a viewpoint deleted and
with one moved, against the inspection's own capture test; how a plan's items become images;
malformed plans in one line."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from agent.cli import main
from agent.commands.import_plan import plan_captures, read_plan
from agent.config.parse import load_scenario
from agent.flight.geodetic import Origin
from agent.flight.plan_images import camera_direction, plan_images
from agent.world.structure import resolve_structure
from tests.conftest import scenario_path

SCENARIO = str(scenario_path("inspect_gabled_house"))
ORIGIN = "47.3977,8.5456,488"
WHERE = Origin(47.3977, 8.5456, 488.0)


@pytest.fixture(scope="module")
def run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A simulated inspection run (lockstep: 2 s) and its plans in ``plans/``."""
    out = tmp_path_factory.mktemp("gabled")
    assert main(["simulate", SCENARIO, "--out", str(out), "--no-plots", "--quiet",
                 "--engine", "lockstep"]) == 0
    assert main(["export-plan", str(out), "--origin", ORIGIN]) == 0
    return out


def _import(run: Path, plans: list[Path], capsys: pytest.CaptureFixture[str]
            ) -> tuple[int, dict[str, Any]]:
    capsys.readouterr()
    code = main(["import-plan", str(run), *map(str, plans), "--origin", ORIGIN, "--scenario",
                 SCENARIO, "--json"])
    return code, json.loads(capsys.readouterr().out)


def _only_by(run: Path) -> tuple[str, int, list[int]]:
    """A plan, the item index (from 1) of one of its images, and the landmarks that image
    alone captures (none of the plans' other images does)."""
    sc = resolve_structure(load_scenario(SCENARIO))
    images = [im for name in ("A", "B")
              for im in read_plan(run / "plans" / f"{name}.plan", WHERE).images]
    P = np.array([im.position for im in images])
    V = np.array([im.direction for im in images])
    ids = np.asarray(sc.landmark_ids)
    each = np.array([plan_captures(sc, P[k:k + 1], V[k:k + 1]).captured
                     for k in range(len(images))])
    only = each & (each.sum(axis=0) == 1)
    k = int(np.argmax(only.sum(axis=1)))
    assert only[k].any(), "every landmark is captured by two images at least"
    return images[k].name, images[k].item, sorted(ids[only[k]].tolist())


def test_the_unchanged_plans_capture_everything_the_run_captured(
        run: Path, capsys: pytest.CaptureFixture[str]) -> None:
    code, rep = _import(run, sorted((run / "plans").glob("*.plan")), capsys)
    assert code == 0 and rep["exit_status"] == 0 and rep["lost"] == []
    result = json.loads((run / "result.json").read_text())
    captured = set(result["inspection"]["captured"])
    rows = {r["id"]: r for r in rep["landmarks"]}
    assert captured and {i for i, r in rows.items() if r["run"] == "captured"} == captured
    assert all(rows[i]["plan"] == "captured" and rows[i]["quality"] >= 0.3 for i in captured)
    assert rep["summary"].endswith(f"{len(captured)}/{len(captured)} landmarks the run "
                                   "captured are captured at quality >= 0.3; none lost")
    assert [p["name"] for p in rep["plans"]] == ["A.plan", "B.plan"]


def _edited(run: Path, tmp_path: Path, name: str, edit: Any) -> list[Path]:
    doc = json.loads((run / "plans" / name).read_text())
    edit(doc["mission"]["items"])
    (tmp_path / name).write_text(json.dumps(doc))
    return [tmp_path / name if p.name == name else p
            for p in sorted((run / "plans").glob("*.plan"))]


def test_a_deleted_viewpoint_loses_the_landmarks_it_alone_captured(
        run: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    name, item, alone = _only_by(run)

    def delete(items: list[dict[str, Any]]) -> None:
        assert items[item - 1]["command"] == 2000  # gimbal, waypoint, image, delay
        del items[item - 3:item + 1]

    code, rep = _import(run, _edited(run, tmp_path, name, delete), capsys)
    assert code == 3 and rep["lost"] == alone
    assert rep["summary"].endswith(f"; {len(alone)} LOST: {', '.join(map(str, alone))}")
    assert all(r["plan"] == "lost" for r in rep["landmarks"] if r["id"] in alone)


def test_a_moved_viewpoint_loses_the_landmarks_it_alone_captured(
        run: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    name, item, alone = _only_by(run)

    def move(items: list[dict[str, Any]]) -> None:
        waypoint = items[item - 2]
        assert waypoint["command"] == 16
        waypoint["params"][5] += 0.0004  # ~30 m east, in QGroundControl's map
    code, rep = _import(run, _edited(run, tmp_path, name, move), capsys)
    assert code == 3 and set(alone) <= set(rep["lost"])
    capsys.readouterr()
    assert main(["import-plan", str(run), *map(str, _edited(run, tmp_path, name, move)),
                 "--origin", ORIGIN, "--scenario", SCENARIO]) == 3
    out = capsys.readouterr().out.splitlines()
    assert out[0].startswith("import-plan: 2 plans, ") and "LOST" in out[0]
    assert out[1].split() == ["landmark", "run", "plans", "quality", "image"]


def _plan(items: list[dict[str, Any]]) -> dict[str, Any]:
    return {"fileType": "Plan", "mission": {"plannedHomePosition": [47.3977, 8.5456, 490.0],
                                            "items": items}}


def _item(command: int, frame: int, params: list[float | None]) -> dict[str, Any]:
    return {"type": "SimpleItem", "command": command, "frame": frame, "params": params,
            "autoContinue": True}


def test_an_image_is_taken_at_the_last_waypoint_along_the_last_gimbal_setting() -> None:
    """Relative altitude is above home (2 m above the origin here); a gimbal yaw without
    YAW_LOCK turns with the vehicle's heading; QGC's DO_MOUNT_CONTROL too; an image with no
    known heading is left out with a warning."""
    items = [
        _item(16, 3, [0, 0.5, 0, 90.0, 47.3977, 8.5456, 3.0]),  # heading east, 5 m up
        _item(1000, 2, [-30.0, 0.0, None, None, 16, 0, 0]),  # locked yaw: north
        _item(2000, 2, [0, 0, 1, 0, None, None, None]),
        _item(1000, 2, [0.0, 90.0, None, None, 12, 0, 0]),  # relative: east + 90 = south
        _item(2000, 2, [0, 0, 1, 0, None, None, None]),
        _item(205, 2, [-90.0, 0, 0.0, 0, 0, 0, 2]),  # mount control: straight down
        _item(203, 2, [0, 0, 0, 0, 1, 0, 0]),  # digicam shot
        _item(16, 0, [0, 0.5, 0, None, 47.3977, 8.5456, 500.0]),  # AMSL, no heading
        _item(1000, 2, [0.0, 10.0, None, None, 12, 0, 0]),
        _item(2000, 2, [0, 0, 1, 0, None, None, None]),
    ]
    got = plan_images(_plan(items), WHERE, "X.plan")
    assert [im.label for im in got.images] == ["X.plan#1", "X.plan#2", "X.plan#3"]
    assert [im.item for im in got.images] == [3, 5, 7]
    np.testing.assert_allclose(got.images[0].position, [0.0, 0.0, 5.0], atol=1e-6)
    np.testing.assert_allclose(got.images[0].direction, camera_direction(0.0, -30.0))
    np.testing.assert_allclose(got.images[1].direction, [0.0, -1.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(got.images[2].direction, [0.0, 0.0, -1.0], atol=1e-12)
    assert got.warnings == ["X.plan: image 4 (item 10): the camera's heading is unknown "
                            "(gimbal yaw relative to a vehicle heading the plan leaves to "
                            "the autopilot): not counted"]
    np.testing.assert_allclose(camera_direction(90.0, 0.0), [1.0, 0.0, 0.0], atol=1e-12)
    assert math.isclose(float(np.linalg.norm(camera_direction(123.0, -47.0))), 1.0)


@pytest.mark.parametrize(("content", "why"), [
    ("{", "not a plan: cannot read it as JSON: Expecting property name enclosed in double "
          "quotes: line 1 column 2 (char 1)"),
    ('{"fileType": "Mission"}', 'not a QGroundControl plan (no "fileType": "Plan")'),
    ('{"fileType": "Plan", "mission": {}}',
     "mission.items: missing (a plan holds a mission with a list of items)"),
    (json.dumps(_plan([_item(16, 3, [0, 0, 0])])),
     "item 1: params must be a list of 7 numbers (null for none)"),
    (json.dumps(_plan([_item(16, 10, [0, 0, 0, 0, 47.0, 8.0, 5.0])])),
     "item 1: frame 10 is not supported (0 or 5: AMSL, 3 or 6: relative to home)"),
    (json.dumps(_plan([{"type": "ComplexItem", "complexItemType": "survey"}])),
     "item 1: type 'ComplexItem' is not supported (only SimpleItem: complex items such as "
     "surveys are not read)"),
])
def test_a_malformed_plan_is_one_line_and_exit_2(
        run: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str], content: str,
        why: str) -> None:
    bad = tmp_path / "bad.plan"
    bad.write_text(content)
    capsys.readouterr()
    assert main(["import-plan", str(run), str(bad), "--origin", ORIGIN, "--scenario",
                 SCENARIO]) == 2
    out, err = capsys.readouterr()
    assert out == "" and err == f"viscover: error: {bad}: {why}\n"


def test_without_a_scenario_or_an_origin_it_says_what_to_give(
        run: Path, capsys: pytest.CaptureFixture[str]) -> None:
    plan = str(run / "plans" / "A.plan")
    capsys.readouterr()
    assert main(["import-plan", str(run), plan, "--origin", ORIGIN]) == 2
    assert capsys.readouterr().err == (
        f"viscover: error: {run}: the run names no scenario file: give --scenario FILE (the "
        "run's scenario: its capture spec and structure)\n")
    assert main(["import-plan", str(run), plan, "--scenario", SCENARIO]) == 2
    assert capsys.readouterr().err == (
        "viscover: error: --origin LAT,LON,ALT is required: the one export-plan was given "
        "(the geodetic position of the world frame's origin)\n")
