"""Boundary and random input to the outdoor equipment of the simulated vehicles (camera,
gimbal, mission / fence protocol): every command to the autopilot or the camera component is
answered with exactly one COMMAND_ACK, nothing reaches the fleet's last-line guard, and the
vehicle still flies afterwards. Seeded and bounded."""

from __future__ import annotations

import math

import numpy as np
import pytest

from agent.wire.mavlink import ARDUPILOT_MODES as APM
from groundstation.vehicle.params import VehicleParams
from tests.sim_vehicle_helpers import M, hello, result
from tests.vehicle_harness import Harness

VALUES = (math.nan, math.inf, -math.inf, 0.0, -1.0, 1.0, 2.0, 255.0, 1e9, -1e30, 0.5, 3.4e38)
COMMANDS = (M.MAV_CMD_IMAGE_START_CAPTURE, M.MAV_CMD_IMAGE_STOP_CAPTURE,
            M.MAV_CMD_DO_DIGICAM_CONTROL, M.MAV_CMD_REQUEST_MESSAGE,
            M.MAV_CMD_REQUEST_CAMERA_INFORMATION, M.MAV_CMD_REQUEST_CAMERA_CAPTURE_STATUS,
            M.MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW, M.MAV_CMD_DO_GIMBAL_MANAGER_CONFIGURE,
            M.MAV_CMD_DO_FENCE_ENABLE, M.MAV_CMD_SET_CAMERA_MODE)
MISSION_TYPES = (0, 1, 2, 7, 255)


@pytest.mark.parametrize("autopilot", ["ardupilot", "px4"])
def test_random_equipment_input_is_answered_not_crashed(autopilot: str) -> None:
    rng = np.random.default_rng(2026)
    px4 = autopilot == "px4"

    def v() -> float:
        return float(VALUES[rng.integers(len(VALUES))]) if rng.random() < 0.7 else \
            float(rng.normal(0.0, 100.0))

    with hello(Harness(VehicleParams(autopilot=autopilot, payload=True, gnss="rtk"))) as h:
        mav = h.client.mav
        sent = 0
        for k in range(300):
            cmd = int(COMMANDS[rng.integers(len(COMMANDS))])
            comp = M.MAV_COMP_ID_CAMERA if (px4 and rng.random() < 0.5) else 1
            mav.command_long_send(1, comp, cmd, 0, *(v() for _ in range(7)))
            sent += 1
            kind = rng.integers(6)
            mtype = int(MISSION_TYPES[rng.integers(len(MISSION_TYPES))])
            if kind == 0:
                mav.mission_count_send(1, 1, int(rng.integers(0, 400)), mtype)
            elif kind == 1:
                mav.mission_item_int_send(
                    1, 1, int(rng.integers(0, 5)), int(rng.integers(0, 12)),
                    int(rng.choice([5001, 5002, 5003, 5004, 5000, 16, 0, 65535])), 0, 1,
                    v(), v(), v(), v(), int(rng.integers(-2**31, 2**31 - 1)),
                    int(rng.integers(-2**31, 2**31 - 1)), v(), mtype)
            elif kind == 2:
                mav.mission_request_int_send(1, 1, int(rng.integers(0, 65535)), mtype)
            elif kind == 3:
                mav.mission_item_send(1, 1, int(rng.integers(0, 5)), 6, 5003, 0, 1, v(), v(),
                                      v(), v(), v(), v(), v(), mtype)
            elif kind == 4:
                mav.gimbal_manager_set_pitchyaw_send(1, 1, int(rng.integers(0, 2**32 - 1)),
                                                     int(rng.integers(0, 256)), v(), v(), v(),
                                                     v())
            else:
                mav.mission_clear_all_send(1, 1, mtype)
            if k % 10 == 9:
                h.run(0.05)
        h.run(1.0)
        acks = h.of("COMMAND_ACK")
        assert len(acks) == sent  # exactly one each (the camera's from the camera)
        assert h.fleet.handler_errors == 0
        # Still a working vehicle: the fence and gimbal answer, it arms in a position mode.
        h.of("MISSION_ACK")
        h.client.mav.mission_clear_all_send(1, 1, M.MAV_MISSION_TYPE_FENCE)
        assert h.wait_for("MISSION_ACK").type == M.MAV_MISSION_ACCEPTED
        assert result(h, M.MAV_CMD_REQUEST_MESSAGE,
                      M.MAVLINK_MSG_ID_GIMBAL_MANAGER_INFORMATION) == M.MAV_RESULT_ACCEPTED
        h.quad.params_table["GF_ACTION" if px4 else "FENCE_ENABLE"] = 0
        assert h.set_mode(3 << 16 if px4 else APM["LOITER"]) == M.MAV_RESULT_ACCEPTED
        assert h.arm() == M.MAV_RESULT_ACCEPTED
