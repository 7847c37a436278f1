"""Fence storage over the mission protocol and breach behaviour of the simulated vehicles
(:mod:`groundstation.vehicle.fence`; sources: ArduPilot libraries/AC_Fence/AC_Fence.cpp,
AC_PolyFence_loader.cpp ``breached``, ArduCopter/fence.cpp ``fence_check``; PX4
src/modules/navigator/geofence_params.c (GF_ACTION), commander failsafe COM_FAIL_ACT_T), with
pymavlink on the manual clock and MAVSDK's geofence plugin on the wall clock."""

from __future__ import annotations

import math
import shutil
import subprocess
import sys
import threading
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import pytest

from agent.clock import WallClock
from agent.wire.mavlink import ARDUPILOT_MODES as APM
from agent.wire.mavlink import px4_custom_mode
from groundstation.vehicle.conventions import EARTH_RADIUS, ORIGIN
from groundstation.vehicle.fleet import SimFleet
from groundstation.vehicle.params import VehicleParams
from tests.conftest import stop_process
from tests.sim_vehicle_helpers import NAN, M, airborne, conf, hello, result, run_sdk
from tests.vehicle_harness import Harness

FENCE = M.MAV_MISSION_TYPE_FENCE
INC = M.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION
CIRC_EX = M.MAV_CMD_NAV_FENCE_CIRCLE_EXCLUSION
P_LOITER, P_RTL, P_LAND = px4_custom_mode(4, 3), px4_custom_mode(4, 5), px4_custom_mode(4, 6)
Item = tuple[int, float, float, float]  #: (command, param1, north [m], east [m])


def _latlon(autopilot: str, north: float, east: float) -> tuple[int, int]:
    """degE7 of a point north/east [m] of the flavour's EKF origin (flat earth)."""
    lat0, lon0, _ = ORIGIN[autopilot]
    k = 180.0 / (math.pi * EARTH_RADIUS)
    return (round((lat0 + north * k) * 1e7),
            round((lon0 + east * k / math.cos(math.radians(lat0))) * 1e7))


def square(half: float) -> list[Item]:
    """An inclusion square ±half [m] around the origin."""
    return [(INC, 4, n, e) for n, e in ((half, half), (half, -half), (-half, -half),
                                        (-half, half))]


def upload(h: Harness, items: Sequence[Item], frame: int = M.MAV_FRAME_GLOBAL_INT,
           mission_type: int = FENCE, bad_seq: bool = False) -> Any:
    """The mission protocol's upload; the final MISSION_ACK (its ``type``)."""
    ap = h.quad.flavour.name
    h.client.mav.mission_count_send(1, 1, len(items), mission_type)
    for _ in range(len(items) + 3):
        req = h.wait_for("MISSION_REQUEST_INT")
        if req is None:
            break
        if bad_seq and req.seq == 1:
            bad_seq = False  # send item 2 first: the vehicle asks for 1 again
            cmd, p1, n, e = items[2]
            h.client.mav.mission_item_int_send(1, 1, 2, frame, cmd, 0, 1, p1, 0, 0, 0,
                                               *_latlon(ap, n, e), 0, mission_type)
            continue
        cmd, p1, n, e = items[req.seq]
        x, y = _latlon(ap, n, e)
        h.client.mav.mission_item_int_send(1, 1, req.seq, frame, cmd, 0, 1, p1, 0, 0, 0, x, y,
                                           0, mission_type)
        ack = h.wait_for("MISSION_ACK", sim_s=0.05)
        if ack is not None:
            return ack
    return h.wait_for("MISSION_ACK")


def download(h: Harness) -> list[Any]:
    h.client.mav.mission_request_list_send(1, 1, FENCE)
    count = h.wait_for("MISSION_COUNT")
    got = []
    for seq in range(count.count):
        h.client.mav.mission_request_int_send(1, 1, seq, FENCE)
        got.append(h.wait_for("MISSION_ITEM_INT"))
    h.client.mav.mission_ack_send(1, 1, M.MAV_MISSION_ACCEPTED, FENCE)
    return got


@pytest.mark.parametrize("autopilot", ["ardupilot", "px4"])
def test_fence_upload_download_and_clear(autopilot: str) -> None:
    with hello(Harness(VehicleParams(autopilot=autopilot))) as h:
        items = [*square(20.0), (CIRC_EX, 3.0, 5.0, 5.0)]
        ack = upload(h, items)
        assert ack.type == M.MAV_MISSION_ACCEPTED and ack.mission_type == FENCE
        got = download(h)
        assert [m.command for m in got] == [INC] * 4 + [CIRC_EX]
        assert got[4].param1 == 3.0 and (got[0].x, got[0].y) == _latlon(autopilot, 20, 20)
        assert all(m.mission_type == FENCE for m in got)
        # MISSION_REQUEST (float degrees) for the same item.
        h.client.mav.mission_request_send(1, 1, 0, FENCE)
        item = h.wait_for("MISSION_ITEM")
        assert item.x == pytest.approx(got[0].x * 1e-7, abs=5e-6)  # a float32 of degrees
        # Out of sequence: the vehicle asks for the item it expects again.
        assert upload(h, square(10.0), bad_seq=True).type == M.MAV_MISSION_ACCEPTED
        assert len(download(h)) == 4
        h.client.mav.mission_request_int_send(1, 1, 9, FENCE)
        assert h.wait_for("MISSION_ACK").type == M.MAV_MISSION_INVALID_SEQUENCE
        h.client.mav.mission_clear_all_send(1, 1, FENCE)
        assert h.wait_for("MISSION_ACK").type == M.MAV_MISSION_ACCEPTED
        assert download(h) == []
        assert h.fleet.handler_errors == 0


def test_bad_fence_items_are_refused_with_their_mission_result() -> None:
    with hello(Harness(VehicleParams())) as h:
        assert upload(h, square(20.0)).type == M.MAV_MISSION_ACCEPTED
        bad = [(INC, 2, 0, 0), (INC, 2, 1, 0)]  # a polygon needs 3 vertices
        assert upload(h, bad).type == M.MAV_MISSION_INVALID_PARAM1
        assert upload(h, [(INC, NAN, 0, 0)] * 3).type == M.MAV_MISSION_INVALID_PARAM1
        assert upload(h, [(CIRC_EX, -1, 0, 0)]).type == M.MAV_MISSION_INVALID_PARAM1
        assert upload(h, [(M.MAV_CMD_NAV_WAYPOINT, 0, 0, 0)]).type == M.MAV_MISSION_UNSUPPORTED
        assert upload(h, [(CIRC_EX, 5, 0, 0)], frame=M.MAV_FRAME_LOCAL_NED).type == \
            M.MAV_MISSION_UNSUPPORTED_FRAME
        assert upload(h, [(INC, 4, 0, 0)] * 3).type == M.MAV_MISSION_INVALID  # 3 of 4
        assert upload(h, [(CIRC_EX, 5, 2e7, 0)]).type == M.MAV_MISSION_INVALID_PARAM5_X
        h.client.mav.mission_count_send(1, 1, 10_000, FENCE)
        assert h.wait_for("MISSION_ACK").type == M.MAV_MISSION_NO_SPACE
        assert len(download(h)) == 4  # the stored fence is unchanged
        # An item with no upload in progress is ignored, not acknowledged.
        h.client.mav.mission_item_int_send(1, 1, 0, M.MAV_FRAME_GLOBAL_INT, INC, 0, 1, 4, 0,
                                           0, 0, 0, 0, 0, FENCE)
        assert h.wait_for("MISSION_ACK", sim_s=0.3) is None
        assert h.fleet.handler_errors == 0


def test_ardupilot_breach_rtl_fence_status_and_report_only() -> None:
    """FENCE_ENABLE on, FENCE_TYPE polygon: outside the inclusion square → FENCE_ACTION 1 →
    RTL; FENCE_STATUS reports the boundary breach; SYS_STATUS's geofence health clears."""
    params = conf(FENCE_ENABLE=1, FENCE_TYPE=4, FENCE_ACTION=1)
    with hello(Harness(VehicleParams(indoor=True, params=params))) as h:
        assert upload(h, square(10.0)).type == M.MAV_MISSION_ACCEPTED
        airborne(h, 3.0)
        st = h.wait_for("FENCE_STATUS", sim_s=1.5)
        assert st.breach_status == 0 and st.breach_count == 0
        h.fleet.p[0, 0] = 15.0  # north, outside the square
        h.run(0.3)
        assert h.quad.mode == APM["RTL"]
        h.of("FENCE_STATUS")
        h.of("SYS_STATUS")
        st = h.wait_for("FENCE_STATUS", sim_s=1.5)
        assert (st.breach_status, st.breach_count, st.breach_type) == \
            (1, 1, M.FENCE_BREACH_BOUNDARY)
        sys = h.wait_for("SYS_STATUS", sim_s=1.5)
        assert sys.onboard_control_sensors_enabled & M.MAV_SYS_STATUS_GEOFENCE
        assert not sys.onboard_control_sensors_health & M.MAV_SYS_STATUS_GEOFENCE
        assert h.quad.log.has("failsafe_fence_rtl")
        assert h.fleet.handler_errors == 0
    params = conf(FENCE_ENABLE=1, FENCE_TYPE=1, FENCE_ACTION=0, FENCE_ALT_MAX=2.0)
    with hello(Harness(VehicleParams(indoor=True, params=params))) as h:
        airborne(h, 3.0)  # above FENCE_ALT_MAX: reported only
        h.of("FENCE_STATUS")
        st = h.wait_for("FENCE_STATUS", sim_s=1.5)
        assert (st.breach_status, st.breach_type) == (1, M.FENCE_BREACH_MAXALT)
        assert h.quad.mode == APM["GUIDED"] and h.quad.log.has("failsafe_fence_report")


def test_ardupilot_brake_action_do_fence_enable_and_landed_disarm() -> None:
    params = conf(FENCE_TYPE=4, FENCE_ACTION=4)
    with hello(Harness(VehicleParams(indoor=True, params=params))) as h:
        assert upload(h, square(10.0)).type == M.MAV_MISSION_ACCEPTED
        airborne(h, 3.0)
        h.fleet.p[0, 1] = -12.0  # west of the square, fence still disabled
        h.run(0.5)
        assert h.quad.mode == APM["GUIDED"]
        assert result(h, M.MAV_CMD_DO_FENCE_ENABLE, 7) == M.MAV_RESULT_FAILED
        assert result(h, M.MAV_CMD_DO_FENCE_ENABLE, NAN) == M.MAV_RESULT_DENIED
        assert result(h, M.MAV_CMD_DO_FENCE_ENABLE, 1) == M.MAV_RESULT_ACCEPTED
        h.run(0.3)
        assert h.quad.mode == APM["BRAKE"]
    params = conf(FENCE_ENABLE=1, FENCE_TYPE=4, FENCE_ACTION=1)
    with hello(Harness(VehicleParams(indoor=True, params=params))) as h:
        h.every = h.vision
        assert upload(h, square(10.0)).type == M.MAV_MISSION_ACCEPTED
        h.run(0.3)
        assert h.set_mode(APM["LOITER"]) == M.MAV_RESULT_ACCEPTED
        assert h.arm() == M.MAV_RESULT_ACCEPTED
        h.fleet.p[0, 0] = 30.0  # on the ground outside: land_complete → disarm
        h.run(0.3)
        assert not h.quad.armed


def test_px4_gf_action_holds_then_returns_after_com_fail_act_t() -> None:
    """GF_ACTION 3 (Return): Hold first for COM_FAIL_ACT_T, then AUTO.RTL; GF_ACTION 5 Land;
    no FENCE_STATUS from PX4 (no such stream)."""
    params = conf(GF_ACTION=3, COM_FAIL_ACT_T=2.0)
    with hello(Harness(VehicleParams(autopilot="px4", indoor=True, params=params))) as h:
        assert upload(h, square(10.0)).type == M.MAV_MISSION_ACCEPTED
        airborne(h, 3.0)
        h.fleet.p[0, 0] = -14.0
        h.run(0.3)
        assert h.quad.mode == P_LOITER
        text = h.wait_for("STATUSTEXT", sim_s=0.5)
        assert text is not None and "fence" in text.text.lower()
        h.run(2.0)
        assert h.quad.mode == P_RTL
        assert h.wait_for("FENCE_STATUS", sim_s=1.5) is None
        assert h.fleet.handler_errors == 0
    params = conf(GF_ACTION=5, GF_MAX_VER_DIST=2.0, COM_FAIL_ACT_T=0.0)
    with hello(Harness(VehicleParams(autopilot="px4", indoor=True, params=params))) as h:
        airborne(h, 3.0, check=False)  # above GF_MAX_VER_DIST: Land at once (no delay)
        assert h.quad.mode == P_LAND
        assert result(h, M.MAV_CMD_DO_FENCE_ENABLE, 1) == M.MAV_RESULT_UNSUPPORTED


@pytest.mark.filterwarnings("ignore::DeprecationWarning")
@pytest.mark.parametrize("autopilot", ["ardupilot", "px4"])
def test_mavsdk_geofence_plugin_uploads_downloads_and_clears(autopilot: str) -> None:
    pytest.importorskip("mavsdk_grpc")
    from mavsdk_grpc.geofence import (
        Circle,
        FenceType,
        GeofenceData,
        Point,
        Polygon,
    )

    lat0, lon0, _ = ORIGIN[autopilot]
    d = 1e-4
    poly = Polygon([Point(lat0 + d, lon0 + d), Point(lat0 + d, lon0 - d),
                    Point(lat0 - d, lon0 - d), Point(lat0 - d, lon0 + d)], FenceType.INCLUSION)
    circle = Circle(Point(lat0, lon0), 2.0, FenceType.EXCLUSION)

    async def body(system: Any, fleet: Any) -> tuple[Any, Any, Any]:
        await system.geofence.upload_geofence(GeofenceData([poly], [circle]))
        stored = list(fleet.quads[0].fence.stored[FENCE])
        back = await system.geofence.download_geofence()
        await system.geofence.clear_geofence()
        return stored, back, list(fleet.quads[0].fence.stored[FENCE])

    stored, back, cleared = run_sdk(VehicleParams(autopilot=autopilot), body)
    assert [i.command for i in stored] == [INC] * 4 + [CIRC_EX]
    assert stored[0].x == round((lat0 + d) * 1e7) and stored[4].params[0] == 2.0
    assert len(back.polygons) == 1 and len(back.polygons[0].points) == 4
    assert back.circles[0].radius == pytest.approx(2.0)
    assert cleared == []


def test_px4_user_mode_change_during_the_hold_cancels_the_failsafe_action() -> None:
    params = conf(GF_ACTION=3, COM_FAIL_ACT_T=2.0)
    with hello(Harness(VehicleParams(autopilot="px4", indoor=True, params=params))) as h:
        assert upload(h, square(10.0)).type == M.MAV_MISSION_ACCEPTED
        airborne(h, 3.0)
        h.fleet.p[0, 1] = 14.0
        h.run(0.3)
        assert h.quad.mode == P_LOITER
        assert h.set_mode(6) == M.MAV_RESULT_ACCEPTED  # back to OFFBOARD (set-points flow)
        h.run(2.5)
        assert h.quad.mode == px4_custom_mode(6) and h.quad.log.has("failsafe_cancelled")


def test_mavproxy_fence_module_loads_and_lists_the_fence(tmp_path: Path) -> None:
    """MAVProxy's fence module (the mission protocol with MAV_MISSION_TYPE_FENCE) uploads a
    waypoint file of inclusion vertices and downloads it back from the simulated ArduPilot."""
    exe = shutil.which("mavproxy.py") or str(Path(sys.executable).with_name("mavproxy.py"))
    lat0, lon0, _ = ORIGIN["ardupilot"]
    rows = ["QGC WPL 110"] + [
        f"{i}\t0\t0\t{INC}\t4\t0\t0\t0\t{lat0 + a:.7f}\t{lon0 + b:.7f}\t0\t1"
        for i, (a, b) in enumerate([(1e-4, 1e-4), (1e-4, -1e-4), (-1e-4, -1e-4),
                                    (-1e-4, 1e-4)])]
    (tmp_path / "fence.txt").write_text("\n".join(rows) + "\n")
    fleet = SimFleet(["d0"], WallClock(), VehicleParams()).start()
    proc = subprocess.Popen(
        [exe, f"--master=udpout:127.0.0.1:{fleet.quads[0].port}", "--default-modules=fence",
         "--source-system=255"], cwd=tmp_path, stdin=subprocess.PIPE, stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT, text=True)
    lines: list[str] = []
    reader = threading.Thread(target=lambda: lines.extend(proc.stdout or []), daemon=True)
    reader.start()

    def seen(text: str, timeout_s: float = 20.0) -> bool:
        end = time.monotonic() + timeout_s
        while time.monotonic() < end:
            if any(text in x for x in lines):
                return True
            time.sleep(0.1)
        return False

    try:
        assert seen("Detected vehicle 1:1"), lines
        assert proc.stdin is not None
        proc.stdin.write("fence load fence.txt\n")
        proc.stdin.flush()
        assert seen("Got MISSION_ACK: TYPE_FENCE: ACCEPTED"), lines
        proc.stdin.write("fence list\n")
        proc.stdin.flush()
        assert seen("Saved 4 fence items"), lines
        stored = fleet.quads[0].fence.stored[FENCE]
        assert len(stored) == 4 and stored[0].command == INC
        assert stored[0].x == round((lat0 + 1e-4) * 1e7)
        assert fleet.handler_errors == 0
    finally:
        stop_process(proc, reader)
        fleet.close()
