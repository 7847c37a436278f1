"""The simulated camera answers as each autopilot's camera answers
(:mod:`groundstation.vehicle.camera`; sources: ArduPilot libraries/AP_Camera/AP_Camera.cpp
``handle_command`` and AP_Camera_Backend.cpp, ardupilot_wiki dev/source/docs/mavlink-camera.rst;
PX4 docs camera/camera_architecture.md and PX4-SITL_gazebo-classic
gazebo_camera_manager_plugin.cpp). Raw pymavlink on the manual clock, then MAVSDK's camera
plugin on the wall clock."""

from __future__ import annotations

import asyncio
import math
from typing import Any

import pytest

from agent.flight.frames import euler_from_quat
from groundstation.vehicle.params import VehicleParams
from tests.sim_vehicle_helpers import NAN, M, airborne, command, first, hello, result, run_sdk
from tests.vehicle_harness import Harness

START = M.MAV_CMD_IMAGE_START_CAPTURE
REQ = M.MAV_CMD_REQUEST_MESSAGE
CAM = M.MAV_COMP_ID_CAMERA


def _payload(autopilot: str, *, params: dict[str, float] | None = None,
             gnss: str | None = None) -> VehicleParams:
    """Camera and gimbal fitted, external navigation configured (mocap forwarded); optionally
    autopilot ``params`` set and a GNSS receiver."""
    return VehicleParams(autopilot=autopilot, payload=True, indoor=True, params=params or {},
                         gnss=gnss)


def test_ardupilot_camera_answers_on_the_autopilot_with_camera_feedback() -> None:
    """AP_Camera (CAM1_TYPE 1): CAMERA_INFORMATION from component 1; a picture is a
    CAMERA_FEEDBACK with the EKF's position and the vehicle's attitude, img_idx counting from 1;
    no CAMERA_IMAGE_CAPTURED; no camera component heartbeat."""
    with hello(Harness(_payload("ardupilot"))) as h:
        airborne(h, 3.0)
        info_ack = command(h, REQ, M.MAVLINK_MSG_ID_CAMERA_INFORMATION)
        assert info_ack.result == M.MAV_RESULT_ACCEPTED and info_ack.get_srcComponent() == 1
        info = h.wait_for("CAMERA_INFORMATION")
        assert info.get_srcComponent() == 1 and info.flags & M.CAMERA_CAP_FLAGS_CAPTURE_IMAGE
        assert (info.resolution_h, info.resolution_v) == (4000, 3000)
        assert info.focal_length == pytest.approx(4.5) and info.sensor_size_h > 0
        assert bytes(info.vendor_name).rstrip(b"\0") == b"viscover"
        assert info.gimbal_device_id == 1 and info.lens_id == 0  # mount instance + 1
        h.of("GLOBAL_POSITION_INT")
        assert result(h, START, 0, 0, 1) == M.MAV_RESULT_ACCEPTED
        fb = h.wait_for("CAMERA_FEEDBACK")
        gp = h.wait_for("GLOBAL_POSITION_INT")
        assert fb.img_idx == 1 and fb.flags == M.CAMERA_FEEDBACK_PHOTO and fb.cam_idx == 0
        assert abs(fb.lat - gp.lat) < 30 and abs(fb.lng - gp.lon) < 30  # degE7, ~3 mm/30 ms
        assert fb.alt_rel == pytest.approx(3.0, abs=0.3) and fb.alt_msl - fb.alt_rel == \
            pytest.approx(584.0, abs=0.01)
        # MAV_CMD_DO_DIGICAM_CONTROL (every version): param5 = 1 takes a picture.
        assert result(h, M.MAV_CMD_DO_DIGICAM_CONTROL, 0, 0, 0, 0, 1) == M.MAV_RESULT_ACCEPTED
        assert h.wait_for("CAMERA_FEEDBACK").img_idx == 2
        assert result(h, M.MAV_CMD_DO_DIGICAM_CONTROL, 0, 0, 0, 0, 0) == M.MAV_RESULT_ACCEPTED
        assert h.wait_for("CAMERA_FEEDBACK", sim_s=0.3) is None  # no shot asked
        assert not h.of("CAMERA_IMAGE_CAPTURED")
        assert not [m for m in h.of("HEARTBEAT") if m.get_srcComponent() == CAM]
        assert h.fleet.handler_errors == 0


def test_ardupilot_camera_refuses_as_ap_camera_does() -> None:
    with hello(Harness(_payload("ardupilot", params={"CAM1_INTRVAL_MIN": 2.0}))) as h:
        assert result(h, START, -1, 0, 1) == M.MAV_RESULT_UNSUPPORTED  # is_negative(param1)
        assert result(h, START, NAN, 0, 1) == M.MAV_RESULT_DENIED  # a NaN id has no instance
        assert result(h, START, 0, NAN, NAN) == M.MAV_RESULT_DENIED
        assert result(h, START, 3, 0, 1) == M.MAV_RESULT_FAILED  # no third camera
        assert result(h, START, 1, 0, 1) == M.MAV_RESULT_ACCEPTED
        # CAM1_INTRVAL_MIN: too soon is FAILED, the picture follows once the gap has passed.
        assert result(h, START, 1, 0, 1) == M.MAV_RESULT_FAILED
        assert h.wait_for("CAMERA_FEEDBACK").img_idx == 1
        late = h.wait_for("CAMERA_FEEDBACK", sim_s=3.0)
        assert late is not None and late.img_idx == 2
        assert result(h, M.MAV_CMD_IMAGE_STOP_CAPTURE, 0) == M.MAV_RESULT_ACCEPTED
        # CAMERA_CAPTURE_STATUS on request: image_count, interval state (2 while it runs).
        assert result(h, START, 0, 2.0, 0) == M.MAV_RESULT_ACCEPTED  # every 2 s, for ever
        assert result(h, REQ, M.MAVLINK_MSG_ID_CAMERA_CAPTURE_STATUS) == M.MAV_RESULT_ACCEPTED
        st = h.wait_for("CAMERA_CAPTURE_STATUS")
        assert st.image_status == 2 and st.image_interval == pytest.approx(2.0)
        h.run(4.1)
        assert result(h, M.MAV_CMD_IMAGE_STOP_CAPTURE, 0) == M.MAV_RESULT_ACCEPTED
        assert result(h, REQ, M.MAVLINK_MSG_ID_CAMERA_CAPTURE_STATUS) == M.MAV_RESULT_ACCEPTED
        st = h.wait_for("CAMERA_CAPTURE_STATUS")
        assert st.image_status == 0 and st.image_count >= 4
        # A camera addressed to another system, or to the camera component: not processed.
        assert command(h, START, 0, 0, 1, target=(2, 1)) is None
        assert command(h, START, 0, 0, 1, target=(1, CAM)) is None
        assert h.fleet.handler_errors == 0
    with hello(Harness(VehicleParams())) as h:  # CAM1_TYPE 0: no camera backend
        assert result(h, START, 0, 0, 1) == M.MAV_RESULT_FAILED
        assert result(h, REQ, M.MAVLINK_MSG_ID_CAMERA_INFORMATION) == M.MAV_RESULT_UNSUPPORTED


def test_px4_camera_is_its_own_component_and_reports_the_pose_at_the_shutter() -> None:
    """A MAVLink camera (component 100, HEARTBEAT MAV_TYPE_CAMERA): CAMERA_IMAGE_CAPTURED with
    the EKF's position at the shutter, relative altitude, and the camera attitude including
    the gimbal's pitch; the autopilot itself does not take camera commands."""
    with hello(Harness(_payload("px4"))) as h:
        airborne(h, 3.0)
        beats = [m for m in h.of("HEARTBEAT") if m.get_srcComponent() == CAM]
        assert beats and beats[-1].type == M.MAV_TYPE_CAMERA
        assert beats[-1].autopilot == M.MAV_AUTOPILOT_INVALID
        ack = command(h, REQ, M.MAVLINK_MSG_ID_CAMERA_INFORMATION, target=(1, CAM))
        assert ack.result == M.MAV_RESULT_ACCEPTED and ack.get_srcComponent() == CAM
        info = h.wait_for("CAMERA_INFORMATION")
        assert info.get_srcComponent() == CAM and info.flags & M.CAMERA_CAP_FLAGS_CAPTURE_IMAGE
        # Pitch the gimbal down 40° first (PX4: take primary control, then command).
        me = (255, 190)
        assert result(h, M.MAV_CMD_DO_GIMBAL_MANAGER_CONFIGURE, *me, -1, -1, 0, 0, 0) == \
            M.MAV_RESULT_ACCEPTED
        assert result(h, M.MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW, -40, 0, NAN, NAN, 0, 0, 0) == \
            M.MAV_RESULT_ACCEPTED
        h.run(1.0)
        assert result(h, START, 0, 0, 1, target=(1, 1)) == M.MAV_RESULT_UNSUPPORTED
        shot = command(h, START, 0, 0, 1, target=(1, CAM))
        assert shot.result == M.MAV_RESULT_ACCEPTED and shot.get_srcComponent() == CAM
        t_cmd = h.clock.now()
        cap = h.wait_for("CAMERA_IMAGE_CAPTURED")
        gp = h.wait_for("GLOBAL_POSITION_INT")
        assert cap.get_srcComponent() == CAM and cap.image_index == 0 and cap.capture_result == 1
        assert 0.0 < cap.time_boot_ms / 1000 - t_cmd < 0.2  # shutter lag 50 ms
        assert cap.time_utc > 1.7e15  # µs since 1970
        assert abs(cap.lat - gp.lat) < 50 and abs(cap.lon - gp.lon) < 50
        assert cap.relative_alt == pytest.approx(3000, abs=300)  # mm above home
        assert cap.alt - cap.relative_alt == pytest.approx(488_000, abs=5)  # mm AMSL of home
        roll, pitch, yaw = euler_from_quat(cap.q)
        assert math.degrees(pitch) == pytest.approx(-40.0, abs=0.5)
        assert abs(roll) < 1e-6 and abs(math.degrees(yaw)) < 10
        assert cap.file_url.endswith("DSC00000.jpg")
        # The camera protocol's re-request of a capture by its index.
        assert result(h, REQ, M.MAVLINK_MSG_ID_CAMERA_IMAGE_CAPTURED, 0, target=(1, CAM)) == \
            M.MAV_RESULT_ACCEPTED
        assert h.wait_for("CAMERA_IMAGE_CAPTURED").image_index == 0
        assert h.fleet.handler_errors == 0


def test_px4_camera_refuses_as_the_sitl_camera_manager_does() -> None:
    with hello(Harness(_payload("px4"))) as h:
        to_cam = (1, CAM)
        assert result(h, START, 0, 0, -1, target=to_cam) == M.MAV_RESULT_DENIED
        assert result(h, START, 0, NAN, NAN, target=to_cam) == M.MAV_RESULT_DENIED
        assert result(h, START, 0, 0.5, 3, target=to_cam) == M.MAV_RESULT_ACCEPTED  # 3 at 2 Hz
        assert result(h, START, 0, 0, 1, target=to_cam) == M.MAV_RESULT_TEMPORARILY_REJECTED
        h.run(1.6)
        got = [m.image_index for m in h.of("CAMERA_IMAGE_CAPTURED")]
        assert got == [0, 1, 2]
        assert result(h, REQ, NAN, target=to_cam) == M.MAV_RESULT_DENIED
        assert result(h, REQ, M.MAVLINK_MSG_ID_CAMERA_IMAGE_CAPTURED, 7, target=to_cam) == \
            M.MAV_RESULT_DENIED  # no such picture
        assert result(h, REQ, M.MAVLINK_MSG_ID_ATTITUDE, target=to_cam) == \
            M.MAV_RESULT_UNSUPPORTED
        assert result(h, 31999, target=to_cam) == M.MAV_RESULT_UNSUPPORTED
        assert command(h, START, 0, 0, 1, target=(2, CAM)) is None  # another system's camera
        assert result(h, M.MAV_CMD_REQUEST_CAMERA_CAPTURE_STATUS, 1, target=to_cam) == \
            M.MAV_RESULT_ACCEPTED
        assert h.wait_for("CAMERA_CAPTURE_STATUS").image_count == 3
        assert h.fleet.handler_errors == 0
    with hello(Harness(VehicleParams(autopilot="px4"))) as h:  # no payload: nobody answers
        assert command(h, START, 0, 0, 1, target=(1, CAM)) is None


@pytest.mark.filterwarnings("ignore::DeprecationWarning")
def test_mavsdk_camera_plugin_takes_a_photo_on_the_px4_camera() -> None:
    """MAVSDK discovers the camera component from its HEARTBEAT and CAMERA_INFORMATION,
    ``take_photo`` is acknowledged and ``capture_info`` carries the pose at the shutter."""
    pytest.importorskip("mavsdk_grpc")

    async def body(system: Any, fleet: Any) -> tuple[Any, Any]:
        cams = await first(system.camera.camera_list(), lambda c: bool(c.cameras))
        info = cams.cameras[0]
        captured = first(system.camera.capture_info())
        task = asyncio.ensure_future(captured)
        await asyncio.sleep(0.2)
        await system.camera.take_photo(info.component_id)
        return info, await task

    info, cap = run_sdk(_payload("px4", gnss="rtk"), body)
    assert info.component_id == CAM and info.vendor_name == "viscover"
    assert info.horizontal_resolution_px == 4000
    assert cap.is_success and cap.index == 0 and cap.component_id == CAM
    assert cap.position.latitude_deg == pytest.approx(47.397742, abs=1e-5)
    assert cap.file_url.startswith("file:///")


@pytest.mark.filterwarnings("ignore::DeprecationWarning")
def test_mavsdk_finds_the_ardupilot_camera_on_the_autopilot_component() -> None:
    """ArduPilot's camera is found on component 1 and ``take_photo`` is acknowledged; as on a
    real ArduPilot no CAMERA_IMAGE_CAPTURED follows (CAMERA_FEEDBACK instead)."""
    pytest.importorskip("mavsdk_grpc")

    async def body(system: Any, fleet: Any) -> Any:
        cams = await first(system.camera.camera_list(), lambda c: bool(c.cameras))
        await system.camera.take_photo(cams.cameras[0].component_id)
        return cams.cameras[0]

    info = run_sdk(_payload("ardupilot"), body)
    assert info.component_id == 1 and info.model_name == "sim-rgb-12mp"
