"""The simulated gimbal (protocol v2) answers as each autopilot's gimbal manager answers
(:mod:`groundstation.vehicle.gimbal`; sources: ArduPilot libraries/AP_Mount/AP_Mount.cpp
``handle_command_do_gimbal_manager_pitchyaw``, AP_Mount_Backend.cpp ``set_angle_target``,
``send_gimbal_manager_information``, ``get_gimbal_device_flags``; PX4
src/modules/gimbal/input_mavlink.cpp, output_rc.cpp and the mavlink streams
GIMBAL_MANAGER_INFORMATION.hpp / GIMBAL_DEVICE_ATTITUDE_STATUS.hpp), and moves at its slew
rate within its limits."""

from __future__ import annotations

import math
from typing import Any

import pytest

from agent.flight.frames import euler_from_quat
from groundstation.vehicle.params import VehicleParams
from tests.sim_vehicle_helpers import NAN, M, first, hello, result, run_sdk
from tests.vehicle_harness import Harness

PITCHYAW = M.MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW
CONFIGURE = M.MAV_CMD_DO_GIMBAL_MANAGER_CONFIGURE
REQ = M.MAV_CMD_REQUEST_MESSAGE
ME = (255, 190)  #: the Harness client's system and component


def _pitch_deg(h: Harness) -> tuple[float, Any]:
    """Latest GIMBAL_DEVICE_ATTITUDE_STATUS: its pitch [deg] and the message."""
    h.of("GIMBAL_DEVICE_ATTITUDE_STATUS")
    m = h.wait_for("GIMBAL_DEVICE_ATTITUDE_STATUS")
    assert m is not None
    return math.degrees(euler_from_quat(m.q)[1]), m


def test_ardupilot_mount_limits_rate_and_flags() -> None:
    """MNT1_TYPE 1: manager and device on component 1 (device id 1); PITCHYAW angles clamped
    to MNT1_PITCH_MIN/MAX; the device slews at the gimbal's rate (60°/s)."""
    with hello(Harness(VehicleParams(payload=True))) as h:
        assert result(h, REQ, M.MAVLINK_MSG_ID_GIMBAL_MANAGER_INFORMATION) == \
            M.MAV_RESULT_ACCEPTED
        info = h.wait_for("GIMBAL_MANAGER_INFORMATION")
        assert info.get_srcComponent() == 1 and info.gimbal_device_id == 1
        assert math.degrees(info.pitch_min) == pytest.approx(-90.0)
        assert math.degrees(info.pitch_max) == pytest.approx(20.0)
        assert math.degrees(info.yaw_min) == pytest.approx(-180.0)
        assert info.cap_flags & M.GIMBAL_MANAGER_CAP_FLAGS_HAS_PITCH_AXIS
        assert result(h, PITCHYAW, -60, 0, NAN, NAN, 0, 0, 0) == M.MAV_RESULT_ACCEPTED
        h.run(0.5)
        pitch, m = _pitch_deg(h)
        assert -40.0 < pitch < -25.0  # 60°/s for 0.5 s
        assert m.get_srcComponent() == 1 and m.gimbal_device_id == 1
        assert m.flags == M.GIMBAL_DEVICE_FLAGS_ROLL_LOCK | M.GIMBAL_DEVICE_FLAGS_PITCH_LOCK
        assert math.isnan(m.angular_velocity_y)  # a servo mount reports no rates
        h.run(1.0)
        assert _pitch_deg(h)[0] == pytest.approx(-60.0, abs=0.1)
        # Out of range: clamped (set_angle_target's constrain_float), ACCEPTED.
        assert result(h, PITCHYAW, -150, 0, NAN, NAN, 0, 0, 0) == M.MAV_RESULT_ACCEPTED
        h.run(1.0)
        assert _pitch_deg(h)[0] == pytest.approx(-90.0, abs=0.1)
        assert result(h, PITCHYAW, 80, 0, NAN, NAN, 0, 0, 0) == M.MAV_RESULT_ACCEPTED
        h.run(2.5)
        assert _pitch_deg(h)[0] == pytest.approx(20.0, abs=0.1)
        # Rates (deg/s) when the angles are NaN.
        assert result(h, PITCHYAW, NAN, NAN, -20, 0, 0, 0, 0) == M.MAV_RESULT_ACCEPTED
        h.run(1.0)
        assert _pitch_deg(h)[0] == pytest.approx(0.0, abs=2.5)
        # GIMBAL_MANAGER_SET_PITCHYAW (rad): angles.
        h.client.mav.gimbal_manager_set_pitchyaw_send(1, 1, 0, 0, math.radians(-30), 0.0,
                                                      NAN, NAN)
        h.run(1.5)
        assert _pitch_deg(h)[0] == pytest.approx(-30.0, abs=0.1)
        # ... angles and rates at once: refused (ignored), no change.
        h.client.mav.gimbal_manager_set_pitchyaw_send(1, 1, 0, 0, math.radians(-80), 0.0,
                                                      0.1, 0.0)
        h.run(1.0)
        assert _pitch_deg(h)[0] == pytest.approx(-30.0, abs=0.1)
        assert result(h, REQ, M.MAVLINK_MSG_ID_GIMBAL_MANAGER_STATUS) == M.MAV_RESULT_ACCEPTED
        st = h.wait_for("GIMBAL_MANAGER_STATUS")
        assert st.flags & M.GIMBAL_MANAGER_FLAGS_PITCH_LOCK and st.gimbal_device_id == 1
        assert h.fleet.handler_errors == 0


def test_ardupilot_gimbal_refusals() -> None:
    with hello(Harness(VehicleParams(payload=True))) as h:
        assert result(h, PITCHYAW, NAN, NAN, NAN, NAN, 0, 0, 0) == M.MAV_RESULT_FAILED
        assert result(h, PITCHYAW, -10, 0, NAN, NAN, 0, 0, 2) == M.MAV_RESULT_FAILED  # device 2
        assert result(h, PITCHYAW, -10, 0, NAN, NAN, 0, 0, -1) == M.MAV_RESULT_DENIED
        assert result(h, PITCHYAW, -10, 0, NAN, NAN, 1e12, 0, 0) == M.MAV_RESULT_DENIED  # flags
        assert result(h, CONFIGURE, 300, 1, -1, -1, 0, 0, 0) == M.MAV_RESULT_FAILED
        assert result(h, CONFIGURE, NAN, 1, -1, -1, 0, 0, 0) == M.MAV_RESULT_DENIED
        assert result(h, CONFIGURE, -2, -2, -1, -1, 0, 0, 0) == M.MAV_RESULT_ACCEPTED
        assert h.quad.gimbal.control == ME  # -2: the sender takes control
        assert result(h, M.MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW, -10, 0, NAN, NAN,
                      M.GIMBAL_MANAGER_FLAGS_NEUTRAL, 0, 0) == M.MAV_RESULT_ACCEPTED
        assert h.quad.gimbal.mode == "neutral"
        assert h.fleet.handler_errors == 0
    with hello(Harness(VehicleParams())) as h:  # MNT1_TYPE 0: no mount
        assert result(h, PITCHYAW, -10, 0, NAN, NAN, 0, 0, 0) == M.MAV_RESULT_FAILED
        assert result(h, REQ, M.MAVLINK_MSG_ID_GIMBAL_MANAGER_INFORMATION) == \
            M.MAV_RESULT_UNSUPPORTED
        assert h.wait_for("GIMBAL_DEVICE_ATTITUDE_STATUS", sim_s=0.3) is None


def test_px4_gimbal_manager_wants_primary_control_and_clamps_at_the_output() -> None:
    """PX4: PITCHYAW DENIED until DO_GIMBAL_MANAGER_CONFIGURE gives the sender primary
    control; MNT_RANGE_PITCH 180 (the payload set-up): ±90°; the device attitude comes from
    the spoofed MAV_COMP_ID_GIMBAL with output_rc's flags."""
    with hello(Harness(VehicleParams(autopilot="px4", payload=True))) as h:
        assert result(h, PITCHYAW, -45, 0, NAN, NAN, 0, 0, 0) == M.MAV_RESULT_DENIED
        assert result(h, CONFIGURE, *ME, -1, -1, 0, 0, 0) == M.MAV_RESULT_ACCEPTED
        assert result(h, PITCHYAW, -45, 0, NAN, NAN, 0, 0, 0) == M.MAV_RESULT_ACCEPTED
        h.run(1.0)
        pitch, m = _pitch_deg(h)
        assert pitch == pytest.approx(-45.0, abs=0.1)
        assert m.get_srcComponent() == M.MAV_COMP_ID_GIMBAL and m.gimbal_device_id == 0
        assert m.flags == (M.GIMBAL_DEVICE_FLAGS_NEUTRAL | M.GIMBAL_DEVICE_FLAGS_ROLL_LOCK
                           | M.GIMBAL_DEVICE_FLAGS_PITCH_LOCK | M.GIMBAL_DEVICE_FLAGS_YAW_LOCK)
        assert result(h, PITCHYAW, -170, 0, NAN, NAN, 0, 0, 0) == M.MAV_RESULT_ACCEPTED
        h.run(1.5)
        assert _pitch_deg(h)[0] == pytest.approx(-90.0, abs=0.1)
        assert result(h, REQ, M.MAVLINK_MSG_ID_GIMBAL_MANAGER_INFORMATION) == \
            M.MAV_RESULT_ACCEPTED
        info = h.wait_for("GIMBAL_MANAGER_INFORMATION")
        assert info.gimbal_device_id == M.MAV_COMP_ID_GIMBAL
        assert math.degrees(info.pitch_min) == pytest.approx(-90.0)
        # -3 releases control (the sender had it); then DENIED again.
        assert result(h, CONFIGURE, -3, -3, -1, -1, 0, 0, 0) == M.MAV_RESULT_ACCEPTED
        assert result(h, PITCHYAW, 0, 0, NAN, NAN, 0, 0, 0) == M.MAV_RESULT_DENIED
        # -2 is the autopilot itself in PX4's input_mavlink.cpp, not the sender.
        assert result(h, CONFIGURE, -2, -2, -1, -1, 0, 0, 0) == M.MAV_RESULT_ACCEPTED
        assert h.quad.gimbal.control == (1, 1)
        assert result(h, PITCHYAW, 0, 0, NAN, NAN, 0, 0, 0) == M.MAV_RESULT_DENIED
        # GIMBAL_MANAGER_SET_PITCHYAW from someone without control: ignored.
        h.client.mav.gimbal_manager_set_pitchyaw_send(1, 1, 0, 0, 0.0, 0.0, NAN, NAN)
        h.run(1.0)
        assert _pitch_deg(h)[0] == pytest.approx(-90.0, abs=0.1)
        assert h.fleet.handler_errors == 0
    with hello(Harness(VehicleParams(autopilot="px4"))) as h:  # MNT_MODE_IN -1
        assert result(h, PITCHYAW, -10, 0, NAN, NAN, 0, 0, 0) == M.MAV_RESULT_UNSUPPORTED


@pytest.mark.filterwarnings("ignore::DeprecationWarning")
@pytest.mark.parametrize("autopilot", ["px4", "ardupilot"])
def test_mavsdk_gimbal_plugin_commands_and_reads_back(autopilot: str) -> None:
    """MAVSDK pairs the manager and the device, takes control, sets the pitch and reads it
    back from GIMBAL_DEVICE_ATTITUDE_STATUS."""
    pytest.importorskip("mavsdk_grpc")
    from mavsdk_grpc.gimbal import (
        ControlMode,
        GimbalMode,
        SendMode,
    )

    async def body(system: Any, fleet: Any) -> Any:
        gimbals = await first(system.gimbal.gimbal_list(), lambda g: bool(g.gimbals))
        gid = gimbals.gimbals[0].gimbal_id
        await system.gimbal.take_control(gid, ControlMode.PRIMARY)
        await system.gimbal.set_angles(gid, 0.0, -35.0, 0.0, GimbalMode.YAW_FOLLOW,
                                       SendMode.ONCE)
        return await first(system.gimbal.attitude(),
                           lambda a: abs(a.euler_angle_forward.pitch_deg + 35.0) < 0.2)

    att = run_sdk(VehicleParams(autopilot=autopilot, payload=True), body)
    assert att.gimbal_id == 1
