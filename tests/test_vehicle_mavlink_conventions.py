"""MAVLink conventions ground stations and SDKs rely on, answered as ArduPilot and PX4 answer.

Each test drives the simulated vehicles over loopback UDP with a raw pymavlink client
(:mod:`tests.vehicle_harness`, manual clock). The expected answers are the autopilots' own
(sources in :mod:`groundstation.vehicle.conventions` and :mod:`groundstation.vehicle.modes`).
The geodetic checks use the flat-earth offset ArduPilot's ``Location::offset`` uses (earth
radius 6378100 m) from each flavour's documented SITL origin.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from agent.flight.frames import quat_from_euler
from agent.wire.mavlink import mavlink, px4_custom_mode
from groundstation.vehicle.params import VehicleParams
from tests.vehicle_harness import Harness

M = mavlink
NAN = math.nan
AP_GUIDED, AP_GUIDED_NOGPS = 4, 20
P_TAKEOFF, P_LOITER = px4_custom_mode(4, 2), px4_custom_mode(4, 3)
#: ArduPilot SITL's default location (CMAC) and PX4 SITL's (PX4_HOME_*): lat, lon [deg], alt [m].
ORIGIN = {"ardupilot": (-35.363261, 149.165230, 584.0), "px4": (47.397742, 8.545594, 488.0)}
INDOOR_AP: dict[str, float] = {"VISO_TYPE": 1, "EK3_SRC1_POSXY": 6, "EK3_SRC1_POSZ": 6}


def _geodetic(autopilot: str, north: float, east: float) -> tuple[float, float]:
    lat0, lon0, _ = ORIGIN[autopilot]
    deg_per_m = 180.0 / (math.pi * 6378100.0)
    return lat0 + north * deg_per_m, lon0 + east * deg_per_m / math.cos(math.radians(lat0))


def _hello(h: Harness) -> Harness:
    """A ground station's HEARTBEAT: the vehicle streams to peers it has heard from."""
    h.client.mav.heartbeat_send(M.MAV_TYPE_GCS, M.MAV_AUTOPILOT_INVALID, 0, 0, 0)
    h.run(0.01)
    return h


def _command(h: Harness, cmd: int, *params: float) -> int:
    """COMMAND_LONG with unused params NaN (as MAVSDK sends them); the ACK's result."""
    p = [*params, NAN, NAN, NAN, NAN, NAN, NAN, NAN][:7]
    h.client.mav.command_long_send(1, 1, cmd, 0, *p)
    ack = h.wait_for("COMMAND_ACK", lambda m: m.command == cmd, sim_s=0.5)
    assert ack is not None, f"no COMMAND_ACK for {cmd}"
    return int(ack.result)


def _takeoff(h: Harness, alt: float = NAN) -> int:
    return _command(h, M.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, NAN, NAN, NAN, alt)


def test_arducopter_nav_takeoff_in_guided() -> None:
    with Harness(VehicleParams(params=INDOOR_AP)) as h:
        _hello(h)
        h.every = h.vision  # mocap forwarded: the EKF has a position
        h.run(0.3)
        assert h.set_mode(AP_GUIDED) == M.MAV_RESULT_ACCEPTED
        assert _takeoff(h, 2.0) == M.MAV_RESULT_FAILED  # do_user_takeoff: disarmed
        assert h.arm() == M.MAV_RESULT_ACCEPTED
        assert _takeoff(h, -1.0) == M.MAV_RESULT_FAILED  # can't take off downwards
        # COMMAND_INT must say MAV_FRAME_GLOBAL_RELATIVE_ALT, else DENIED (bad parameters).
        h.client.mav.command_int_send(1, 1, M.MAV_FRAME_GLOBAL, M.MAV_CMD_NAV_TAKEOFF, 0, 0,
                                      0, 0, 0, 0, 0, 0, 2.0)
        ack = h.wait_for("COMMAND_ACK", lambda m: m.command == M.MAV_CMD_NAV_TAKEOFF)
        assert ack.result == M.MAV_RESULT_DENIED
        assert _takeoff(h, 2.0) == M.MAV_RESULT_ACCEPTED  # param7: metres above home
        h.run(6.0)
        assert h.altitude() == pytest.approx(2.0, abs=0.1) and h.quad.mode == AP_GUIDED
        assert _takeoff(h, 3.0) == M.MAV_RESULT_FAILED  # not land_complete: no second one
        h.of("GLOBAL_POSITION_INT")
        gp = h.wait_for("GLOBAL_POSITION_INT")
        assert gp.relative_alt == pytest.approx(2000, abs=100)  # mm above home
        assert gp.alt - gp.relative_alt == pytest.approx(584_000, abs=2)  # mm AMSL of home


def test_px4_nav_takeoff_climbs_to_mis_takeoff_alt_then_holds() -> None:
    with Harness(VehicleParams(autopilot="px4", indoor=True)) as h:
        _hello(h)
        h.every = h.vision
        h.run(0.3)
        # Disarmed: any mode change is allowed (UserModeIntention); AUTO.TAKEOFF waits.
        assert _takeoff(h) == M.MAV_RESULT_ACCEPTED and h.quad.mode == P_TAKEOFF
        assert h.arm() == M.MAV_RESULT_ACCEPTED
        h.run(8.0)  # NaN param7: home + MIS_TAKEOFF_ALT (2.5 m), then AUTO.LOITER
        assert h.altitude() == pytest.approx(2.5, abs=0.1) and h.quad.mode == P_LOITER
    with Harness(VehicleParams(autopilot="px4", indoor=True)) as h:
        _hello(h)
        h.every = lambda: h.attitude(0.0)
        h.run(0.2)
        assert h.set_mode(6) == 0 and h.arm() == 0  # OFFBOARD, armed, no position estimate
        assert _takeoff(h) == M.MAV_RESULT_TEMPORARILY_REJECTED  # AUTO.TAKEOFF can't run


@pytest.mark.parametrize("autopilot", ["ardupilot", "px4"])
def test_get_home_position_answers_and_home_is_reset_at_arming(autopilot: str) -> None:
    start = np.array([[3.0, 4.0, 0.0]])  # ENU: 4 m north, 3 m east of the EKF origin
    with Harness(VehicleParams(autopilot=autopilot), start=start) as h:
        _hello(h)
        assert _command(h, M.MAV_CMD_GET_HOME_POSITION) == M.MAV_RESULT_ACCEPTED
        home = h.wait_for("HOME_POSITION")
        lat, lon = _geodetic(autopilot, 4.0, 3.0)
        assert home.latitude == pytest.approx(lat * 1e7, abs=1)
        assert home.longitude == pytest.approx(lon * 1e7, abs=1)
        assert home.altitude == pytest.approx(ORIGIN[autopilot][2] * 1000, abs=1)
        assert (home.x, home.y, home.z) == pytest.approx((4.0, 3.0, 0.0), abs=1e-3)
        h.fleet.p[0, :2] = (-2.0, 5.0)  # carried elsewhere before arming
        h.run(0.05)
        assert h.arm() == M.MAV_RESULT_ACCEPTED
        h.of("HOME_POSITION")
        assert _command(h, M.MAV_CMD_GET_HOME_POSITION) == M.MAV_RESULT_ACCEPTED
        home = h.wait_for("HOME_POSITION")
        assert (home.x, home.y) == pytest.approx((-2.0, 5.0), abs=1e-3)


@pytest.mark.parametrize(("autopilot", "rate"), [("ardupilot", 30.0), ("px4", 5.0)])
def test_global_position_int_streams_position_from_the_ekf_origin(autopilot: str,
                                                                  rate: float) -> None:
    start = np.array([[-6.0, 10.0, 0.0]])  # ENU → NED (10, -6, 0)
    with Harness(VehicleParams(autopilot=autopilot), start=start) as h:
        _hello(h)
        h.fleet.att[0, 2] = math.radians(-30.0)  # heading 330° (NED yaw)
        h.run(2.0)
        msgs = h.of("GLOBAL_POSITION_INT")
        assert len(msgs) == pytest.approx(2.0 * rate, abs=2)  # ArduPilot SR POSITION / PX4 5 Hz
        gp = msgs[-1]
        lat, lon = _geodetic(autopilot, 10.0, -6.0)
        assert gp.lat == pytest.approx(lat * 1e7, abs=1) and gp.lon == pytest.approx(lon * 1e7,
                                                                                    abs=1)
        assert gp.alt == pytest.approx(ORIGIN[autopilot][2] * 1000, abs=1) and gp.relative_alt == 0
        assert (gp.vx, gp.vy, gp.vz) == (0, 0, 0)
        assert gp.hdg == pytest.approx(33000, abs=1)  # cdeg, 0..35999


@pytest.mark.parametrize("autopilot", ["ardupilot", "px4"])
def test_attitude_quaternion_default_and_requested_rates(autopilot: str) -> None:
    with Harness(VehicleParams(autopilot=autopilot)) as h:
        _hello(h)
        h.fleet.att[0] = (0.05, -0.02, 1.0)
        h.run(1.0)
        got = h.of("ATTITUDE_QUATERNION")
        if autopilot == "px4":
            assert len(got) == pytest.approx(10, abs=1)  # PX4 "normal" link: 10 Hz
        else:
            assert not got  # ArduPilot: in no stream group, only on request
        assert _command(h, M.MAV_CMD_SET_MESSAGE_INTERVAL,
                        M.MAVLINK_MSG_ID_ATTITUDE_QUATERNION, 50_000) == M.MAV_RESULT_ACCEPTED
        h.of("ATTITUDE_QUATERNION")
        h.run(1.0)
        got = h.of("ATTITUDE_QUATERNION")
        assert len(got) == pytest.approx(20, abs=1)
        q = np.array([got[-1].q1, got[-1].q2, got[-1].q3, got[-1].q4])
        expected = quat_from_euler(*(float(a) for a in h.fleet.att[0]))
        assert np.allclose(q, expected, atol=1e-3) and list(got[-1].repr_offset_q) == [0.0] * 4


@pytest.mark.parametrize(("autopilot", "name", "value", "ptype"), [
    ("ardupilot", "FRAME_CLASS", 1.0, M.MAV_PARAM_TYPE_INT8),  # 1 = Quad
    ("ardupilot", "FRAME_TYPE", 1.0, M.MAV_PARAM_TYPE_INT8),  # 1 = X
    ("ardupilot", "FENCE_TYPE", 7.0, M.MAV_PARAM_TYPE_INT8),  # alt max | circle | polygon
    ("px4", "SYS_AUTOSTART", 4001.0, M.MAV_PARAM_TYPE_INT32),  # SITL x500 quadrotor
    ("px4", "MIS_TAKEOFF_ALT", 2.5, M.MAV_PARAM_TYPE_REAL32),  # m
])
def test_parameters_clients_read(autopilot: str, name: str, value: float, ptype: int) -> None:
    with Harness(VehicleParams(autopilot=autopilot)) as h:
        _hello(h)
        h.client.mav.param_request_read_send(1, 1, name.encode(), -1)
        pv = h.wait_for("PARAM_VALUE", lambda m: m.param_id == name)
        assert pv is not None and pv.param_type == ptype
        if autopilot == "px4" and ptype == M.MAV_PARAM_TYPE_INT32:  # PX4: int32 byte-wise
            assert np.array([pv.param_value], np.float32).view(np.int32)[0] == value
        else:
            assert pv.param_value == value


def test_sys_status_geofence_bit_as_each_autopilot_reports_it() -> None:
    fence = M.MAV_SYS_STATUS_GEOFENCE
    with Harness(VehicleParams()) as h:  # ArduCopter: FENCE_TYPE 7 present, FENCE_ENABLE 0
        _hello(h)
        st = h.wait_for("SYS_STATUS", sim_s=1.5)
        assert st.onboard_control_sensors_present & fence
        assert not st.onboard_control_sensors_enabled & fence
        assert st.onboard_control_sensors_health & fence  # not breached: MAVProxy stays calm
    with Harness(VehicleParams(params={"FENCE_ENABLE": 1.0})) as h:
        _hello(h)
        st = h.wait_for("SYS_STATUS", sim_s=1.5)
        assert st.onboard_control_sensors_enabled & fence
        assert st.onboard_control_sensors_health & fence
    with Harness(VehicleParams(autopilot="px4")) as h:  # PX4 reports no geofence bits
        _hello(h)
        st = h.wait_for("SYS_STATUS", sim_s=1.5)
        assert not (st.onboard_control_sensors_present | st.onboard_control_sensors_enabled
                    | st.onboard_control_sensors_health) & fence


@pytest.mark.parametrize("autopilot", ["ardupilot", "px4"])
def test_prearm_bit_says_whether_arming_would_work(autopilot: str) -> None:
    """MAVSDK's ``health.is_armable`` is SYS_STATUS health & MAV_SYS_STATUS_PREARM_CHECK."""
    prearm = M.MAV_SYS_STATUS_PREARM_CHECK
    hold = (AP_GUIDED,) if autopilot == "ardupilot" else (4, 3)  # needs a position
    with Harness(VehicleParams(autopilot=autopilot)) as h:
        _hello(h)
        st = h.wait_for("SYS_STATUS", sim_s=1.5)
        assert st.onboard_control_sensors_health & prearm  # STABILIZE / MANUAL: armable
        if autopilot == "ardupilot":
            assert st.onboard_control_sensors_present & st.onboard_control_sensors_enabled \
                & prearm
        assert h.set_mode(*hold) == M.MAV_RESULT_ACCEPTED  # disarmed: any mode
        h.of("SYS_STATUS")
        st = h.wait_for("SYS_STATUS", sim_s=1.5)
        assert not st.onboard_control_sensors_health & prearm  # no position estimate
        refused = M.MAV_RESULT_FAILED if autopilot == "ardupilot" else \
            M.MAV_RESULT_TEMPORARILY_REJECTED
        assert h.arm() == refused and not h.quad.armed


def test_px4_offboard_stop_to_hold_as_mavsdk_sends_it() -> None:
    """MAVSDK ``offboard.stop()``: DO_SET_MODE param1 = custom | armed flag, AUTO, LOITER."""
    armed_flags = M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | M.MAV_MODE_FLAG_SAFETY_ARMED
    with Harness(VehicleParams(autopilot="px4", indoor=True)) as h:
        _hello(h)
        # Disarmed and without a position: PX4 still takes the mode (UserModeIntention).
        assert _command(h, M.MAV_CMD_DO_SET_MODE, M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 4, 3) \
            == M.MAV_RESULT_ACCEPTED and h.quad.mode == P_LOITER
    with Harness(VehicleParams(autopilot="px4", indoor=True)) as h:
        _hello(h)
        def fly() -> None:
            h.vision()
            up = -float(h.fleet.v[0, 2])
            h.attitude(0.5 * (1.0 + (2.0 * (1.0 - h.altitude()) - 2.5 * up) / 9.81))
        h.every = fly
        h.run(0.3)
        assert h.set_mode(6) == 0 and h.arm() == 0
        h.run(4.0)
        h.every = h.vision  # set-points stop, mocap flows
        assert _command(h, M.MAV_CMD_DO_SET_MODE, armed_flags, 4, 3) == M.MAV_RESULT_ACCEPTED
        h.run(2.0)
        assert h.quad.mode == P_LOITER and h.quad.armed
        assert h.altitude() == pytest.approx(1.0, abs=0.15)


def test_arducopter_guided_needs_a_position_only_once_armed() -> None:
    with Harness(VehicleParams(params=INDOOR_AP)) as h:
        _hello(h)
        # Copter::set_mode: ignore_checks = !armed, so GUIDED is taken on the ground...
        assert h.set_mode(AP_GUIDED) == M.MAV_RESULT_ACCEPTED
        assert h.arm() == M.MAV_RESULT_FAILED  # ...and arming says "Need Position Estimate"
        assert h.set_mode(AP_GUIDED_NOGPS) == 0 and h.arm() == 0
        h.every = lambda: h.attitude(0.7 if h.altitude() < 1.0 else 0.5)
        h.run(2.5)
        assert h.set_mode(AP_GUIDED) == M.MAV_RESULT_FAILED  # armed: "requires position"
        def hold_with_mocap() -> None:
            h.vision()
            h.attitude(0.5)
        h.every = hold_with_mocap
        h.run(0.3)
        assert h.set_mode(AP_GUIDED) == M.MAV_RESULT_ACCEPTED  # EKF has the mocap position
