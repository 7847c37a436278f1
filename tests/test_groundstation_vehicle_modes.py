"""The simulated autopilots' modes and failsafes, and the vehicle physics, each driven by a
raw MAVLink client on a manual clock (deterministic)."""

from __future__ import annotations

import numpy as np
import pytest

from agent.wire.mavlink import mavlink, px4_custom_mode
from groundstation.mocap import SimMocapSource
from groundstation.vehicle import dynamics
from groundstation.vehicle.dynamics import FleetParams
from groundstation.vehicle.params import VehicleParams
from tests.vehicle_harness import Harness

M = mavlink
AP_GUIDED_NOGPS, AP_LOITER, AP_RTL = 20, 5, 6


def _climb_then_hold(h: Harness, height: float) -> None:
    """ArduCopter default thrust semantics: 0.7 climbs at 1 m/s, 0.5 holds altitude."""
    h.every = lambda: h.attitude(0.7 if h.altitude() < height else 0.5)
    h.run(height / 1.0 + 2.0)


def _pd_thrust(h: Harness, height: float, hover: float = 0.5) -> float:
    """Real thrust (PX4, or ArduCopter with GUID_OPTIONS bit 3) holding ``height`` [m]."""
    up = -float(h.fleet.v[0, 2])
    return hover * (1.0 + (2.0 * (height - h.altitude()) - 2.5 * up) / 9.81)


def test_arducopter_guid_timeout_levels_and_holds_after_3_s() -> None:
    with Harness(VehicleParams(setpoint_timeout=None)) as h:
        assert h.set_mode(AP_GUIDED_NOGPS) == 0 and h.arm() == 0
        h.run(2.0)
        assert h.altitude() == 0.0  # thrust 0.5 = climb rate 0: ArduCopter stays on the ground
        _climb_then_hold(h, 1.0)
        h.every = None  # the companion goes silent
        z0 = h.altitude()
        h.run(2.9)
        assert not h.quad.log.has("setpoint_timeout")
        h.run(0.2)
        assert h.quad.log.has("setpoint_timeout")  # GUID_TIMEOUT = 3 s (default)
        h.run(3.0)
        assert h.quad.mode == AP_GUIDED_NOGPS and h.quad.armed  # stays in GUIDED_NOGPS
        assert abs(h.altitude() - z0) < 0.1
        assert np.allclose(h.fleet.att[0, :2], 0.0, atol=1e-3)  # level


def test_bad_setpoints_reinitialise_arducopter_guided() -> None:
    with Harness(VehicleParams()) as h:
        h.set_mode(AP_GUIDED_NOGPS)
        h.arm()
        _climb_then_hold(h, 1.0)
        h.every = None
        h.attitude(0.5, q=[1.0, 0.2, 0.0, 0.0])  # not unit length
        h.attitude(0.5, mask=3)  # yaw rate without roll and pitch rates
        h.run(0.1)
        assert h.quad.log.rejected_quat == 1 and h.quad.log.rejected_mask == 1
        assert h.quad.sp_hold_alt  # level, climb 0, as mode_guided.init(true)


def test_px4_offboard_needs_one_fresh_setpoint_and_fails_safe_by_com_obl_rc_act() -> None:
    with Harness(VehicleParams(autopilot="px4", setpoint_timeout=None,
                               params={"COM_OBL_RC_ACT": 4})) as h:
        h.attitude(0.0)
        h.run(1.2)  # that one set-point is now older than COM_OF_LOSS_T = 1 s
        assert h.set_mode(6) == M.MAV_RESULT_TEMPORARILY_REJECTED
        assert h.quad.log.has("offboard_refused")
        h.attitude(0.0)
        h.run(0.5)  # a single set-point 0.5 s old is enough for PX4 (offboardCheck.cpp)
        assert h.set_mode(6) == M.MAV_RESULT_ACCEPTED and h.arm() == 0
        h.every = lambda: h.attitude(_pd_thrust(h, 1.0))
        h.run(4.0)
        assert h.altitude() == pytest.approx(1.0, abs=0.1)
        h.every = None
        h.run(1.1)
        assert h.quad.log.has("setpoint_timeout")
        assert h.quad.mode == px4_custom_mode(4, 6)  # COM_OBL_RC_ACT 4: AUTO.LAND
        h.run(8.0)
        assert h.quad.log.has("landed") and not h.quad.armed and h.altitude() == 0.0


def test_px4_offboard_loss_goes_to_position_mode_with_a_position() -> None:
    with Harness(VehicleParams(autopilot="px4")) as h:
        def tick() -> None:
            h.vision()
            h.attitude(_pd_thrust(h, 1.0))

        h.every = tick
        h.run(0.2)
        assert h.set_mode(6) == 0 and h.arm() == 0
        h.run(4.0)
        h.every = h.vision  # mocap still flows, set-points stop
        h.run(1.0)
        assert h.quad.mode == px4_custom_mode(3)  # POSCTL (COM_OBL_RC_ACT = 0)
        h.run(3.0)
        assert np.linalg.norm(h.fleet.p[0] - h.quad.hold_p) < 0.1 and h.quad.armed


def test_loiter_needs_external_navigation_configured() -> None:
    """Without a position estimate ArduCopter takes LOITER while disarmed (set_mode ignores
    the checks on the ground) and refuses to arm in it."""
    with Harness(VehicleParams()) as h:
        h.every = h.vision  # mocap forwarded, but VISO_TYPE = 0 by default: ignored
        h.run(0.5)
        assert h.set_mode(AP_LOITER) == M.MAV_RESULT_ACCEPTED
        assert h.arm() == M.MAV_RESULT_FAILED
        assert h.quad.log.has("arming_refused_no_position")
    good = VehicleParams(params={"VISO_TYPE": 1, "EK3_SRC1_POSXY": 6, "EK3_SRC1_POSZ": 6})
    with Harness(good) as h:
        h.every = h.vision
        h.run(0.5)
        h.client.mav.heartbeat_send(M.MAV_TYPE_GCS, M.MAV_AUTOPILOT_INVALID, 0, 0, 0)
        assert h.set_mode(AP_LOITER) == M.MAV_RESULT_ACCEPTED
        h.of("HEARTBEAT")
        hb = h.wait_for("HEARTBEAT", sim_s=1.5)
        assert hb.custom_mode == AP_LOITER
        assert hb.base_mode & M.MAV_MODE_FLAG_GUIDED_ENABLED  # NE position controller runs


def test_nav_land_descends_reports_landing_and_disarms() -> None:
    with Harness(VehicleParams()) as h:
        h.client.mav.heartbeat_send(M.MAV_TYPE_GCS, M.MAV_AUTOPILOT_INVALID, 0, 0, 0)
        h.set_mode(AP_GUIDED_NOGPS)
        h.arm()
        _climb_then_hold(h, 1.5)
        assert h.arm(False) == M.MAV_RESULT_FAILED  # no disarm in flight...
        h.every = None
        assert h.command(M.MAV_CMD_NAV_LAND) == M.MAV_RESULT_ACCEPTED
        assert h.quad.mode == 9
        h.of("EXTENDED_SYS_STATE")
        h.run(1.5)
        assert h.of("EXTENDED_SYS_STATE")[-1].landed_state == M.MAV_LANDED_STATE_LANDING
        h.run(4.0)
        assert not h.quad.armed and h.quad.log.has("landed")
        assert h.of("EXTENDED_SYS_STATE")[-1].landed_state == M.MAV_LANDED_STATE_ON_GROUND
        assert h.arm() == M.MAV_RESULT_FAILED  # ArduCopter does not arm in LAND


def test_rtl_climbs_flies_home_and_lands() -> None:
    cfg = VehicleParams(params={"VISO_TYPE": 1, "EK3_SRC1_POSXY": 6, "RTL_ALT": 200})
    with Harness(cfg) as h:
        def tick() -> None:
            h.vision()
            h.attitude(0.7 if h.altitude() < 1.0 else 0.5)

        h.every = tick
        h.set_mode(AP_GUIDED_NOGPS)
        h.arm()
        h.run(3.0)
        h.fleet.p[0, :2] = [3.0, -2.0]  # carried away from home (x, y NED)
        h.every = h.vision
        assert h.command(M.MAV_CMD_NAV_RETURN_TO_LAUNCH) == M.MAV_RESULT_ACCEPTED
        peak = 0.0
        for _ in range(30):
            h.run(0.5)
            peak = max(peak, h.altitude())
        assert peak == pytest.approx(2.0, abs=0.25)  # RTL_ALT = 2 m
        assert np.linalg.norm(h.fleet.p[0, :2]) < 0.3 and not h.quad.armed


def test_wrong_hover_thrust_parameter_sags_the_altitude_hold() -> None:
    def hold_error(params: dict[str, float]) -> float:
        with Harness(VehicleParams(params={"GUID_OPTIONS": 8, **params})) as h:
            h.set_mode(AP_GUIDED_NOGPS)
            h.arm()
            h.every = lambda: h.attitude(_pd_thrust(h, 1.0))
            h.run(4.0)
            z0 = h.altitude()
            h.every = None
            h.run(4.0)  # setpoint timeout (0.5 s): the autopilot's own altitude hold
            return h.altitude() - z0

    assert abs(hold_error({})) < 0.05
    # Believes 0.35, needs 0.5: the simulated hold (no integrator, no MOT_HOVER_LEARN) sinks.
    assert hold_error({"MOT_THST_HOVER": 0.35}) < -0.3


def test_battery_drains_with_thrust() -> None:
    with Harness(VehicleParams(battery_mah=1000.0)) as h:
        h.client.mav.heartbeat_send(M.MAV_TYPE_GCS, M.MAV_AUTOPILOT_INVALID, 0, 0, 0)
        h.run(2.0)
        idle = h.of("BATTERY_STATUS")[-1]
        h.set_mode(AP_GUIDED_NOGPS)
        h.arm()
        _climb_then_hold(h, 1.0)
        h.run(4.0)
        flying = h.of("BATTERY_STATUS")[-1]
        assert flying.current_battery > 5 * idle.current_battery  # cA, motors on
        assert flying.current_consumed > 10  # mAh after ~7 s at ~9 A
        assert flying.battery_remaining < idle.battery_remaining
        assert flying.voltages[0] < idle.voltages[0]


def test_dynamics_step_is_pure_and_vectorised() -> None:
    params = FleetParams.of([VehicleParams(wind=[2.0, 0.0, 0.0]),
                             VehicleParams(wind=[0.0, -1.0, 0.0], tau_thrust=0.1)])
    s0 = dynamics.initial_state(np.array([[0.0, 0.0, -5.0], [1.0, 0.0, -5.0]]))
    s0.armed[:] = True
    before = s0.copy()
    cmd = np.array([[0.0, 0.0, 0.0, 0.5], [0.0, 0.0, 0.0, 0.5]])
    s1 = dynamics.step(s0, cmd, params, 0.01)
    for a, b in zip((s0.p, s0.v, s0.thrust), (before.p, before.v, before.thrust), strict=True):
        np.testing.assert_array_equal(a, b)  # the input state is untouched
    # Drag on the air-relative velocity: each vehicle pushed along its own wind.
    assert s1.v[0, 0] > 0 and s1.v[0, 1] == 0 and s1.v[1, 1] < 0 and s1.v[1, 0] == 0
    # Motor lag: first order with each vehicle's tau_thrust.
    assert s1.thrust[0] == pytest.approx(0.5 * (1 - np.exp(-0.01 / 0.03)))
    assert s1.thrust[1] == pytest.approx(0.5 * (1 - np.exp(-0.01 / 0.1)))


def test_gusts_are_seeded() -> None:
    def drift(seed: int) -> np.ndarray:
        with Harness(VehicleParams(gust_std=1.0, gust_tau=0.5), seed=seed) as h:
            h.fleet.p[0, 2] = -10.0
            h.run(1.0)
            return h.fleet.state.gust[0, :].copy()

    a, b, c = drift(1), drift(1), drift(2)
    np.testing.assert_array_equal(a, b)
    assert not np.allclose(a, c) and 0.05 < np.linalg.norm(a) < 5.0


def test_mocap_dropouts_are_seeded() -> None:
    def seen(seed: int) -> list[bool]:
        with Harness(VehicleParams(mocap_dropout=0.3), seed=seed) as h:
            src = SimMocapSource(h.fleet)
            out = []
            for _ in range(400):
                h.clock.advance(0.01)
                h.fleet.step_to(h.clock.now())
                out.append(src.read(h.clock.now())["d0"] is not None)
            return out

    a = seen(3)
    assert a == seen(3)
    assert 0.6 < sum(a) / len(a) < 0.8  # about 70 % delivered
