"""A periodic inspection flown again in stock AUTO and compared (issue 23): a small simulated
inspection run (``viscover simulate``) is exported as QGroundControl plans (``viscover
export-plan``), each plan is uploaded to a simulated vehicle with a standard client (pymavlink's
mission protocol for ArduPilot, MAVSDK ``mission_raw`` import, upload and start for PX4), armed
and flown to the end, outdoors on RTK at the plan's origin. Checked: every waypoint reached in
order within its acceptance radius; one image per capture item, taken there, with the gimbal
at the item's pitch (ArduPilot: CAMERA_FEEDBACK and the gimbal device's attitude; PX4:
CAMERA_IMAGE_CAPTURED's camera attitude); the vehicle landed at its launch point and disarmed;
and each image, from its logged pose, captures (:mod:`agent.core.inspection`) the landmarks the
original run's capture at that viewpoint did."""

from __future__ import annotations

import asyncio
import json
import math
import socket
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from numpy.typing import NDArray

from agent.cli import main
from agent.clock import WallClock
from agent.core.inspection import CaptureSpec, capture_quality, captured_mask
from agent.flight import qgc_plan as qp
from agent.flight.frames import euler_from_quat
from agent.flight.geodetic import Origin, geodetic_to_enu
from agent.wire.mavlink import mavutil, px4_custom_mode
from groundstation.vehicle.fleet import SimFleet
from groundstation.vehicle.params import VehicleParams
from tests.sim_vehicle_helpers import (
    Flown,
    M,
    command,
    fly,
    hello,
    plan_mission,
    upload_mission,
)
from tests.vehicle_harness import Harness

Array = NDArray[np.float64]
P_MISSION = px4_custom_mode(4, 4)
ORIGIN = (47.3977419, 8.545594, 488.0)  #: lat, lon [deg], alt [m] of the world origin (ENU)
WHERE = Origin(*ORIGIN)
#: A 2 m box of landmarks (four walls and the roof) inspected by two drones; a scenario of
#: generated landmarks has no occlusion, so the capture test needs no ray caster.
SCENARIO = """\
name = "refly_box"
dims = 3
seed = 0
d_opt = 3.0
duration = 120.0

[space]
lo = [-8.0, -8.0, 0.5]
hi = [8.0, 8.0, 8.0]

[planner]
dt = 0.1
p_lim = 1.5
p_min = 0.05
r_s = 2.0
d_w = 1.0

[[generators]]
kind = "box"
center = [0.0, 0.0, 2.0]
size = 2.0
faces = ["+x", "-x", "+y", "-y", "+z"]
count = 3

[inspection]
quality = 0.3
fov_deg = [90.0, 70.0]

[[agents]]
id = "A"
position = [-5.0, -2.0, 2.0]
yaw = 0.0
landmarks = [1, 2, 3, 4, 5, 6, 7, 8]

[[agents]]
id = "B"
position = [5.0, 2.0, 2.0]
yaw = 3.14
landmarks = [9, 10, 11, 12, 13, 14, 15]
"""
SPEC = CaptureSpec(quality=0.3, fov=(math.radians(90.0), math.radians(70.0)))


@dataclass
class Original:
    """The original run: its folder, ``result.json`` and the landmarks (ids, q, u [m; ENU])."""

    run: Path
    doc: dict[str, Any]
    ids: list[int]
    q: Array
    u: Array
    d_opt: float


@pytest.fixture(scope="module")
def original(tmp_path_factory: pytest.TempPathFactory) -> Original:
    """The inspection flown once in the simulator (``viscover simulate``)."""
    folder = tmp_path_factory.mktemp("refly")
    scenario = folder / "refly_box.toml"
    scenario.write_text(SCENARIO, encoding="utf-8")
    run = folder / "run"
    assert main(["simulate", str(scenario), "--out", str(run), "--no-plots", "--quiet"]) == 0
    doc = json.loads((run / "result.json").read_text(encoding="utf-8"))
    assert doc["inspection"]["captured"] and len(doc["captures"]) >= 4
    rows = doc["landmarks"]
    return Original(run, doc, [int(r["id"]) for r in rows],
                    np.array([r["position"] for r in rows], dtype=np.float64),
                    np.array([r["normal"] for r in rows], dtype=np.float64),
                    float(doc["d_opt"]))


#: Hold at each viewpoint [s]: the simulated gimbal turns at 60 °/s (VehicleParams
#: gimbal_rate), and at the first viewpoint, right above the launch point, ArduCopter still
#: faces where it was put down: its gimbal may have to turn the camera by up to 180° there.
HOLD = 3.0


def plans(original: Original, autopilot: str) -> dict[str, Path]:
    """``viscover export-plan`` of the original run: one plan per drone."""
    out = original.run / f"plans_{autopilot}"
    argv = ["export-plan", str(original.run), "--origin", ",".join(map(str, ORIGIN)),
            "--autopilot", autopilot, "--out", str(out), "--hold", str(HOLD)]
    assert main(argv) == 0
    return {p.stem: p for p in sorted(out.glob("*.plan"))}


#: How far a re-flown image's logged pose may be from the viewpoint: the RTK-fixed EKF's error
#: (VehicleParams gnss="rtk": 1σ noise 1 / 1.5 cm, drift 2 / 3 cm, yaw 0.005 rad) and the
#: position controller's, about 3σ [m], [rad].
POS_TOL, ANG_TOL = 0.1, math.radians(1.0)


def captured(original: Original, position: Array, direction: Array) -> set[int]:
    """The landmarks a camera at ``position`` looking along ``direction`` [m; ENU] captures
    (the project's own capture test: eq. 3.1 with the field of view)."""
    return set.intersection(*captured_around(original, position, direction, 0.0, 0.0))


def captured_around(original: Original, position: Array, direction: Array, dp: float,
                    da: float) -> list[set[int]]:
    """What each pose within ``dp`` [m] (each axis) and ``da`` [rad] (pitch, heading) of the
    camera (``position``, ``direction`` [m; ENU]) captures: the pose itself and the corners."""
    d = direction / np.linalg.norm(direction)
    pitch, heading = math.asin(max(-1.0, min(1.0, float(d[2])))), math.atan2(d[0], d[1])
    poses = [(position + np.array(s) * dp, axis(pitch + a, heading + b))
             for s in ((0, 0, 0), *((x, y, z) for x in (-1, 1) for y in (-1, 1)
                                     for z in (-1, 1)))
             for a, b in ((0.0, 0.0), (da, da), (da, -da), (-da, da), (-da, -da))]
    P = np.array([p for p, _ in poses])
    V = np.array([v for _, v in poses])
    mask = captured_mask(capture_quality(P, V, original.q, original.u, original.d_opt, SPEC),
                         None, SPEC)
    return [{original.ids[j] for j in np.flatnonzero(row)} for row in mask]


def launch_of(original: Original, agent: str) -> Array:
    """The drone's launch point [m; ENU]: on the ground below its start."""
    start = np.array(original.doc["initial_poses"][agent]["position"], dtype=np.float64)
    return np.array([start[0], start[1], 0.0])


def viewpoints(plan: dict[str, Any]) -> list[tuple[int, Array, float, float]]:
    """Each capture item's waypoint: (its seq in the uploaded mission, position [m; ENU], the
    gimbal item's pitch [deg], acceptance radius [m])."""
    items = plan["mission"]["items"]
    offset = 1 if plan["mission"]["firmwareType"] == qp.AUTOPILOTS["ardupilot"] else 0
    out = []
    for k, it in enumerate(items):
        if it["command"] != qp.MAV_CMD_IMAGE_START_CAPTURE:
            continue
        wp, gimbal = items[k - 1], items[k - 2]
        assert wp["command"] == qp.MAV_CMD_NAV_WAYPOINT
        assert gimbal["command"] == qp.MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW
        lat, lon, alt = wp["params"][4:7]
        out.append((k - 1 + offset, geodetic_to_enu(lat, lon, WHERE.alt + alt, WHERE),
                    float(gimbal["params"][0]), float(wp["params"][1])))
    return out


def enu_of_ned(p: Array) -> Array:
    """A local NED position [m] (the vehicles' EKF origin is the world origin) as ENU."""
    return np.array([p[1], p[0], -p[2]])


def axis(pitch: float, yaw: float) -> Array:
    """The optical axis [ENU] of a camera pitched ``pitch`` [rad, + up] with heading ``yaw``
    [rad; NED, from north] and no roll."""
    return np.array([math.cos(pitch) * math.sin(yaw), math.cos(pitch) * math.cos(yaw),
                     math.sin(pitch)])


def check_flight(original: Original, agent: str, plan: dict[str, Any], reached: list[int],
                 where: dict[int, Array], images: list[tuple[Array, Array, float]],
                 end: Array, armed: bool) -> None:
    """What the re-flown plan must show (module docstring): ``where`` the true position [m;
    ENU] at each MISSION_ITEM_REACHED, ``images`` each image's logged (position [m; ENU],
    optical axis [ENU], gimbal pitch [deg]), ``end`` where the vehicle stopped."""
    views = viewpoints(plan)
    home = 1 if plan["mission"]["firmwareType"] == qp.AUTOPILOTS["ardupilot"] else 0
    wps = [seq for seq, it in enumerate(plan_mission(plan))
           if it.command == qp.MAV_CMD_NAV_WAYPOINT and seq >= home]
    assert [s for s in reached if s in wps] == wps, f"{agent}: waypoints {reached}"
    for seq, point, _pitch, radius in views:
        assert np.linalg.norm(where[seq] - point) <= radius, f"{agent}: item {seq} not reached"
    assert len(images) == len(views), f"{agent}: {len(images)} images for {len(views)} items"
    rows = [c for c in original.doc["captures"] if c["agent"] == agent]
    assert len(rows) == len(views)
    for (seq, point, pitch, radius), (pos, axis_, gimbal_pitch), row in \
            zip(views, images, rows, strict=True):
        assert np.linalg.norm(pos - point) <= radius, f"{agent}: image of item {seq} elsewhere"
        assert gimbal_pitch == pytest.approx(pitch, abs=1.0)
        p0, v0 = np.array(row["position"]), np.array(row["direction"])
        assert set(row["landmarks"]) <= captured(original, p0, v0)  # the original, re-checked
        # The same landmarks, but for those the original pose images at the quality threshold
        # (captured from some pose within the error budget and not from another).
        around = captured_around(original, p0, v0, POS_TOL, ANG_TOL)
        sure, maybe = set.intersection(*around), set.union(*around)
        again = captured(original, pos, axis_)
        assert sure <= again <= maybe, \
            f"{agent} item {seq}: {sorted(sure)} .. {sorted(maybe)}, got {sorted(again)}"
    assert not armed and end[2] < 0.05
    assert np.linalg.norm(end[:2] - launch_of(original, agent)[:2]) < 0.3


def fly_ardupilot(original: Original, agent: str, path: Path) -> None:
    """pymavlink's mission protocol (the plan's items as MAVSDK imports them, home first),
    GUIDED, arm, MAV_CMD_MISSION_START; on the manual clock."""
    plan = json.loads(path.read_text(encoding="utf-8"))
    params = VehicleParams(autopilot="ardupilot", payload=True, gnss="rtk", origin=ORIGIN)
    with hello(Harness(params, start=launch_of(original, agent)[None, :])) as h:
        h.run(1.0)  # a moment on the ground, as after power-up
        assert upload_mission(h, plan_mission(plan)) == M.MAV_MISSION_ACCEPTED
        assert h.set_mode(4) == M.MAV_RESULT_ACCEPTED
        assert h.arm() == M.MAV_RESULT_ACCEPTED
        assert command(h, M.MAV_CMD_MISSION_START, 0, 0).result == M.MAV_RESULT_ACCEPTED
        run: Flown = fly(h, 300.0, lambda h: not h.quad.armed)
        images = []
        for shot, pitch, gyaw in zip(run.shots, run.shot_pitch, run.shot_gimbal_yaw,
                                     strict=True):
            assert shot.get_type() == "CAMERA_FEEDBACK"
            pos = geodetic_to_enu(shot.lat / 1e7, shot.lng / 1e7, shot.alt_msl, WHERE)
            heading = math.radians(shot.yaw + gyaw)  # vehicle yaw + the gimbal's (body frame)
            images.append((pos, axis(math.radians(pitch), heading), pitch))
        check_flight(original, agent, plan, run.seqs,
                     {s: enu_of_ned(p) for s, p in run.reached}, images,
                     enu_of_ned(h.fleet.p[0]), h.quad.armed)
        assert h.fleet.handler_errors == 0


@pytest.mark.slow
def test_an_exported_plan_is_flown_again_in_ardupilot_auto(original: Original) -> None:
    for agent, path in plans(original, "ardupilot").items():
        fly_ardupilot(original, agent, path)


#: PX4's flights run on the wall clock (MAVSDK's own timers) this many times faster.
TIME_SCALE = 4.0


def _free_port(kind: int) -> int:
    with socket.socket(socket.AF_INET, kind) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def fly_px4(original: Original, agent: str, path: Path, mavsdk: Any) -> None:
    """MAVSDK: ``mission_raw.import_qgroundcontrol_mission`` of the plan file,
    ``upload_mission``, ``action.arm``, ``mission_raw.start_mission``; a pymavlink listener
    logs what the vehicle sends. The fleet runs on the wall clock, :data:`TIME_SCALE` times
    faster."""
    plan = json.loads(path.read_text(encoding="utf-8"))
    params = VehicleParams(autopilot="px4", payload=True, gnss="rtk", origin=ORIGIN)
    fleet = SimFleet([agent], WallClock(TIME_SCALE), params,
                     start=launch_of(original, agent)[None, :])
    port = fleet.quads[0].port
    listener = mavutil.mavlink_connection(f"udpout:127.0.0.1:{port}", source_system=250,
                                          source_component=190)
    reached: list[int] = []
    where: dict[int, Array] = {}
    images: list[tuple[Array, Array, float]] = []

    def listen() -> None:
        while (m := listener.recv_match(blocking=False)) is not None:
            if m.get_type() == "MISSION_ITEM_REACHED":
                reached.append(int(m.seq))
                where[int(m.seq)] = fleet.position_enu(0)
            elif m.get_type() == "CAMERA_IMAGE_CAPTURED":
                _r, pitch, yaw = euler_from_quat(np.array(m.q, dtype=np.float64))
                pos = geodetic_to_enu(m.lat / 1e7, m.lon / 1e7, m.alt / 1000.0, WHERE)
                images.append((pos, axis(pitch, yaw), math.degrees(pitch)))

    async def body() -> None:
        system = mavsdk.System(port=_free_port(socket.SOCK_STREAM))
        try:
            await asyncio.wait_for(system.connect(system_address=f"udpout://127.0.0.1:{port}"),
                                   30.0)
            data = await system.mission_raw.import_qgroundcontrol_mission(str(path))
            await system.mission_raw.upload_mission(data.mission_items)
            await system.action.arm()
            await system.mission_raw.start_mission()
            deadline = time.monotonic() + 300.0 / TIME_SCALE
            while time.monotonic() < deadline and (fleet.quads[0].armed or not reached):
                listener.mav.heartbeat_send(M.MAV_TYPE_GCS, M.MAV_AUTOPILOT_INVALID, 0, 0, 0)
                listen()
                await asyncio.sleep(0.005)
            listen()
        finally:
            system._stop_mavsdk_server()

    try:
        fleet.start()
        listener.mav.heartbeat_send(M.MAV_TYPE_GCS, M.MAV_AUTOPILOT_INVALID, 0, 0, 0)
        asyncio.run(asyncio.wait_for(body(), 400.0 / TIME_SCALE))
        check_flight(original, agent, plan, reached, where, images, fleet.position_enu(0),
                     fleet.quads[0].armed)
        assert fleet.quads[0].mode == P_MISSION  # landed in the mission: COM_DISARM_LAND
        assert fleet.handler_errors == 0
    finally:
        listener.close()
        fleet.close()


@pytest.mark.slow
@pytest.mark.long  # a whole AUTO mission through MAVSDK (about 22 s): make test-long
@pytest.mark.filterwarnings("ignore:path is deprecated:DeprecationWarning")  # mavsdk_grpc's
def test_an_exported_plan_is_flown_again_in_px4_mission_mode(original: Original) -> None:
    mavsdk = pytest.importorskip("mavsdk_grpc")
    for agent, path in plans(original, "px4").items():
        fly_px4(original, agent, path, mavsdk)
