"""The simulated vehicle on the wire, as a raw pymavlink ground station sees it: telemetry
that arrives unasked, HEARTBEAT flags, the parameter protocol with each autopilot's typing,
AUTOPILOT_VERSION, message intervals and COMMAND_ACK addressing."""

from __future__ import annotations

import struct
from typing import Any

import pytest

from agent.wire.mavlink import mavlink, mavutil, px4_custom_mode
from groundstation.vehicle.params import VehicleParams
from tests.vehicle_harness import Harness

M = mavlink


def test_telemetry_streams_unasked_to_the_configured_gcs() -> None:
    gcs = mavutil.mavlink_connection("udpin:127.0.0.1:0")
    port = gcs.port.getsockname()[1]
    try:
        with Harness(VehicleParams(gcs=f"udp:127.0.0.1:{port}")) as h:
            h.run(2.05)
            got: dict[str, list[Any]] = {}  # pymavlink messages (untyped)
            while (m := gcs.recv_match(blocking=False)) is not None:
                got.setdefault(m.get_type(), []).append(m)
    finally:
        gcs.close()
    # The ground station never sent a byte, yet it has the SITL-style streams.
    assert 2 <= len(got["HEARTBEAT"]) <= 3
    for kind in ("SYS_STATUS", "EXTENDED_SYS_STATE", "BATTERY_STATUS"):
        assert len(got[kind]) >= 2, kind
    assert len(got["ATTITUDE"]) >= 50 and len(got["LOCAL_POSITION_NED"]) >= 50  # 30 Hz
    hb = got["HEARTBEAT"][-1]
    assert hb.autopilot == M.MAV_AUTOPILOT_ARDUPILOTMEGA and hb.type == M.MAV_TYPE_QUADROTOR
    # ArduCopter on the ground in STABILIZE: custom mode, stabilize and manual-input flags.
    assert hb.base_mode == (M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | M.MAV_MODE_FLAG_STABILIZE_ENABLED
                            | M.MAV_MODE_FLAG_MANUAL_INPUT_ENABLED)
    assert hb.custom_mode == 0 and hb.system_status == M.MAV_STATE_STANDBY
    assert got["EXTENDED_SYS_STATE"][-1].landed_state == M.MAV_LANDED_STATE_ON_GROUND
    assert got["BATTERY_STATUS"][-1].battery_remaining == 100


def test_answers_whoever_sends_and_acks_to_the_sender() -> None:
    with Harness(VehicleParams(), source_system=42, source_component=191) as h:
        assert h.wait_for("HEARTBEAT") is None  # nobody asked: nothing to this client yet
        h.client.mav.heartbeat_send(M.MAV_TYPE_ONBOARD_CONTROLLER, M.MAV_AUTOPILOT_INVALID,
                                    0, 0, M.MAV_STATE_ACTIVE)
        assert h.wait_for("HEARTBEAT") is not None  # now it streams to us too
        h.client.mav.command_long_send(1, 1, M.MAV_CMD_REQUEST_MESSAGE, 0,
                                       M.MAVLINK_MSG_ID_AUTOPILOT_VERSION, 0, 0, 0, 0, 0, 0)
        ack = h.wait_for("COMMAND_ACK")
        assert ack.result == M.MAV_RESULT_ACCEPTED
        assert (ack.target_system, ack.target_component) == (42, 191)
        ver = h.wait_for("AUTOPILOT_VERSION")
        assert ver.capabilities & M.MAV_PROTOCOL_CAPABILITY_MAVLINK2
        assert ver.capabilities & M.MAV_PROTOCOL_CAPABILITY_PARAM_FLOAT
        assert ver.flight_sw_version >> 24 == 4  # ArduCopter 4.x


def test_messages_for_another_system_are_not_processed() -> None:
    with Harness(VehicleParams()) as h:
        h.client.mav.command_long_send(7, 1, M.MAV_CMD_COMPONENT_ARM_DISARM, 0,
                                       1, 0, 0, 0, 0, 0, 0)
        h.run(0.2)
        assert not h.quad.armed and not h.of("COMMAND_ACK")


def test_ardupilot_parameter_protocol_and_types() -> None:
    with Harness(VehicleParams(hover_thrust=0.42)) as h:
        h.client.mav.param_request_list_send(1, 1)
        h.run(0.2)
        values = {str(m.param_id): m for m in h.of("PARAM_VALUE")}
        count = len(h.quad.params_table)
        assert len(values) == count and {m.param_count for m in values.values()} == {count}
        assert sorted(m.param_index for m in values.values()) == list(range(count))
        assert values["GUID_OPTIONS"].param_type == M.MAV_PARAM_TYPE_INT32
        assert values["VISO_TYPE"].param_type == M.MAV_PARAM_TYPE_INT8
        assert values["VISO_TYPE"].param_value == 0.0  # mocap ignored by default
        assert values["EK3_SRC1_POSXY"].param_value == 3.0  # GPS
        assert values["GUID_TIMEOUT"].param_type == M.MAV_PARAM_TYPE_REAL32
        assert values["MOT_THST_HOVER"].param_value == pytest.approx(0.42)  # the true hover
        # By index, then a write: the float on the wire becomes the parameter's own type.
        idx = values["GUID_OPTIONS"].param_index
        h.client.mav.param_request_read_send(1, 1, b"", idx)
        assert h.wait_for("PARAM_VALUE").param_id == "GUID_OPTIONS"
        h.client.mav.param_set_send(1, 1, b"GUID_OPTIONS", 8.0, M.MAV_PARAM_TYPE_REAL32)
        m = h.wait_for("PARAM_VALUE", lambda m: m.param_id == "GUID_OPTIONS")
        assert m.param_value == 8.0 and m.param_type == M.MAV_PARAM_TYPE_INT32
        h.client.mav.param_set_send(1, 1, b"VISO_TYPE", 1.7, M.MAV_PARAM_TYPE_REAL32)
        assert h.wait_for("PARAM_VALUE").param_value == 1.0  # cast to AP_Int8
        h.client.mav.param_set_send(1, 1, b"NO_SUCH_PARAM", 1.0, M.MAV_PARAM_TYPE_REAL32)
        assert h.wait_for("PARAM_VALUE", sim_s=0.3) is None


def test_px4_parameters_are_bytewise_int32() -> None:
    with Harness(VehicleParams(autopilot="px4", hover_thrust=0.38, setpoint_timeout=None,
                               params={"EKF2_EV_CTRL": 0})) as h:
        h.client.mav.param_request_read_send(1, 1, b"EKF2_EV_CTRL", -1)
        m = h.wait_for("PARAM_VALUE")
        assert m.param_type == M.MAV_PARAM_TYPE_INT32
        assert struct.unpack("<i", struct.pack("<f", m.param_value))[0] == 0  # misconfigured
        wire = struct.unpack("<f", struct.pack("<i", 9))[0]  # QGC / MAVSDK style
        h.client.mav.param_set_send(1, 1, b"EKF2_EV_CTRL", wire, M.MAV_PARAM_TYPE_INT32)
        m = h.wait_for("PARAM_VALUE")
        assert struct.unpack("<i", struct.pack("<f", m.param_value))[0] == 9
        assert h.quad.params_table["EKF2_EV_CTRL"] == 9
        h.client.mav.param_request_read_send(1, 1, b"MPC_THR_HOVER", -1)
        m = h.wait_for("PARAM_VALUE")
        assert m.param_type == M.MAV_PARAM_TYPE_REAL32 and m.param_value == pytest.approx(0.38)
        assert h.quad.params_table["COM_OF_LOSS_T"] == 1.0  # PX4's default kept


def test_configuration_is_per_vehicle_and_checked() -> None:
    wrong = VehicleParams(params={"GUID_TIMEOUT": 5.0, "MOT_THST_HOVER": 0.3})
    right = VehicleParams(setpoint_timeout=None)
    with Harness([wrong, right], n=2) as h:
        a, b = h.fleet.quads
        assert a.params_table["GUID_TIMEOUT"] == 5.0 and a.params_table["MOT_THST_HOVER"] == 0.3
        assert b.params_table["GUID_TIMEOUT"] == 3.0 and b.params_table["MOT_THST_HOVER"] == 0.5
        assert (a.sysid, b.sysid) == (1, 2) and b.params_table["SYSID_THISMAV"] == 2
    with pytest.raises(ValueError, match="unknown ardupilot parameter"):
        Harness(VehicleParams(params={"EKF2_EV_CTRL": 1}))


def test_message_intervals_and_requests() -> None:
    with Harness(VehicleParams()) as h:
        h.client.mav.heartbeat_send(M.MAV_TYPE_GCS, M.MAV_AUTOPILOT_INVALID, 0, 0, 0)
        assert h.command(M.MAV_CMD_SET_MESSAGE_INTERVAL, M.MAVLINK_MSG_ID_ATTITUDE,
                         100_000) == M.MAV_RESULT_ACCEPTED
        h.of("ATTITUDE")
        h.run(2.0)
        assert 19 <= len(h.of("ATTITUDE")) <= 21  # 10 Hz
        assert h.command(M.MAV_CMD_GET_MESSAGE_INTERVAL, M.MAVLINK_MSG_ID_ATTITUDE) == 0
        assert h.wait_for("MESSAGE_INTERVAL").interval_us == 100_000
        h.command(M.MAV_CMD_SET_MESSAGE_INTERVAL, M.MAVLINK_MSG_ID_ATTITUDE, -1)
        h.of("ATTITUDE")
        h.run(1.0)
        assert not h.of("ATTITUDE")
        h.command(M.MAV_CMD_SET_MESSAGE_INTERVAL, M.MAVLINK_MSG_ID_ATTITUDE, 0)  # default
        h.run(1.0)
        assert len(h.of("ATTITUDE")) >= 25
        assert h.command(M.MAV_CMD_REQUEST_MESSAGE, M.MAVLINK_MSG_ID_HOME_POSITION) == 0
        assert h.wait_for("HOME_POSITION") is not None
        assert h.command(M.MAV_CMD_REQUEST_MESSAGE, 9999) == M.MAV_RESULT_UNSUPPORTED
        # ArduPilot's legacy REQUEST_DATA_STREAM: POSITION at 2 Hz.
        h.client.mav.request_data_stream_send(1, 1, M.MAV_DATA_STREAM_POSITION, 2, 1)
        h.run(0.1)
        h.of("LOCAL_POSITION_NED")
        h.run(2.0)
        assert 3 <= len(h.of("LOCAL_POSITION_NED")) <= 5


def test_heartbeat_flags_follow_mode_and_arming() -> None:
    with Harness(VehicleParams()) as h:
        h.client.mav.heartbeat_send(M.MAV_TYPE_GCS, M.MAV_AUTOPILOT_INVALID, 0, 0, 0)
        assert h.set_mode(20) == M.MAV_RESULT_ACCEPTED
        assert h.arm() == M.MAV_RESULT_ACCEPTED
        h.of("HEARTBEAT")
        hb = h.wait_for("HEARTBEAT", sim_s=1.5)
        assert hb.custom_mode == 20 and hb.base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED
        assert not hb.base_mode & M.MAV_MODE_FLAG_GUIDED_ENABLED  # angle control: NE idle
        assert hb.system_status == M.MAV_STATE_STANDBY  # armed but land_complete
        assert h.set_mode(99) == M.MAV_RESULT_FAILED  # unknown ArduCopter mode
        assert h.command(M.MAV_CMD_DO_SET_MODE, 0, 4) == M.MAV_RESULT_DENIED  # no custom flag
    with Harness(VehicleParams(autopilot="px4")) as h:
        h.client.mav.heartbeat_send(M.MAV_TYPE_GCS, M.MAV_AUTOPILOT_INVALID, 0, 0, 0)
        h.every = lambda: h.attitude(0.0)
        h.run(0.1)  # PX4 needs a set-point newer than COM_OF_LOSS_T before OFFBOARD
        assert h.set_mode(6) == M.MAV_RESULT_ACCEPTED and h.arm() == M.MAV_RESULT_ACCEPTED
        h.of("HEARTBEAT")
        hb = h.wait_for("HEARTBEAT", sim_s=1.5)
        assert hb.autopilot == M.MAV_AUTOPILOT_PX4 and hb.custom_mode == px4_custom_mode(6)
        flags = (M.MAV_MODE_FLAG_AUTO_ENABLED | M.MAV_MODE_FLAG_GUIDED_ENABLED
                 | M.MAV_MODE_FLAG_STABILIZE_ENABLED | M.MAV_MODE_FLAG_SAFETY_ARMED
                 | M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED)
        assert hb.base_mode == flags and hb.system_status == M.MAV_STATE_ACTIVE
        ver_ack = h.command(M.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES, 1)
        assert ver_ack == 0
        ver = h.wait_for("AUTOPILOT_VERSION")
        assert ver.capabilities & M.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE
