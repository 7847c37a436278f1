"""The simulated autopilots answer bad MAVLink as ArduPilot and PX4 do, never with a dead fleet.

Regression of "one COMMAND_LONG kills the simulated fleet": MAVSDK's ``action.arm()`` sends
MAV_CMD_COMPONENT_ARM_DISARM with param1 = 1 and every unused parameter NaN; the PX4 vehicle
raised ``ValueError: cannot convert float NaN to integer`` in the fleet thread. Each test
drives the vehicles over loopback UDP with a raw pymavlink client (:mod:`tests.vehicle_harness`).
"""

from __future__ import annotations

import logging
import math
import time

import pytest

from agent.clock import WallClock
from agent.wire.mavlink import mavlink, mavutil
from groundstation.vehicle.fleet import SimFleet
from groundstation.vehicle.params import VehicleParams
from tests.vehicle_harness import Harness

M = mavlink
NAN = math.nan
ARM = M.MAV_CMD_COMPONENT_ARM_DISARM


def _command(h: Harness, cmd: int, *params: float, target: tuple[int, int] = (1, 1)) -> int | None:
    """COMMAND_LONG (unused params NaN, as MAVSDK sends them); the ACK's result, None if no
    ACK came within 0.5 s of simulation."""
    p = [*params, NAN, NAN, NAN, NAN, NAN, NAN, NAN][:7]
    h.client.mav.command_long_send(*target, cmd, 0, *p)
    ack = h.wait_for("COMMAND_ACK", lambda m: m.command == cmd, sim_s=0.5)
    return None if ack is None else int(ack.result)


@pytest.mark.parametrize("autopilot", ["px4", "ardupilot"])
def test_mavsdk_arm_and_disarm_with_nan_params_are_acked_and_the_vehicle_lives(
        autopilot: str) -> None:
    with Harness(VehicleParams(autopilot=autopilot)) as h:
        # PX4: a NaN param2 is not the force value (lroundf(param2) != 21196): a normal arm.
        assert _command(h, ARM, 1.0) == M.MAV_RESULT_ACCEPTED
        assert h.quad.armed
        assert _command(h, ARM, 0.0) == M.MAV_RESULT_ACCEPTED  # on the ground: disarms
        assert not h.quad.armed
        h.of("HEARTBEAT")
        h.run(3.0)
        assert len(h.of("HEARTBEAT")) >= 2  # still alive and talking
        assert h.fleet.handler_errors == 0  # answered by the handlers, not caught by the guard


@pytest.mark.parametrize(("autopilot", "param1", "result"), [
    # ArduPilot: arm only for param1 == 1, disarm for 0, anything else UNSUPPORTED
    # (GCS_MAVLINK::handle_command_component_arm_disarm).
    ("ardupilot", NAN, M.MAV_RESULT_UNSUPPORTED),
    ("ardupilot", math.inf, M.MAV_RESULT_UNSUPPORTED),
    ("ardupilot", 0.7, M.MAV_RESULT_UNSUPPORTED),
    ("ardupilot", 2.0, M.MAV_RESULT_UNSUPPORTED),
    # PX4: lroundf(param1) must be 0 or 1, else "Unsupported ARM_DISARM param" (Commander).
    ("px4", NAN, M.MAV_RESULT_UNSUPPORTED),
    ("px4", -math.inf, M.MAV_RESULT_UNSUPPORTED),
    ("px4", 2.0, M.MAV_RESULT_UNSUPPORTED),
    ("px4", 0.7, M.MAV_RESULT_ACCEPTED),
])
def test_arm_disarm_param1_as_each_autopilot_reads_it(autopilot: str, param1: float,
                                                      result: int) -> None:
    with Harness(VehicleParams(autopilot=autopilot)) as h:
        assert _command(h, ARM, param1, 0.0) == result
        assert h.quad.armed == (result == M.MAV_RESULT_ACCEPTED)
        assert h.fleet.handler_errors == 0


@pytest.mark.parametrize("autopilot", ["px4", "ardupilot"])
def test_non_finite_and_out_of_range_numbers_are_denied(autopilot: str) -> None:
    with Harness(VehicleParams(autopilot=autopilot)) as h:
        custom = 6 if autopilot == "px4" else 20
        assert _command(h, M.MAV_CMD_DO_SET_MODE, NAN, custom) == M.MAV_RESULT_DENIED
        assert _command(h, M.MAV_CMD_DO_SET_MODE, 1, NAN) == M.MAV_RESULT_DENIED
        assert _command(h, M.MAV_CMD_DO_SET_MODE, 1, -math.inf) == M.MAV_RESULT_DENIED
        assert _command(h, M.MAV_CMD_DO_SET_MODE, 1, 1e30) == M.MAV_RESULT_DENIED
        att = M.MAVLINK_MSG_ID_ATTITUDE
        assert _command(h, M.MAV_CMD_SET_MESSAGE_INTERVAL, att, NAN) == M.MAV_RESULT_DENIED
        assert _command(h, M.MAV_CMD_SET_MESSAGE_INTERVAL, att, math.inf) == M.MAV_RESULT_DENIED
        assert _command(h, M.MAV_CMD_SET_MESSAGE_INTERVAL, att, 1e30) == M.MAV_RESULT_DENIED
        assert _command(h, M.MAV_CMD_SET_MESSAGE_INTERVAL, NAN, 1e5) == M.MAV_RESULT_DENIED
        assert _command(h, M.MAV_CMD_GET_MESSAGE_INTERVAL, NAN) == M.MAV_RESULT_DENIED
        assert _command(h, M.MAV_CMD_GET_MESSAGE_INTERVAL, 1e9) == M.MAV_RESULT_DENIED
        assert _command(h, M.MAV_CMD_REQUEST_MESSAGE, -math.inf) == M.MAV_RESULT_DENIED
        assert _command(h, 31999) == M.MAV_RESULT_UNSUPPORTED  # a command nobody handles
        # The stream intervals were not touched: ATTITUDE still at its default rate.
        assert _command(h, M.MAV_CMD_GET_MESSAGE_INTERVAL, att) == M.MAV_RESULT_ACCEPTED
        reply = h.wait_for("MESSAGE_INTERVAL")
        assert reply is not None and reply.interval_us == round(1e6 / 30.0)
        assert h.fleet.handler_errors == 0


def test_commands_for_another_target_are_ignored_as_each_autopilot_does() -> None:
    with Harness(VehicleParams()) as h:
        # ArduPilot (MAVLink_routing): processed when target system and component are ours
        # or broadcast (0); otherwise not processed and not acknowledged.
        assert _command(h, ARM, 1.0, target=(1, 7)) is None
        assert _command(h, ARM, 1.0, target=(2, 1)) is None
        assert not h.quad.armed
        assert _command(h, ARM, 1.0, target=(0, 0)) == M.MAV_RESULT_ACCEPTED
        h.client.mav.param_set_send(1, 42, b"GUID_OPTIONS", 8.0, M.MAV_PARAM_TYPE_REAL32)
        h.run(0.1)
        assert h.quad.params_table["GUID_OPTIONS"] == 0 and not h.of("PARAM_VALUE")
    with Harness(VehicleParams(autopilot="px4")) as h:
        # PX4 (MavlinkReceiver::evaluate_target_ok): commands need our system id; component
        # ours or 0. REQUEST_AUTOPILOT_CAPABILITIES also takes system 0, any component.
        assert _command(h, ARM, 1.0, target=(0, 1)) is None
        assert _command(h, ARM, 1.0, target=(1, 7)) is None
        assert not h.quad.armed
        caps = M.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES
        assert _command(h, caps, 1.0, target=(0, 99)) == M.MAV_RESULT_ACCEPTED
        assert _command(h, ARM, 1.0, target=(1, 0)) == M.MAV_RESULT_ACCEPTED
        assert h.fleet.handler_errors == 0


def test_px4_refuses_an_in_flight_disarm_as_temporarily_rejected() -> None:
    with Harness(VehicleParams(autopilot="px4")) as h:
        h.every = lambda: h.attitude(0.8)
        h.run(0.1)
        assert _command(h, M.MAV_CMD_DO_SET_MODE, 1, 6) == M.MAV_RESULT_ACCEPTED
        assert _command(h, ARM, 1.0) == M.MAV_RESULT_ACCEPTED
        h.run(1.0)
        assert h.altitude() > 0.2
        # Commander::disarm: not landed and not forced -> TRANSITION_DENIED ->
        # VEHICLE_CMD_RESULT_TEMPORARILY_REJECTED; NaN param2 is not the force value.
        assert _command(h, ARM, 0.0) == M.MAV_RESULT_TEMPORARILY_REJECTED
        assert h.quad.armed
        assert _command(h, ARM, 0.0, 21196.0) == M.MAV_RESULT_ACCEPTED
        assert not h.quad.armed


def test_the_fleet_thread_survives_an_exception_from_one_message(
        caplog: pytest.LogCaptureFixture, monkeypatch: pytest.MonkeyPatch) -> None:
    """The last line of defence: a handler bug costs that message, not the fleet."""
    fleet = SimFleet(["A", "B"], WallClock(), VehicleParams(autopilot="px4"))
    broken = fleet.quads[0]

    def boom(*_a: object) -> None:
        raise RuntimeError("handler bug")

    monkeypatch.setattr(broken, "_on_attitude_target", boom)
    gcs = mavutil.mavlink_connection(f"udpout:127.0.0.1:{broken.port}", source_system=255)
    try:
        with caplog.at_level(logging.ERROR, logger="viscover.groundstation.vehicle"):
            fleet.start()
            for _ in range(5):
                gcs.mav.set_attitude_target_send(0, 1, 1, 7, [1.0, 0, 0, 0], 0, 0, 0, 0.5)
            time.sleep(0.3)
            assert fleet.handler_errors == 5
            gcs.mav.command_long_send(1, 1, ARM, 0, 1, NAN, NAN, NAN, NAN, NAN, NAN)
            ack = gcs.recv_match(type="COMMAND_ACK", blocking=True, timeout=2.0)
            assert ack is not None and ack.result == M.MAV_RESULT_ACCEPTED
            assert fleet._thread is not None and fleet._thread.is_alive()
        lines = [r.getMessage() for r in caplog.records if r.levelno >= logging.ERROR]
        assert len(lines) == 1  # rate-limited: one line for the burst
        assert "A: handling SET_ATTITUDE_TARGET from 255/" in lines[0]
        assert "RuntimeError: handler bug" in lines[0]
    finally:
        gcs.close()
        fleet.close()
