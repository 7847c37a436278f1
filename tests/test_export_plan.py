"""``viscover export-plan``: captures → routes (agent.flight.refly) → QGroundControl .plan
documents (agent.flight.qgc_plan), checked against the logged captures and QGC's documented
schema; the command's user errors."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from agent.cli import main
from agent.flight import qgc_plan as qp
from agent.flight.geodetic import Origin, geodetic_to_enu
from agent.flight.refly import NO_CAPTURES, Route, Viewpoint, Waypoint, fences, plan_routes
from tests.plan_helpers import ORIGIN, inspection_doc

WHERE = Origin(*ORIGIN)
ORIGIN_ARG = ",".join(str(v) for v in ORIGIN)


def plans_of(doc: dict[str, Any]) -> dict[str, dict[str, Any]]:
    routes = plan_routes(doc)
    fence = fences(doc, routes)
    return {r.agent: json.loads(json.dumps(qp.plan_document(r, fence, WHERE), allow_nan=False))
            for r in routes}


def enu_of(item: dict[str, Any]) -> np.ndarray:
    lat, lon, alt = item["params"][4:7]
    return geodetic_to_enu(lat, lon, WHERE.alt + alt, WHERE)


def check_schema(plan: dict[str, Any]) -> None:
    """The fields QGC's loader and MAVSDK's importer require (QGC dev guide, MissionItem::load,
    MissionImport::parse_json)."""
    assert plan["fileType"] == "Plan" and plan["version"] == 1
    m = plan["mission"]
    assert m["version"] == 2 and m["firmwareType"] in (3, 12) and m["vehicleType"] == 2
    assert {"cruiseSpeed", "hoverSpeed", "globalPlanAltitudeMode"} <= set(m)
    assert len(m["plannedHomePosition"]) == 3 and m["items"]
    for k, item in enumerate(m["items"], start=1):
        assert item["type"] == "SimpleItem" and item["autoContinue"] is True
        assert item["doJumpId"] == k
        assert isinstance(item["command"], int) and isinstance(item["frame"], int)
        assert len(item["params"]) == 7
        assert all(p is None or isinstance(p, float) for p in item["params"])
        if item["frame"] == qp.MAV_FRAME_GLOBAL_RELATIVE_ALT:
            assert item["AltitudeMode"] == 1 and item["Altitude"] == item["params"][6]
            assert item["AMSLAltAboveTerrain"] is None
    fence = plan["geoFence"]
    assert fence["version"] == 2 and fence["circles"] == []
    for poly in fence["polygons"]:
        assert poly["version"] == 1 and isinstance(poly["inclusion"], bool)
        pts = np.array(poly["polygon"])  # [lat, lon]
        assert pts.shape == (4, 2)
        x, y = pts[:, 1], pts[:, 0]  # clockwise seen from above: negative signed area
        assert 0.5 * np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y) < 0.0
    assert plan["rallyPoints"] == {"version": 2, "points": []}


def test_waypoints_are_the_logged_capture_positions() -> None:
    doc = inspection_doc(crossing=True)
    plans = plans_of(doc)
    assert list(plans) == ["A", "B"]
    for agent, plan in plans.items():
        check_schema(plan)
        items = plan["mission"]["items"]
        rows = [c for c in doc["captures"] if c["agent"] == agent]
        shots = [k for k, it in enumerate(items) if it["command"] == qp.MAV_CMD_IMAGE_START_CAPTURE]
        assert len(shots) == len(rows)
        for k, row in zip(shots, rows, strict=True):
            gimbal, wp, cam = items[k - 2], items[k - 1], items[k]
            assert gimbal["command"] == qp.MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW
            assert wp["command"] == qp.MAV_CMD_NAV_WAYPOINT
            assert np.max(np.abs(enu_of(wp) - row["position"])) < 1e-3
            d = np.array(row["direction"])
            heading = math.degrees(math.atan2(d[0], d[1])) % 360.0
            assert wp["params"][3] == pytest.approx(heading, abs=1e-6)
            pitch, yaw = gimbal["params"][:2]
            assert pitch == pytest.approx(math.degrees(math.asin(d[2])), abs=1e-6)
            assert yaw == pytest.approx(heading - 360.0 if heading > 180.0 else heading, abs=1e-6)
            assert gimbal["params"][2:] == [None, None, 28.0, 0.0, 0.0]
            assert gimbal["frame"] == cam["frame"] == qp.MAV_FRAME_MISSION
            assert cam["params"] == [0.0, 0.0, 1.0, 0.0, None, None, None]
        assert items[0]["command"] == qp.MAV_CMD_NAV_TAKEOFF
        assert items[-1]["command"] == qp.MAV_CMD_NAV_LAND
        start = np.array(doc["initial_poses"][agent]["position"])
        assert np.allclose(enu_of(items[0]), start, atol=1e-3)
        assert np.allclose(enu_of(items[-2]), start, atol=1e-3)  # back above the launch point
        assert np.allclose(enu_of(items[-1]), [start[0], start[1], 0.0], atol=1e-3)
        home = plan["mission"]["plannedHomePosition"]
        assert np.allclose(geodetic_to_enu(home[0], home[1], home[2], WHERE),
                           [start[0], start[1], 0.0], atol=1e-3)


def test_a_leg_through_the_structure_climbs_over_it() -> None:
    """A flies from the cube's south side to its north side: two transit waypoints above the
    roof (top landmark 4 m + 2 m), yaw unset; the other legs stay straight."""
    items = plans_of(inspection_doc(crossing=True))["A"]["mission"]["items"]
    transit = [enu_of(it) for it in items if it["command"] == qp.MAV_CMD_NAV_WAYPOINT
               and it["params"][3] is None]
    assert len(transit) == 3  # two over the roof, one back above the start
    assert np.allclose(transit[0], [2.0, -4.0, 6.0], atol=1e-3)
    assert np.allclose(transit[1], [2.0, 8.0, 6.0], atol=1e-3)
    plain = plans_of(inspection_doc(crossing=False))["A"]["mission"]["items"]
    assert sum(it["params"][3] is None for it in plain
               if it["command"] == qp.MAV_CMD_NAV_WAYPOINT) == 1


def test_fences() -> None:
    """Inclusion: the space's rectangle 1 m in; exclusion: the cube's footprint, only when no
    route comes over it."""
    plan = plans_of(inspection_doc(crossing=False))["B"]
    polys = plan["geoFence"]["polygons"]
    assert [p["inclusion"] for p in polys] == [True, False]
    inc_ll, exc_ll = (np.array(polys[k]["polygon"]).T for k in (0, 1))
    inc = geodetic_to_enu(inc_ll[0], inc_ll[1], WHERE.alt, WHERE)
    exc = geodetic_to_enu(exc_ll[0], exc_ll[1], WHERE.alt, WHERE)
    assert np.allclose(inc[:, :2], [[-9, -9], [-9, 13], [13, 13], [13, -9]], atol=1e-3)
    assert np.allclose(exc[:, :2], [[0, 0], [0, 4], [4, 4], [4, 0]], atol=1e-3)
    crossing = plans_of(inspection_doc(crossing=True))
    assert [p["inclusion"] for p in crossing["A"]["geoFence"]["polygons"]] == [True]
    assert crossing["A"]["geoFence"] == crossing["B"]["geoFence"]


def test_mavlink_constants_match_pymavlink() -> None:
    from agent.wire.mavlink import mavlink

    for name in ("MAV_FRAME_MISSION", "MAV_FRAME_GLOBAL_RELATIVE_ALT", "MAV_CMD_NAV_WAYPOINT",
                 "MAV_CMD_NAV_LAND", "MAV_CMD_NAV_TAKEOFF", "MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW",
                 "MAV_CMD_IMAGE_START_CAPTURE", "GIMBAL_MANAGER_FLAGS_YAW_LOCK",
                 "GIMBAL_MANAGER_FLAGS_PITCH_LOCK", "GIMBAL_MANAGER_FLAGS_ROLL_LOCK",
                 "MAV_TYPE_QUADROTOR"):
        assert getattr(qp, name) == getattr(mavlink, name), name
    assert qp.AUTOPILOTS == {"ardupilot": mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA,
                             "px4": mavlink.MAV_AUTOPILOT_PX4}


def test_no_captures_is_refused() -> None:
    doc = inspection_doc()
    doc["captures"] = []
    with pytest.raises(ValueError, match="no captures to re-fly"):
        plan_routes(doc)


# -- the command -------------------------------------------------------------------------------


def write_run(folder: Path, doc: dict[str, Any]) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "result.json").write_text(json.dumps(doc), encoding="utf-8")
    return folder


def test_cli_writes_one_plan_per_drone(tmp_path: Path,
                                       capsys: pytest.CaptureFixture[str]) -> None:
    run = write_run(tmp_path / "run" / "report", inspection_doc(crossing=True)).parent
    assert main(["export-plan", str(run), "--origin", ORIGIN_ARG, "--autopilot",
                 "ardupilot"]) == 0
    cap = capsys.readouterr()
    assert sorted(p.name for p in (run / "plans").iterdir()) == ["A.plan", "B.plan"]
    assert "A.plan: 3 viewpoints" in cap.out and "B.plan: 2 viewpoints" in cap.out
    assert "no exclusion fence" in cap.err
    plan = json.loads((run / "plans" / "A.plan").read_text())
    check_schema(plan)
    assert plan["mission"]["firmwareType"] == 3
    out = tmp_path / "elsewhere"
    sim = write_run(tmp_path / "sim", inspection_doc(crossing=False))
    assert main(["export-plan", str(sim), "--origin", ORIGIN_ARG, "--out", str(out)]) == 0
    assert sorted(p.name for p in out.iterdir()) == ["A.plan", "B.plan"]
    assert capsys.readouterr().err == ""


@pytest.mark.parametrize("case, needle", [
    ("coverage", NO_CAPTURES),
    ("no_origin", "--origin LAT,LON,ALT is required: the scenario carries no geodetic origin"),
    ("missing", "no such folder"),
    ("empty", "no result.json here or in report/"),
    ("garbage", "cannot read it as JSON"),
])
def test_cli_user_errors(tmp_path: Path, capsys: pytest.CaptureFixture[str], case: str,
                         needle: str) -> None:
    doc = inspection_doc()
    run = tmp_path / "run"
    if case == "coverage":
        doc["captures"] = []
    if case not in ("missing", "empty"):
        write_run(run, doc)
    if case == "empty":
        run.mkdir()
    if case == "garbage":
        (run / "result.json").write_text("{not json")
    argv = ["export-plan", str(run)] + ([] if case == "no_origin" else ["--origin", ORIGIN_ARG])
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert needle in err and "Traceback" not in err
    assert len(err.strip().splitlines()) == 1


@pytest.mark.parametrize("bad", ["47.4,8.5", "47.4,8.5,x", "95,8.5,400", "nan,8,1"])
def test_cli_bad_origin(tmp_path: Path, capsys: pytest.CaptureFixture[str], bad: str) -> None:
    run = write_run(tmp_path / "run", inspection_doc())
    assert main(["export-plan", str(run), f"--origin={bad}"]) == 2
    err = capsys.readouterr().err
    assert "--origin" in err and "LAT,LON,ALT" in err and "Traceback" not in err


def _route(*views: tuple[float, float]) -> Route:
    """A route whose viewpoints have (heading, pitch) [degrees]."""
    wps = [Waypoint(np.array([float(k), 0.0, 3.0]),
                    Viewpoint(np.array([float(k), 0.0, 3.0]), h, p, float(k), (k,)))
           for k, (h, p) in enumerate(views)]
    return Route("A", np.zeros(3), 3.0, wps)


def test_each_hold_covers_the_gimbals_turn_from_the_previous_viewpoint() -> None:
    """At 60 degrees/s: the first viewpoint from level and any yaw (180 degrees: 3 s), then
    the larger of the two axes' turns (yaw the short way round), never less than --hold;
    a NaN heading leaves the yaw where it was."""
    route = _route((90.0, -30.0), (350.0, -30.0), (10.0, -80.0), (math.nan, -90.0),
                   (20.0, -90.0))
    holds = qp.viewpoint_holds(route, 1.0, 60.0)
    assert holds == pytest.approx([3.0, 100.0 / 60.0, 1.0, 1.0, 1.0])
    assert qp.viewpoint_holds(route, 1.0, None) == [1.0] * 5
    assert qp.viewpoint_holds(route, 0.5, 30.0)[1] == pytest.approx(100.0 / 30.0)
    items = qp.mission_items(route, Origin(*ORIGIN), hold=1.0, gimbal_rate=60.0)
    waypoints = [i for i in items if i["command"] == qp.MAV_CMD_NAV_WAYPOINT]
    assert [w["params"][0] for w in waypoints] == pytest.approx(holds)
