"""The exported .plan files read by MAVSDK: ``mission_raw.import_qgroundcontrol_mission`` of the
gRPC wrapper's own ``mavsdk_server`` (package ``mavsdk-grpc``, the ``mavsdk`` < 4 API under a new
name; the server ships in the wheel).

``mavsdk_server`` serves nothing until it has discovered a vehicle, so a stand-in sends
HEARTBEATs (pymavlink) to its UDP port; the HEARTBEAT's autopilot decides how MAVSDK imports
(ArduPilot: the planned home position becomes mission item 0)."""

from __future__ import annotations

import asyncio
import json
import math
import socket
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from agent.cli import main
from agent.flight import qgc_plan as qp
from tests.plan_helpers import ORIGIN, inspection_doc

mavsdk = pytest.importorskip("mavsdk_grpc")

MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION = 5001
MAV_CMD_NAV_FENCE_POLYGON_VERTEX_EXCLUSION = 5002


def free_port(kind: int) -> int:
    with socket.socket(socket.AF_INET, kind) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@pytest.fixture
def vehicle_heartbeat() -> Iterator[tuple[int, list[int]]]:
    """A UDP port that receives a HEARTBEAT every 0.2 s, from the autopilot put in the list."""
    from agent.wire.mavlink import mavlink, mavutil

    port, autopilot, stop = free_port(socket.SOCK_DGRAM), [mavlink.MAV_AUTOPILOT_PX4], \
        threading.Event()

    def beat() -> None:
        link = mavutil.mavlink_connection(f"udpout:127.0.0.1:{port}", source_system=1,
                                          source_component=1)
        try:
            while not stop.is_set():
                link.mav.heartbeat_send(mavlink.MAV_TYPE_QUADROTOR, autopilot[0], 0, 0,
                                        mavlink.MAV_STATE_STANDBY)
                stop.wait(0.2)
        finally:
            link.close()

    thread = threading.Thread(target=beat, daemon=True)
    thread.start()
    yield port, autopilot
    stop.set()
    thread.join(5.0)


def import_plans(paths: list[Path], udp_port: int) -> list[Any]:
    """Each file through mavsdk_server's QGC importer (one server for all)."""

    async def run() -> list[Any]:
        system = mavsdk.System(port=free_port(socket.SOCK_STREAM))
        try:
            await asyncio.wait_for(system.connect(system_address=f"udpin://127.0.0.1:{udp_port}"),
                                   30.0)
            return [await asyncio.wait_for(
                system.mission_raw.import_qgroundcontrol_mission(str(p)), 30.0) for p in paths]
        finally:
            system._stop_mavsdk_server()  # kills the server process this System started

    return asyncio.run(run())


def check_import(plan: dict[str, Any], data: Any, ardupilot: bool) -> None:
    """MAVSDK's items are the plan's: commands, frames, lat/lon to 1e-7°, altitudes, the gimbal
    and camera params, the fence vertices."""
    items = list(data.mission_items)
    mission = plan["mission"]
    if ardupilot:  # the planned home position as item 0 (MAV_FRAME_GLOBAL_INT, AMSL)
        home, items = items[0], items[1:]
        lat, lon, alt = mission["plannedHomePosition"]
        assert home.command == qp.MAV_CMD_NAV_WAYPOINT and home.seq == 0
        assert abs(home.x / 1e7 - lat) <= 1e-7 and abs(home.y / 1e7 - lon) <= 1e-7
        assert home.z == pytest.approx(alt, abs=1e-3)
    assert len(items) == len(mission["items"])
    for got, want in zip(items, mission["items"], strict=True):
        assert (got.command, got.frame, got.autocontinue) == (want["command"], want["frame"], 1)
        p = [math.nan if v is None else v for v in want["params"]]
        for g, w in zip((got.param1, got.param2, got.param3, got.param4), p[:4], strict=True):
            assert (math.isnan(g) and math.isnan(w)) or g == pytest.approx(w, rel=1e-6, abs=1e-5)
        if want["frame"] == qp.MAV_FRAME_GLOBAL_RELATIVE_ALT:
            assert abs(got.x / 1e7 - p[4]) <= 1e-7 and abs(got.y / 1e7 - p[5]) <= 1e-7
            assert got.z == pytest.approx(p[6], abs=1e-5)
        else:  # MAV_FRAME_MISSION: params 5, 6 travel as integers (null as 0)
            assert (got.x, got.y) == tuple(0 if math.isnan(v) else int(v) for v in p[4:6])
            assert (math.isnan(got.z) and math.isnan(p[6])) or got.z == p[6]
    gimbals = [i for i in items if i.command == qp.MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW]
    shots = [i for i in items if i.command == qp.MAV_CMD_IMAGE_START_CAPTURE]
    assert len(gimbals) == len(shots) > 0
    assert all(math.isnan(g.param3) and g.x == qp.GIMBAL_FLAGS for g in gimbals)
    assert all(abs(g.param1) <= 90.0 and -180.0 < g.param2 <= 180.0 for g in gimbals)
    assert all((s.param1, s.param2, s.param3, s.param4) == (0, 0, 1, 0) for s in shots)
    fence = list(data.geofence_items)
    want_cmds = [MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION if poly["inclusion"]
                 else MAV_CMD_NAV_FENCE_POLYGON_VERTEX_EXCLUSION
                 for poly in plan["geoFence"]["polygons"] for _ in poly["polygon"]]
    assert [f.command for f in fence] == want_cmds
    vertices = [v for poly in plan["geoFence"]["polygons"] for v in poly["polygon"]]
    for f, (lat, lon) in zip(fence, vertices, strict=True):
        assert f.param1 == 4.0 and f.mission_type == 1
        assert abs(f.x / 1e7 - lat) <= 1e-7 and abs(f.y / 1e7 - lon) <= 1e-7
    assert list(data.rally_items) == []


@pytest.mark.filterwarnings("ignore:path is deprecated:DeprecationWarning")  # mavsdk_grpc's
@pytest.mark.parametrize("autopilot", ["px4", "ardupilot"])
def test_mavsdk_imports_every_exported_plan(tmp_path: Path, autopilot: str,
                                            vehicle_heartbeat: tuple[int, list[int]],
                                            capsys: pytest.CaptureFixture[str]) -> None:
    port, heartbeat = vehicle_heartbeat
    heartbeat[0] = qp.AUTOPILOTS[autopilot]
    paths = []
    for crossing in (True, False):
        run = tmp_path / f"run_{crossing}"
        run.mkdir()
        (run / "result.json").write_text(json.dumps(inspection_doc(crossing)), encoding="utf-8")
        assert main(["export-plan", str(run), "--origin", ",".join(map(str, ORIGIN)),
                     "--autopilot", autopilot]) == 0
        paths += sorted((run / "plans").glob("*.plan"))
    capsys.readouterr()
    assert len(paths) == 4
    imported = import_plans(paths, port)
    fences_seen = set()
    for path, data in zip(paths, imported, strict=True):
        plan = json.loads(path.read_text())
        check_import(plan, data, ardupilot=autopilot == "ardupilot")
        fences_seen.add(len(plan["geoFence"]["polygons"]))
    assert fences_seen == {1, 2}  # with and without the structure's exclusion polygon
